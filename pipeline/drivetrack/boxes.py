"""Upright 7-DoF boxes: (cx, cy, cz, length, width, height, heading)."""

from __future__ import annotations

import numpy as np

from pipeline.core.geometry import rotation_z, se3_from_rotation_translation

_CORNER_SIGNS = np.array(
    [[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=np.float64
)


def box_poses(boxes: np.ndarray) -> np.ndarray:
    """parent_from_box transforms [..., 4, 4] = translate(center) Rz(heading) for boxes [..., 7]."""
    return se3_from_rotation_translation(rotation_z(boxes[..., 6]), boxes[..., :3])


def box_corners_local(box: np.ndarray) -> np.ndarray:
    """The 8 corners [8, 3] of a box [7] in its own frame."""
    return _CORNER_SIGNS * (box[3:6] / 2.0)


def inside_box(points_local: np.ndarray, size: np.ndarray, shrink: float) -> np.ndarray:
    """True for points [M, 3] in box coordinates inside the box of ``size`` [3] shrunk by
    ``shrink`` metres in each dimension."""
    half = (np.asarray(size) - shrink) / 2.0
    return np.all(np.abs(points_local) <= half, axis=-1)


def longest_run(flags: np.ndarray) -> tuple[int, int]:
    """[start, stop) of the longest run of True in ``flags`` [T] (earliest on ties; (0, 0) if none)."""
    best, start = (0, 0), None
    for index, flag in enumerate(list(flags) + [False]):
        if flag and start is None:
            start = index
        elif not flag and start is not None:
            if index - start > best[1] - best[0]:
                best = (start, index)
            start = None
    return best
