"""Depth-test visibility (paper eq. 4) and its pieces."""

from __future__ import annotations

import numpy as np

from pipeline.core.geometry import in_image, project


def in_view(points_cam: np.ndarray, fx_fy_cx_cy: np.ndarray, width: int, height: int) -> np.ndarray:
    """True where points [..., 3] are in front of the camera and project inside the image."""
    pixels = project(points_cam, fx_fy_cx_cy)
    return (points_cam[..., 2] > 0) & in_image(pixels, width, height)


def passes_relative_depth_test(z: np.ndarray, depth: np.ndarray, margin: float) -> np.ndarray:
    """Not occluded with a relative margin: D >= (1 - margin) z (DriveTrack's 5% rule).

    False where the depth is unknown (NaN): no evidence of visibility.
    """
    with np.errstate(invalid="ignore"):
        return depth >= (1.0 - margin) * z
