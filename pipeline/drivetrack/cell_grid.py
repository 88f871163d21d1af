"""Points in an image binned in square cells (``CellGrid``): the nearest point to any query, and each
point's nearest neighbour, found by searching a few cells instead of a tree. DriveTrack's depth
lookup (``visibility.nearest_depth_max4``) and its parallax cleanup (``parallax``) use it."""

from __future__ import annotations

import numba
import numpy as np


def bounds(uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The lowest and highest (u, v) [2] of points [M, 2]: ``uv.min(axis=0)``, ``uv.max(axis=0)``,
    reduced over a transposed copy (NumPy's reduction across the rows of [M, 2] is far slower)."""
    columns = np.ascontiguousarray(uv.T)
    return columns.min(axis=1), columns.max(axis=1)


def mean_spacing(uv: np.ndarray) -> float:
    """The spacing of points [M, 2] were they spread evenly over their bounding box."""
    low, high = bounds(uv)
    spread = high - low
    return float(np.sqrt(max(spread[0] * spread[1], 1e-12) / len(uv)))


class CellGrid:
    """Points [M, 2] binned in square cells of side ``side`` (at least 1/1024 of their spread, so at
    most 1026 x 1026 cells): the points of the 3 x 3 cells around a point hold every point within
    ``side`` of it.

    arrays: keys [M] (each point's cell, row-major with a spare cell around), order [M] (the
    points sorted by key), starts [cells + 1] (where each cell's points begin in ``order``), and
    the cells per row.
    """

    def __init__(self, uv: np.ndarray, side: float):
        self.uv = uv
        low, high = bounds(uv)
        self.side = max(side, (high - low).max() / 1024, 1e-9)
        self.origin = low
        cells = np.floor((uv - self.origin) / self.side).astype(np.int64)  # [M, 2] (x, y)
        columns = int(cells[:, 0].max()) + 3
        self.rows = int(cells[:, 1].max()) + 3
        keys = (cells[:, 1] + 1) * columns + cells[:, 0] + 1
        order = np.argsort(keys, kind="stable")
        starts = np.zeros(self.rows * columns + 1, np.int64)  # cell c: order[starts[c]:starts[c + 1]]
        np.cumsum(np.bincount(keys, minlength=self.rows * columns), out=starts[1:])
        self.arrays = (keys, order, starts, columns)

    def nearest(self, queries: np.ndarray) -> np.ndarray:
        """[K] index of the point nearest each query [K, 2] (the first found on a tie), by rings of
        cells searched outwards until no farther cell can hold a nearer point."""
        cells = np.floor((queries - self.origin) / self.side).astype(np.int64) + 1  # [K, 2], may lie out
        _, order, starts, columns = self.arrays
        return _nearest_points(self.uv, order, starts, columns, self.rows, self.side, queries, cells)

    def nearest_distances(self) -> np.ndarray:
        """[M] each point's distance to its nearest other point in the 3 x 3 cells around it (inf
        if none): exact where it is at most the cell side."""
        return _nearest_within(self.uv, *self.arrays)


@numba.njit(cache=True, nogil=True)
def _nearest_points(uv, order, starts, columns, rows, side, queries, cells):
    """[K] index of the point of uv [M, 2] nearest each query [K, 2] in cell (x, y) ``cells``."""
    found = np.zeros(len(queries), np.int64)
    for q in range(len(queries)):
        x, y = cells[q, 0], cells[q, 1]
        best = np.inf
        ring = 0
        while True:
            for row in range(max(y - ring, 0), min(y + ring, rows - 1) + 1):
                edge = row == y - ring or row == y + ring
                for span in range(1 if edge else 2):  # a whole edge row, else its two end cells
                    low = x - ring if edge or span == 0 else x + ring
                    high = x + ring if edge or span == 1 else x - ring
                    low, high = max(low, 0), min(high, columns - 1)
                    if low > high:
                        continue
                    for k in range(starts[row * columns + low], starts[row * columns + high + 1]):
                        j = order[k]
                        dx, dy = queries[q, 0] - uv[j, 0], queries[q, 1] - uv[j, 1]
                        d2 = dx * dx + dy * dy
                        if d2 < best:
                            best, found[q] = d2, j
            # Beyond this ring every point is at least ring x side away; past the grid, none is left.
            if np.sqrt(best) < ring * side or ring > max(x, y, columns - x, rows - y):
                break
            ring += 1
    return found


@numba.njit(cache=True, nogil=True)
def _nearest_within(uv, keys, order, starts, columns):
    """[M] distance from each point to its nearest other point in the 3 x 3 cells around it."""
    nearest = np.full(len(keys), np.inf)
    for i in range(len(keys)):
        for row in (-1, 0, 1):
            low = keys[i] + row * columns - 1
            for k in range(starts[low], starts[low + 3]):
                j = order[k]
                if j != i:
                    dx, dy = uv[i, 0] - uv[j, 0], uv[i, 1] - uv[j, 1]
                    nearest[i] = min(nearest[i], np.sqrt(dx * dx + dy * dy))
    return nearest
