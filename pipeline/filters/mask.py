"""Mask agreement: a visible track should land on its own object's mask."""

from __future__ import annotations

import numpy as np

from pipeline.core.geometry import in_image


def on_mask(mask: np.ndarray, track_uv: np.ndarray) -> np.ndarray:
    """True where pixels [N, 2] fall on ``mask`` [H, W] (False outside the image)."""
    height, width = mask.shape
    pixels = np.floor(track_uv).astype(np.int64)
    inside = in_image(pixels, width, height)
    result = np.zeros(len(track_uv), bool)
    result[inside] = mask[pixels[inside, 1], pixels[inside, 0]]
    return result


def agreement(on_object: np.ndarray, visible: np.ndarray, has_mask: np.ndarray) -> np.ndarray:
    """Share of a track's visible frames (that have a mask) where it is on its mask.

    Args:
      on_object: [T, N] bool, track on the mask.
      visible: [T, N] bool.
      has_mask: [T] bool, frames with a mask.
    Returns:
      [N] float64; NaN where the track has no visible frame with a mask.
    """
    counted = visible & has_mask[:, None]
    total = counted.sum(axis=0)
    hits = (on_object & counted).sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(total > 0, hits / np.maximum(total, 1), np.nan)
