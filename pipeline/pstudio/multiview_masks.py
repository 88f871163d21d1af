"""Panoptic Studio's mask statistic: a track's centre, over every (frame, camera) pair where it
projects into the image, lands on that camera's foreground mask how often (the release's
multi-view mask agreement)."""

from __future__ import annotations

import numba
import numpy as np

from pipeline.pstudio.records import UnitInput


@numba.njit(cache=True, nogil=True)
def camera_pixel(x, y, z, w2c, fx_fy_cx_cy):
    """(u, v, depth) of the world point (x, y, z) in a camera (w2c [4, 4], fx_fy_cx_cy [4]):
    ``transform_points`` then ``project``, bit for bit (each row's products summed as NumPy's
    einsum sums them, (x + z) + y, then the translation; u = fx x / z + cx; NumPy 2.4's order,
    tests/pstudio/test_pixels.py compares with those functions). u and v are meaningless where
    the depth is not positive."""
    depth = ((w2c[2, 0] * x + w2c[2, 2] * z) + w2c[2, 1] * y) + w2c[2, 3]
    if not depth > 0:
        return 0.0, 0.0, depth
    px = ((w2c[0, 0] * x + w2c[0, 2] * z) + w2c[0, 1] * y) + w2c[0, 3]
    py = ((w2c[1, 0] * x + w2c[1, 2] * z) + w2c[1, 1] * y) + w2c[1, 3]
    return fx_fy_cx_cy[0] * px / depth + fx_fy_cx_cy[2], fx_fy_cx_cy[1] * py / depth + fx_fy_cx_cy[3], depth


@numba.njit(cache=True, nogil=True)
def _add_view(centres, w2c, fx_fy_cx_cy, width, height, packed, on_mask, seen_count):
    """One camera's share of ``multiview_mask_fraction`` at one frame: for each centre [K, 3] in
    front of it and inside its image of width x height pixels (``camera_pixel``), seen_count += 1
    and on_mask += the mask's bit at pixel (floor(u), floor(v)) (``packed``: [ceil(H W / 8)] uint8,
    ``np.packbits`` of the [H, W] mask, first pixel in the high bit)."""
    for k in range(centres.shape[0]):
        u, v, depth = camera_pixel(centres[k, 0], centres[k, 1], centres[k, 2], w2c, fx_fy_cx_cy)
        if depth > 0 and u >= 0 and u < width and v >= 0 and v < height:
            seen_count[k] += 1
            pixel = int(np.floor(v)) * width + int(np.floor(u))
            on_mask[k] += (packed[pixel >> 3] >> (7 - (pixel & 7))) & 1


def multiview_mask_fraction(unit: UnitInput, gaussians: np.ndarray) -> np.ndarray:
    """[K] fraction of (frame, camera) pairs with the centre in the image whose pixel
    (floor(u), floor(v)) is on that camera's foreground mask (NaN when never in any image). The
    masks are read packed (``read_masks`` checked their length), never unpacked."""
    views = unit.views
    w2c = np.ascontiguousarray(views.w2c, dtype=np.float64)
    intrinsics = np.ascontiguousarray(views.fx_fy_cx_cy, dtype=np.float64)
    on_mask = np.zeros(len(gaussians), np.int64)
    seen_count = np.zeros(len(gaussians), np.int64)
    for t in range(unit.gaussians.num_frames):
        centres = unit.gaussians.means[t, gaussians].astype(np.float64)
        for view in range(len(views.camera_ids)):
            packed = unit.packed_mask(view, t)
            _add_view(
                centres, w2c[view], intrinsics[view], views.width, views.height, packed, on_mask, seen_count
            )
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(seen_count > 0, on_mask / seen_count, np.nan)
