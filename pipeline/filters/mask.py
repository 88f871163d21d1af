"""Mask agreement: a visible track should land on its own object's mask."""

from __future__ import annotations

import cv2
import numpy as np
from apache_beam.io.filesystem import CompressionTypes
from apache_beam.io.filesystems import FileSystems
from scipy.spatial import cKDTree

from pipeline.core.images import decode_image

MAX_CLOSING_PX = 63


def adaptive_closing_px(points_uv: np.ndarray) -> int:
    """Closing kernel (odd, pixels) that bridges the gaps between lidar scan lines: twice the
    median distance from a projected point [M, 2] to its nearest point on a lower line."""
    if len(points_uv) < 2:
        return 3
    distances, index = cKDTree(points_uv).query(points_uv, k=min(16, len(points_uv)))
    below = points_uv[index, 1] - points_uv[:, None, 1] > 0.5
    gaps = np.where(below, distances, np.inf).min(axis=1)
    gap = np.median(gaps[np.isfinite(gaps)]) if np.isfinite(gaps).any() else distances[:, 1].max()
    size = int(np.ceil(2.0 * max(gap, np.median(distances[:, 1])))) | 1
    return int(np.clip(size, 3, MAX_CLOSING_PX))


def silhouette_mask(points_uv: np.ndarray, width: int, height: int, closing_px: int) -> np.ndarray:
    """Object mask [H, W] bool from its projected points [M, 2]: the points' pixels, closed
    with an elliptical kernel of ``closing_px`` (0 = adaptive), then grown by half a kernel
    so surface points just beyond the outermost scan line still count as on the object."""
    mask = np.zeros((height, width), np.uint8)
    pixels = np.floor(points_uv).astype(np.int64)
    inside = (pixels[:, 0] >= 0) & (pixels[:, 0] < width) & (pixels[:, 1] >= 0)
    inside &= pixels[:, 1] < height
    if not inside.any():
        return mask.astype(bool)
    xs, ys = pixels[inside, 0], pixels[inside, 1]
    mask[ys, xs] = 1
    size = closing_px or adaptive_closing_px(points_uv[inside])
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
    grow = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size // 2 | 1, size // 2 | 1))
    # Only the points' bounding box, padded beyond the reach of both kernels, can change: working
    # on it alone gives the same mask as the whole image (a vehicle is a small part of a frame).
    pad = 2 * size
    x0, x1 = max(xs.min() - pad, 0), min(xs.max() + pad + 1, width)
    y0, y1 = max(ys.min() - pad, 0), min(ys.max() + pad + 1, height)
    box = mask[y0:y1, x0:x1]
    mask[y0:y1, x0:x1] = cv2.dilate(cv2.morphologyEx(box, cv2.MORPH_CLOSE, kernel), grow)
    return mask.astype(bool)


def on_mask(mask: np.ndarray, track_uv: np.ndarray) -> np.ndarray:
    """True where pixels [N, 2] fall on ``mask`` [H, W] (False outside the image)."""
    height, width = mask.shape
    pixels = np.floor(track_uv).astype(np.int64)
    inside = (pixels[:, 0] >= 0) & (pixels[:, 0] < width) & (pixels[:, 1] >= 0)
    inside &= pixels[:, 1] < height
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


def read_mask_png(path: str, width: int, height: int) -> np.ndarray | None:
    """A user-supplied mask [H, W] bool (non-zero = object), or None when the file is absent."""
    if not FileSystems.exists(path):
        return None
    with FileSystems.open(path, compression_type=CompressionTypes.UNCOMPRESSED) as handle:
        data = handle.read()
    return decode_image(data, width, height, f"mask {path}", noun="mask") > 0
