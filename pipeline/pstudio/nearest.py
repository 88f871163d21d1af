"""Nearest Gaussian centre to a few points, by brute force.

A unit attaches a handful of queries per frame to the nearest of ~10^5 foreground centres; a
KD-tree built per frame for them costs far more than comparing every centre. Distances are
computed as scipy's cKDTree computes them, sqrt(((x0 - c0)^2 + (x1 - c1)^2) + (x2 - c2)^2) in
float64; among centres at exactly the same distance the first candidate is taken.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)
def _nearest(centres, candidates, points, out_distance, out_index):
    """Candidates outer, points inner: each centre is read once."""
    best = np.full(points.shape[0], np.inf)
    out_index[:] = -1
    for k in range(candidates.shape[0]):
        c = candidates[k]
        cx, cy, cz = np.float64(centres[c, 0]), np.float64(centres[c, 1]), np.float64(centres[c, 2])
        for p in range(points.shape[0]):
            d0, d1, d2 = points[p, 0] - cx, points[p, 1] - cy, points[p, 2] - cz
            squared = d0 * d0 + d1 * d1 + d2 * d2
            if squared < best[p]:
                best[p], out_index[p] = squared, k
    out_distance[:] = np.sqrt(best)


def nearest_centres(
    centres: np.ndarray, candidates: np.ndarray, points: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """For points [P, 3] (float64), the nearest of the centres [N, 3] (float32 or float64) listed
    in ``candidates`` [F]: (distance [P], position in ``candidates`` [P])."""
    points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    distance = np.empty(len(points))
    index = np.empty(len(points), np.int64)
    _nearest(
        np.ascontiguousarray(centres),
        np.ascontiguousarray(candidates, dtype=np.int64),
        points,
        distance,
        index,
    )
    return distance, index
