"""Surface normals of the TOP lidar's returns from the range image's own neighbours, for the facing
test (``visibility.py``).

Each pixel's neighbours on the same beam (columns) and in the same column (rows) are fixed by the
scan, not by which other points exist, so a normal never depends on a point cloud's density or on
where the world's origin lies (a nearest-neighbour estimate flips on single scan lines).
"""

from __future__ import annotations

import numpy as np

# A neighbour lies on the same surface when its range differs by at most this fraction of the
# pixel's own: a plane seen at 85 degrees incidence differs by ~8% between neighbouring columns of
# the TOP lidar at any range, a car in front of a wall by far more.
MAX_RANGE_JUMP = 0.2


def _tangent(
    points: np.ndarray, ranges: np.ndarray, rows: np.ndarray, cols: np.ndarray, axis: int
) -> tuple[np.ndarray, np.ndarray]:
    """For pixels (rows [K], cols [K]), the offset [K, 3] to the neighbour along ``axis`` (either
    side, the nearer in range) on the same surface, and whether there is one [K]. The image's edges
    have no neighbour beyond them (the columns' seam joins the sweep's first and last instants)."""
    here = ranges[rows, cols]
    best = np.zeros((len(rows), 3))
    best_jump = np.full(len(rows), np.inf)
    for step in (-1, 1):
        r, c = (rows + step, cols) if axis == 0 else (rows, cols + step)
        on_image = (r >= 0) & (r < ranges.shape[0]) & (c >= 0) & (c < ranges.shape[1])
        r, c = np.where(on_image, r, 0), np.where(on_image, c, 0)
        there = np.where(on_image, ranges[r, c], 0.0)
        jump = np.abs(there - here)
        same = (there > 0) & (here > 0) & (jump <= MAX_RANGE_JUMP * here) & (jump < best_jump)
        best[same] = points[r[same], c[same]] - points[rows[same], cols[same]]
        best_jump[same] = jump[same]
    return best, np.isfinite(best_jump)


def range_image_normals(points: np.ndarray, ranges: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """Unit normals [K, 3] facing the lidar at the range image's pixels [K] (flat indices), in the
    frame of ``points`` [H, W, 3] (each pixel's return, lidar at the origin), for ranges [H, W]
    (<= 0: no return): the cross product of the offsets to a row neighbour and a column neighbour
    on the same surface. A pixel lacking either gets the direction back to the lidar (which saw the
    surface from there)."""
    ranges = np.asarray(ranges, np.float64)
    rows, cols = np.unravel_index(np.asarray(pixels, np.int64), ranges.shape)
    along_rows, has_row = _tangent(points, ranges, rows, cols, 0)
    along_columns, has_column = _tangent(points, ranges, rows, cols, 1)
    normals = np.cross(along_rows, along_columns)
    length = np.linalg.norm(normals, axis=-1, keepdims=True)
    here = points[rows, cols]
    towards_lidar = -here / np.maximum(np.linalg.norm(here, axis=-1, keepdims=True), 1e-12)
    defined = (has_row & has_column)[:, None] & (length > 0)
    normals = np.where(defined, normals / np.where(length > 0, length, 1.0), towards_lidar)
    facing = np.einsum("ki,ki->k", normals, towards_lidar) >= 0
    return np.where(facing[:, None], normals, -normals)
