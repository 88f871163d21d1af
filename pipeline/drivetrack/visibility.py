"""Which (frame, track) pairs of a DriveTrack clip are visible: in view, facing the camera
(``drivetrack.facing_test``), and not occluded in the lidar's depth.

Occluded: the reference depth (the largest of the nearest lidar depths at the four integer pixels
around the track point) is < (1 - margin) x the track's depth. The DriveTrack generator densified
the projected lidar points into a full-image depth map by nearest-neighbour interpolation (scipy's
NearestNDInterpolator) and read, for a track point at (u, v), the largest depth among the four
integer pixels around it. ``nearest_depth_max4`` gives the same numbers by looking up the nearest
lidar point of just those four pixels in a grid of cells (``cell_grid.CellGrid``), so no [H, W] map
is ever built."""

from __future__ import annotations

import numpy as np

from pipeline.core.visibility import passes_relative_depth_test
from pipeline.drivetrack.cell_grid import CellGrid, mean_spacing


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
    depth_grids: list[CellGrid | None],
    image_size: tuple[int, int],
    occlusion_margin: float,
) -> np.ndarray:
    """Visibility [T, N] bool of track points [T, N, 3] (camera frame) appearing at uv [T, N, 2] in
    the stored frames of ``image_size`` (width, height), where ``in_view`` [T, N]
    (``camera_model.Projection``).

    normals: [T, N, 3] surface normals (camera frame), or None to skip the facing test.
    depth_uv, depth_z, depth_grids: per frame, the lidar depth samples' pixels [M, 2], depths [M]
    and the pixels' lookup (``depth_grid``).
    """
    visibility = in_view.copy()
    if normals is not None:
        visibility &= facing_camera(tracks, normals)
    for i, (lidar_uv, lidar_z, grid) in enumerate(zip(depth_uv, depth_z, depth_grids, strict=True)):
        candidates = np.nonzero(visibility[i])[0]
        depth = nearest_depth_max4(lidar_uv, lidar_z, uv[i, candidates], *image_size, grid)
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


def depth_grid(lidar_uv: np.ndarray) -> CellGrid | None:
    """The lookup ``nearest_depth_max4`` queries: lidar pixels [M, 2] in cells of about their mean
    spacing (``cell_grid.CellGrid``; None without pixels)."""
    if len(lidar_uv) == 0:
        return None
    uv = np.ascontiguousarray(lidar_uv, np.float64)
    return CellGrid(uv, mean_spacing(uv))


def nearest_depth_max4(
    lidar_uv: np.ndarray,
    lidar_depth: np.ndarray,
    query_uv: np.ndarray,
    width: int,
    height: int,
    grid: CellGrid | None = None,
) -> np.ndarray:
    """Reference depth [N] for query pixels [N, 2] from lidar pixels [M, 2] and depths [M].

    NaN where there is no lidar point in the image (no evidence either way). grid: ``depth_grid``
    of lidar_uv when the caller holds it (a frame's samples serve every clip of the unit).
    """
    if len(lidar_depth) == 0:
        return np.full(len(query_uv), np.nan)
    if len(query_uv) == 0:
        return np.zeros(0)
    cols, rows = _four_neighbours(query_uv, width, height)
    grid = depth_grid(lidar_uv) if grid is None else grid
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
