"""Depth-test visibility, one rule a function: in view; the paper's dense depth test (eq. 4: within
delta of the rendered surface, ADT's and Panoptic Studio's); DriveTrack's relative test (the lidar's
reference depth at least (1 - margin) of the point's)."""

from __future__ import annotations

import numpy as np

from pipeline.core.geometry import in_image, project


def in_view(points_cam: np.ndarray, fx_fy_cx_cy: np.ndarray, width: int, height: int) -> np.ndarray:
    """True where points [..., 3] are in front of the camera and project inside the image."""
    pixels = project(points_cam, fx_fy_cx_cy)
    return (points_cam[..., 2] > 0) & in_image(pixels, width, height)


def passes_dense_depth_test(z: np.ndarray, depth: np.ndarray, delta: float) -> np.ndarray:
    """Paper eq. 4: |z - D| < delta, for point depths z and the rendered surface's depth D there (each
    [...]). False where there is no surface (D is NaN)."""
    with np.errstate(invalid="ignore"):
        return np.abs(z - depth) < delta


def passes_relative_depth_test(z: np.ndarray, depth: np.ndarray, margin: float) -> np.ndarray:
    """Not occluded with a relative margin: D >= (1 - margin) z (DriveTrack's 5% rule).

    False where the depth is unknown (NaN): no evidence of visibility.
    """
    with np.errstate(invalid="ignore"):
        return depth >= (1.0 - margin) * z
