"""Nearest Gaussian centre to a few points, by brute force over the centres that can be near.

A unit attaches a few dozen queries per frame to the nearest of ~10^5 foreground centres, and
keeps an attachment only within ``max_attach_distance_m``; a KD-tree built per frame for them
costs far more than comparing every centre. With such a bound, one pass over the centres first
drops those that cannot be within it of any point: a centre is compared with the points only if
its cell (cells of the bound's side, over the points' bounding box) is, along each axis, at most
one from a point's cell (tested per axis first, then the cell itself: on the bench's frames
about a quarter of the centres pass the first test and a fortieth the second).
Distances are computed as scipy's cKDTree computes them, sqrt(((x0 - c0)^2 + (x1 - c1)^2) +
(x2 - c2)^2) in float64; among centres at exactly the same distance the first candidate is taken.
"""

from __future__ import annotations

import numba
import numpy as np

from pipeline.core.kernel_arrays import read_only

MAX_AXIS_CELLS = 1 << 16  # points spread wider than this many cells along an axis: no prefilter
NEIGHBOURS = np.stack(np.meshgrid([-1, 0, 1], [-1, 0, 1], [-1, 0, 1], indexing="ij"), axis=-1).reshape(-1, 3)


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
    # Element by element: assigning an array to a slice would compile numba's shape-mismatch error
    # message (about 4 s on a first run), for no other effect.
    for p in range(points.shape[0]):
        out_distance[p] = np.sqrt(best[p])


@numba.njit(cache=True)
def _near_some_point(centres, candidates, size, low, occupied, cell_keys):
    """Positions in ``candidates`` [S], ascending, of the centres whose cell (side ``size``, from
    ``low`` [3]) is at most one from a point's along every axis: first per axis (``occupied``
    [3, D]: the cells within one of a point's), without branches; then, for those, the cell itself
    (``cell_keys``: the sorted keys (x D + y) D + z of the cells within one of a point's)."""
    keep = np.empty(candidates.shape[0], np.int64)
    count = 0
    dims = occupied.shape[1]
    top = dims - 1.0
    inverse = 1.0 / size  # a cell index an ulp off is covered by the cell's margin
    for k in range(candidates.shape[0]):
        c = candidates[k]
        x = (np.float64(centres[c, 0]) - low[0]) * inverse
        y = (np.float64(centres[c, 1]) - low[1]) * inverse
        z = (np.float64(centres[c, 2]) - low[2]) * inverse
        inside = (x >= 0) & (x < dims) & (y >= 0) & (y < dims) & (z >= 0) & (z < dims)
        ix, iy, iz = int(min(max(x, 0.0), top)), int(min(max(y, 0.0), top)), int(min(max(z, 0.0), top))
        keep[count] = k
        count += inside & occupied[0, ix] & occupied[1, iy] & occupied[2, iz]
    exact = 0
    for j in range(count):
        c = candidates[keep[j]]
        ix = int((np.float64(centres[c, 0]) - low[0]) * inverse)
        iy = int((np.float64(centres[c, 1]) - low[1]) * inverse)
        iz = int((np.float64(centres[c, 2]) - low[2]) * inverse)
        key = (ix * dims + iy) * dims + iz
        found = np.searchsorted(cell_keys, key)
        if found < cell_keys.shape[0] and cell_keys[found] == key:
            keep[exact] = keep[j]
            exact += 1
    return keep[:exact]


def nearest_centres(
    centres: np.ndarray, candidates: np.ndarray, points: np.ndarray, within: float = np.inf
) -> tuple[np.ndarray, np.ndarray]:
    """For points [P, 3] (float64), the nearest of the centres [N, 3] (float32 or float64) listed
    in ``candidates`` [F] no farther than ``within``: (distance [P], position in ``candidates``
    [P]); inf and -1 where none is."""
    points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    centres = read_only(centres)
    candidates = np.ascontiguousarray(candidates, dtype=np.int64)
    distance = np.full(len(points), np.inf)
    index = np.full(len(points), -1, np.int64)
    finite = np.isfinite(points).all(axis=1)
    near = np.arange(len(candidates))
    if 0 < within < np.inf and finite.any():
        # A centre within ``within`` of a point differs from it by less than one cell along each
        # axis (the cell a millionth wider, so that rounding cannot carry it two cells off).
        size = within * (1 + 1e-6)
        low = points[finite].min(axis=0) - 2 * size  # every point's cell is at least 1
        cells = np.floor((points[finite] - low) / size).astype(np.int64)
        dims = int(cells.max()) + 2
        if dims <= MAX_AXIS_CELLS:
            around = (cells[:, None, :] + NEIGHBOURS[None]).reshape(-1, 3)  # cells within one of a point's
            occupied = np.zeros((3, dims), np.bool_)
            occupied[np.arange(3), around] = True  # their coordinates, axis by axis
            cell_keys = np.unique((around[:, 0] * dims + around[:, 1]) * dims + around[:, 2])
            near = _near_some_point(centres, candidates, size, low, occupied, cell_keys)
    found_distance, found = np.empty(int(finite.sum())), np.empty(int(finite.sum()), np.int64)
    _nearest(centres, candidates[near], points[finite], found_distance, found)
    hit = (found >= 0) & (found_distance <= within)
    rows = np.flatnonzero(finite)[hit]
    distance[rows], index[rows] = found_distance[hit], near[found[hit]]
    return distance, index
