"""Depth-test visibility on ADT's stored frames (paper eq. 4): a point is visible when it is in
front of the camera, inside the image, within ``delta`` of the re-rendered depth there and not on
the wearer's pixels. Pixel centres at +0.5: pixel [r, c] covers [c, c+1) x [r, r+1)."""

from __future__ import annotations

import numpy as np

from pipeline.adt.records import DepthMetres, IdRuns
from pipeline.core.geometry import in_image, project
from pipeline.core.visibility import passes_dense_depth_test


def pixel_centres(rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Continuous coordinates [N, 2] (x, y) of pixel centres."""
    return np.stack([cols + 0.5, rows + 0.5], axis=-1).astype(np.float64)


def pixel_at(xy: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols) [N] of the pixels containing points [N, 2] (clamped into the image)."""
    cols = np.clip(np.floor(xy[:, 0]), 0, size - 1).astype(np.int64)
    rows = np.clip(np.floor(xy[:, 1]), 0, size - 1).astype(np.int64)
    return rows, cols


def sample_depth(depth: np.ndarray | DepthMetres, xy: np.ndarray, max_spread: float = np.inf) -> np.ndarray:
    """Depth [N] at continuous points [N, 2] of a depth image [H, W] (an array, or ``DepthMetres``
    converting only the pixels read): bilinear between the four nearest pixel centres
    when all four hold a surface and differ by at most ``max_spread`` (one surface, not an
    edge between two), else the containing pixel's value; NaN where there is none.

    At a pixel centre it returns that pixel's value exactly.
    """
    size_y, size_x = depth.shape
    x, y = xy[:, 0] - 0.5, xy[:, 1] - 0.5
    x0 = np.clip(np.floor(x), 0, size_x - 1).astype(np.int64)
    y0 = np.clip(np.floor(y), 0, size_y - 1).astype(np.int64)
    x1, y1 = np.minimum(x0 + 1, size_x - 1), np.minimum(y0 + 1, size_y - 1)
    fx, fy = np.clip(x - x0, 0.0, 1.0), np.clip(y - y0, 0.0, 1.0)
    d00, d01 = depth[y0, x0].astype(np.float64), depth[y0, x1].astype(np.float64)
    d10, d11 = depth[y1, x0].astype(np.float64), depth[y1, x1].astype(np.float64)
    bilinear = d00 * (1 - fx) * (1 - fy) + d01 * fx * (1 - fy) + d10 * (1 - fx) * fy + d11 * fx * fy
    rows, cols = pixel_at(xy, size_x)
    nearest = depth[rows, cols].astype(np.float64)
    corners = np.stack([d00, d01, d10, d11])
    complete = (corners.min(axis=0) > 0) & (corners.max(axis=0) - corners.min(axis=0) <= max_spread)
    out = np.where(complete, bilinear, nearest)
    return np.where(out > 0, out, np.nan)


def interior(ids: np.ndarray) -> np.ndarray:
    """[S, S] bool: pixels whose 3x3 neighbourhood (inside the image) holds one id (their depth
    is not a blend of two surfaces: the re-rendering interpolates depth bilinearly across edges).

    Each of the 4 neighbour directions is compared once; both pixels of an unequal pair fail.
    """
    height, width = ids.shape
    same = np.ones(ids.shape, bool)
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        here = (slice(0, height - dr), slice(max(0, -dc), width - max(0, dc)))
        there = (slice(dr, height), slice(max(0, dc), width + min(0, dc)))
        equal = ids[here] == ids[there]
        same[here] &= equal
        same[there] &= equal
    return same


def frame_visibility(
    points_cam: np.ndarray,
    object_ids: np.ndarray,
    depth: np.ndarray | DepthMetres,
    ids: np.ndarray | IdRuns,
    human_ids: frozenset[int],
    fx_fy_cx_cy: np.ndarray,
    delta: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Visibility (paper eq. 4) and own-id agreement of N points at one frame.

    Args:
      points_cam: [N, 3] stored-camera points; object_ids: [N] each point's object.
      depth: [S, S] metres (an array or ``DepthMetres``); ids: [S, S] instance ids (an array or
        ``IdRuns``); human_ids: the wearer's ids (the hand term).
    Returns:
      visible: [N] bool, in front, inside the image, |z - D(u, v)| < delta, not on a human pixel.
        D is bilinear where the four pixels around (u, v) agree within delta, else the
        containing pixel's depth (no blending across a depth edge).
      on_own_id: [N] bool, the id at the point's pixel is its own object's.
    """
    size = depth.shape[1]
    xy = project(points_cam, fx_fy_cx_cy)
    inside = (points_cam[:, 2] > 0) & in_image(xy, size, depth.shape[0])
    visible = np.zeros(len(points_cam), bool)
    on_own = np.zeros(len(points_cam), bool)
    if not inside.any():
        return visible, on_own
    xy_in = xy[inside]
    rows, cols = pixel_at(xy_in, size)
    pixel_ids = ids[rows, cols]
    surface = sample_depth(depth, xy_in, max_spread=delta)
    close = passes_dense_depth_test(points_cam[inside, 2], surface, delta)
    not_human = ~np.isin(pixel_ids, list(human_ids)) if human_ids else np.ones(len(rows), bool)
    visible[inside] = close & not_human
    on_own[inside] = pixel_ids == object_ids[inside]
    return visible, on_own
