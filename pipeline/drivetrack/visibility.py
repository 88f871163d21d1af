"""Which (frame, track) pairs of a DriveTrack clip are visible: in view, facing the camera
(``drivetrack.facing_test``), and not occluded in the lidar's depth.

Occluded: the reference depth (the largest of the nearest lidar depths at the four integer pixels
around the track point) is < (1 - margin) x the track's depth. The DriveTrack generator densified
the projected lidar points into a full-image depth map by nearest-neighbour interpolation (scipy's
NearestNDInterpolator) and read, for a track point at (u, v), the largest depth among the four
integer pixels around it. ``nearest_depth_max4`` gives the same numbers by looking up the nearest
lidar point of just those four pixels in a grid of cells (``CellGrid``), so no [H, W] map is ever
built."""

from __future__ import annotations

import numba
import numpy as np
from scipy.spatial import cKDTree

from pipeline.core.visibility import passes_relative_depth_test


def facing_camera(tracks: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """[T, N] bool: the surface at track points [T, N, 3] (camera frame), of normals [T, N, 3]
    (camera frame), faces the camera."""
    cosine = np.einsum("tni,tni->tn", normals, -tracks) / np.linalg.norm(tracks, axis=2)
    return cosine > 0


def track_visibility(
    tracks: np.ndarray,
    uv: np.ndarray,
    in_view: np.ndarray,
    normals: np.ndarray | None,
    depth_uv: list[np.ndarray],
    depth_z: list[np.ndarray],
    depth_trees: list[CellGrid | None],
    image_size: tuple[int, int],
    occlusion_margin: float,
) -> np.ndarray:
    """Visibility [T, N] bool of track points [T, N, 3] (camera frame) appearing at uv [T, N, 2] in
    the stored frames of ``image_size`` (width, height), where ``in_view`` [T, N]
    (``camera_model.Projection``).

    normals: [T, N, 3] surface normals (camera frame), or None to skip the facing test.
    depth_uv, depth_z, depth_trees: per frame, the lidar depth samples' pixels [M, 2], depths [M]
    and the pixels' lookup (``depth.depth_tree``).
    """
    visibility = in_view.copy()
    if normals is not None:
        visibility &= facing_camera(tracks, normals)
    for i, (lidar_uv, lidar_z, tree) in enumerate(zip(depth_uv, depth_z, depth_trees, strict=True)):
        candidates = np.nonzero(visibility[i])[0]
        depth = nearest_depth_max4(lidar_uv, lidar_z, uv[i, candidates], *image_size, tree)
        visibility[i, candidates] = passes_relative_depth_test(
            tracks[i, candidates, 2], depth, occlusion_margin
        )
    return visibility


def _four_neighbours(query_uv: np.ndarray, width: int, height: int) -> tuple[np.ndarray, ...]:
    """Integer pixel columns and rows around query pixels [N, 2]: each [N, 4]."""
    u, v = query_uv[:, 0], query_uv[:, 1]
    u0 = np.clip(np.floor(u), 0, width - 1)
    u1 = np.clip(np.ceil(u), 0, width - 1)
    v0 = np.clip(np.floor(v), 0, height - 1)
    v1 = np.clip(np.ceil(v), 0, height - 1)
    cols = np.stack([u0, u1, u0, u1], axis=1)
    rows = np.stack([v0, v0, v1, v1], axis=1)
    return cols, rows


def depth_tree(lidar_uv: np.ndarray) -> CellGrid | None:
    """The lookup ``nearest_depth_max4`` queries: lidar pixels [M, 2] in cells of about their mean
    spacing (None without pixels)."""
    if len(lidar_uv) == 0:
        return None
    uv = np.ascontiguousarray(lidar_uv, np.float64)
    return CellGrid(uv, _mean_spacing(uv))


def _bounds(uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The lowest and highest (u, v) [2] of points [M, 2]: ``uv.min(axis=0)``, ``uv.max(axis=0)``,
    reduced over a transposed copy (NumPy's reduction across the rows of [M, 2] is far slower)."""
    columns = np.ascontiguousarray(uv.T)
    return columns.min(axis=1), columns.max(axis=1)


def _mean_spacing(uv: np.ndarray) -> float:
    """The spacing of points [M, 2] were they spread evenly over their bounding box."""
    low, high = _bounds(uv)
    spread = high - low
    return float(np.sqrt(max(spread[0] * spread[1], 1e-12) / len(uv)))


def nearest_depth_max4(
    lidar_uv: np.ndarray,
    lidar_depth: np.ndarray,
    query_uv: np.ndarray,
    width: int,
    height: int,
    tree: CellGrid | None = None,
) -> np.ndarray:
    """Reference depth [N] for query pixels [N, 2] from lidar pixels [M, 2] and depths [M].

    NaN where there is no lidar point in the image (no evidence either way). tree: ``depth_tree``
    of lidar_uv when the caller holds it (a frame's samples serve every clip of the unit).
    """
    if len(lidar_depth) == 0:
        return np.full(len(query_uv), np.nan)
    if len(query_uv) == 0:
        return np.zeros(0)
    cols, rows = _four_neighbours(query_uv, width, height)
    grid = depth_tree(lidar_uv) if tree is None else tree
    assert grid is not None, "lidar_depth is not empty"
    index = grid.nearest(np.stack([cols.ravel(), rows.ravel()], axis=1))
    return lidar_depth[index].reshape(-1, 4).max(axis=1)


def dense_nearest_depth(lidar_uv: np.ndarray, lidar_depth: np.ndarray, width: int, height: int) -> np.ndarray:
    """The generator's dense depth map [H, W]: nearest projected lidar depth at every pixel."""
    from scipy.interpolate import NearestNDInterpolator  # the generator's reference only: 1.3 s to import

    interpolator = NearestNDInterpolator(np.asarray(lidar_uv, dtype=np.float64), lidar_depth)
    cols, rows = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    return interpolator(cols, rows)


def max4_from_dense(dense: np.ndarray, query_uv: np.ndarray) -> np.ndarray:
    """The generator's lookup: largest of the four integer pixels around each query [N]."""
    height, width = dense.shape
    cols, rows = _four_neighbours(query_uv, width, height)
    return dense[rows.astype(np.int64), cols.astype(np.int64)].max(axis=1)


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

    Computed on grids of cells (``CellGrid``), not with a KD-tree query of each point's
    ``neighbours`` nearest: the same distances and the same test (only neighbours within the
    spacing count), at a fraction of the cost; where two points share a position exactly, each
    is the other's neighbour (the tree's query dropped one of the two as the point itself).
    """
    if len(lidar_depth) <= neighbours:
        return np.zeros(len(lidar_depth), bool)
    uv = np.ascontiguousarray(lidar_uv, np.float64)
    low, high = _bounds(uv)
    side, extent = _mean_spacing(uv), np.hypot(*(high - low))
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
        low, high = _bounds(uv)
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


@numba.njit(cache=True, nogil=True)
def _hidden_within(uv, depth, keys, order, starts, columns, reach, neighbours, margin):
    """[M] bool: point i has, among its ``neighbours`` nearest other points, one within ``reach``
    (Euclidean, as the KD-tree measures it) whose depth is below (1 - 2 margin) x its own.

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
