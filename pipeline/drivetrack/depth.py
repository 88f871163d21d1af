"""The occlusion reference depth from projected lidar points.

The DriveTrack generator densified the projected lidar points into a full-image depth map by
nearest-neighbour interpolation (scipy's NearestNDInterpolator) and read, for a track point
at (u, v), the largest depth among the four integer pixels around it. ``nearest_depth_max4``
gives the same numbers by querying the nearest lidar point of just those four pixels, with
the same KD-tree, so no [H, W] map is ever built.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import NearestNDInterpolator
from scipy.spatial import cKDTree


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


def depth_tree(lidar_uv: np.ndarray) -> cKDTree:
    """The KD-tree ``nearest_depth_max4`` queries, of lidar pixels [M, 2]."""
    return cKDTree(np.asarray(lidar_uv, dtype=np.float64))


def nearest_depth_max4(
    lidar_uv: np.ndarray,
    lidar_depth: np.ndarray,
    query_uv: np.ndarray,
    width: int,
    height: int,
    tree: cKDTree | None = None,
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
    tree = depth_tree(lidar_uv) if tree is None else tree
    _, index = tree.query(np.stack([cols.ravel(), rows.ravel()], axis=1))
    return lidar_depth[index].reshape(-1, 4).max(axis=1)


def dense_nearest_depth(lidar_uv: np.ndarray, lidar_depth: np.ndarray, width: int, height: int) -> np.ndarray:
    """The generator's dense depth map [H, W]: nearest projected lidar depth at every pixel."""
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
    """
    if len(lidar_depth) <= neighbours:
        return np.zeros(len(lidar_depth), bool)
    tree = cKDTree(lidar_uv)
    distances, index = tree.query(lidar_uv, k=neighbours + 1)
    reach = 2.0 * np.median(distances[:, 1])
    nearer = lidar_depth[index[:, 1:]] < (1.0 - 2 * margin) * lidar_depth[:, None]
    return np.any(nearer & (distances[:, 1:] <= reach), axis=1)
