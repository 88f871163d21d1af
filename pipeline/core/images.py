"""Image sizes read from file headers, and checked decoding: no image is decoded before its header
says it has the expected size (a crafted header can claim gigapixels)."""

from __future__ import annotations

import cv2
import numpy as np
import simplejpeg

from pipeline.core.errors import InputError

# Start-of-frame markers (baseline, progressive, lossless, arithmetic): they carry the image size.
SOF_MARKERS = frozenset({0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF})
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def jpeg_size(data: bytes) -> tuple[int, int] | None:
    """(height, width) from a JPEG's start-of-frame header, or None when there is none to read."""
    if data[:2] != b"\xff\xd8":
        return None
    pos = 2
    while pos + 4 <= len(data):
        if data[pos] != 0xFF:
            return None
        marker = data[pos + 1]
        if marker == 0xFF:  # fill byte before a marker
            pos += 1
            continue
        if marker in SOF_MARKERS:
            if pos + 9 > len(data):
                return None
            height = int.from_bytes(data[pos + 5 : pos + 7], "big")
            width = int.from_bytes(data[pos + 7 : pos + 9], "big")
            return (height, width) if height and width else None
        if marker in (0xD9, 0xDA):  # end of image or start of scan before any frame header
            return None
        pos += 2 + int.from_bytes(data[pos + 2 : pos + 4], "big")
    return None


def png_size(data: bytes) -> tuple[int, int] | None:
    """(height, width) from a PNG's IHDR chunk, or None when it is not a PNG."""
    if data[:8] != PNG_SIGNATURE or data[12:16] != b"IHDR" or len(data) < 24:
        return None
    width, height = int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    return (height, width) if height and width else None


def decode_image(
    data: bytes, width: int, height: int, what: str, noun: str = "image", flags: int = cv2.IMREAD_GRAYSCALE
) -> np.ndarray:
    """Decode a JPEG or PNG whose header says ``width`` x ``height`` ([H, W] or [H, W, 3] uint8);
    InputError naming ``what`` otherwise, before anything is decoded."""
    size = jpeg_size(data) or png_size(data)
    if size is None:
        raise InputError(f"{what}: corrupt {noun} (no JPEG or PNG size header)")
    if size != (height, width):
        raise InputError(f"{what}: {noun} is {size[1]}x{size[0]}, expected {width}x{height}")
    image = cv2.imdecode(np.frombuffer(data, np.uint8), flags)
    if image is None or image.shape[:2] != (height, width):
        raise InputError(f"{what}: corrupt {noun} (cannot be decoded)")
    return image


def check_jpeg(
    data: bytes, width: int, height: int, what: str, flags: int = cv2.IMREAD_GRAYSCALE
) -> np.ndarray:
    """The decoded image ([H, W] or [H, W, 3] uint8, as ``flags`` ask) of ``data``; InputError unless
    it is a complete JPEG of ``width`` x ``height`` pixels."""
    check_jpeg_header(data, width, height, what)
    return decode_image(data, width, height, what, noun="JPEG", flags=flags)


def check_jpeg_decodes(data: bytes, width: int, height: int, what: str) -> None:
    """InputError unless ``data`` is a complete JPEG of ``width`` x ``height`` pixels that decodes,
    as ``check_jpeg`` refuses it, for a JPEG passed on undecoded: decoded grey at an eighth of its
    size (``-(-height // 8)`` x ``-(-width // 8)``), where libjpeg still reads every marker, table
    and the whole entropy-coded scan, but spares most of the inverse DCT and the pixels."""
    check_jpeg_header(data, width, height, what)
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_REDUCED_GRAYSCALE_8)
    if image is None or image.shape != (-(-height // 8), -(-width // 8)):
        raise InputError(f"{what}: corrupt JPEG (cannot be decoded)")


def check_jpeg_header(data: bytes, width: int, height: int, what: str) -> None:
    """InputError unless ``data`` starts and ends as a JPEG and its frame header says ``width`` x
    ``height`` pixels."""
    if not isinstance(data, bytes) or len(data) < 4:
        raise InputError(f"{what}: missing or empty JPEG")
    if data[:2] != b"\xff\xd8" or data.rstrip(b"\x00")[-2:] != b"\xff\xd9":
        raise InputError(f"{what}: corrupt JPEG (missing start or end marker)")
    size = jpeg_size(data)
    if size is None:
        raise InputError(f"{what}: corrupt JPEG (no frame header)")
    if size != (height, width):
        raise InputError(f"{what}: JPEG is {size[1]}x{size[0]}, calibration says {width}x{height}")


def decode_jpeg_bgrx(data: bytes, out: np.ndarray, what: str) -> None:
    """A JPEG of out's size decoded straight into out [H, W, 4] uint8 (blue, green, red, 255): the
    pixels of ``cv2.imdecode(..., IMREAD_COLOR)`` with the fourth channel, without a colour pass or
    a fresh array (libjpeg-turbo through simplejpeg). InputError unless it is a complete JPEG of
    that size; as OpenCV, recoverable damage in the data is decoded as it comes."""
    height, width = out.shape[:2]
    check_jpeg_header(data, width, height, what)
    try:
        simplejpeg.decode_jpeg(data, colorspace="BGRX", buffer=out, strict=False)
    except ValueError as error:
        raise InputError(f"{what}: corrupt JPEG (cannot be decoded: {error})") from None
