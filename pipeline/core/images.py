"""Checks on the JPEG frames that clips pass through unchanged."""

from __future__ import annotations

import cv2
import numpy as np

from pipeline.core.errors import InputError


def check_jpeg(data: bytes, width: int, height: int, what: str) -> None:
    """Raise InputError unless ``data`` is a complete JPEG of ``width`` x ``height`` pixels."""
    if not isinstance(data, bytes) or len(data) < 4:
        raise InputError(f"{what}: missing or empty JPEG")
    if data[:2] != b"\xff\xd8" or data.rstrip(b"\x00")[-2:] != b"\xff\xd9":
        raise InputError(f"{what}: corrupt JPEG (missing start or end marker)")
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise InputError(f"{what}: corrupt JPEG (cannot be decoded)")
    if image.shape != (height, width):
        raise InputError(
            f"{what}: JPEG is {image.shape[1]}x{image.shape[0]}, calibration says {width}x{height}"
        )
