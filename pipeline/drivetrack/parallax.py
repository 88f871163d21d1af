"""The lidar's parallax cleanup (``drivetrack.parallax_cleanup``): projected lidar points the camera
cannot see, because a nearer lidar point hides them from it."""

from __future__ import annotations

import numba
import numpy as np
from scipy.spatial import cKDTree

from pipeline.drivetrack.cell_grid import CellGrid, bounds, mean_spacing


def camera_occluded_lidar(
    lidar_uv: np.ndarray, lidar_depth: np.ndarray, margin: float, neighbours: int = 8
) -> np.ndarray:
    """True for projected lidar points [M] hidden from the camera by a nearer lidar point.

    The lidar sits apart from the camera (on Waymo, about 0.3 m higher), so it sees surfaces
    behind an occluder's edge that the camera cannot; projected into the image they land inside
    the occluder and would make it look far. A point is hidden when one of its ``neighbours``
    nearest projected points, within twice the median point spacing, is nearer by more than
    twice the occlusion margin (twice, so that surfaces seen at a grazing angle, whose
    neighbouring points differ in depth by a few percent, keep their points).

    Computed on grids of cells (``CellGrid``): only neighbours within twice the median spacing count,
    and where two points share a position exactly, each is the other's neighbour.
    """
    if len(lidar_depth) <= neighbours:
        return np.zeros(len(lidar_depth), bool)
    uv = np.ascontiguousarray(lidar_uv, np.float64)
    low, high = bounds(uv)
    side, extent = mean_spacing(uv), np.hypot(*(high - low))
    reach = None
    while reach is None and side < extent:
        grid = CellGrid(uv, side)
        reach = _twice_the_median(grid.nearest_distances(), grid.side)
        side = 2.0 * grid.side
    if reach is None:  # a handful of far-apart points
        reach = 2.0 * np.median(cKDTree(uv).query(uv, k=2)[0][:, 1])
    grid = CellGrid(uv, reach)
    return _hidden_within(uv, np.asarray(lidar_depth, np.float64), *grid.arrays, reach, neighbours, margin)


def _twice_the_median(nearest: np.ndarray, side: float) -> float | None:
    """2 x the median of the points' nearest-point distances [M], from ``CellGrid.nearest_distances``
    (exact up to ``side``), or None when the distances beyond ``side`` reach the median."""
    exact = np.where(nearest <= side, nearest, np.inf)
    if np.isinf(exact).sum() >= len(exact) // 2:  # the middle one or two might be unknown
        return None
    return 2.0 * np.median(exact)


@numba.njit(cache=True, nogil=True)
def _hidden_within(uv, depth, keys, order, starts, columns, reach, neighbours, margin):
    """[M] bool: point i has, among its ``neighbours`` nearest other points, one within ``reach``
    (Euclidean) whose depth is below (1 - 2 margin) x its own.

    uv [M, 2], depth [M]; the rest ``CellGrid.arrays`` of cells of side ``reach``.
    """
    count = len(depth)
    hidden = np.zeros(count, np.bool_)
    found = np.empty(count, np.float64)
    nearer = np.empty(count, np.bool_)
    for i in range(count):
        limit = (1.0 - 2 * margin) * depth[i]
        n = 0
        for row in (-1, 0, 1):
            low = keys[i] + row * columns - 1
            for k in range(starts[low], starts[low + 3]):
                j = order[k]
                if j == i:
                    continue
                dx, dy = uv[i, 0] - uv[j, 0], uv[i, 1] - uv[j, 1]
                distance = np.sqrt(dx * dx + dy * dy)
                if distance <= reach:
                    found[n] = distance
                    nearer[n] = depth[j] < limit
                    n += 1
        for a in range(n):  # a nearer one among the ``neighbours`` nearest (ties: first found)
            if nearer[a]:
                rank = 0
                for b in range(n):
                    rank += found[b] < found[a] or (found[b] == found[a] and b < a)
                if rank < neighbours:
                    hidden[i] = True
                    break
    return hidden
