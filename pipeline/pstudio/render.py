"""Median depth from splats, as Dynamic 3D Gaussians renders it, at chosen image points or at
every pixel centre.

Both paths run the same per-point loop (``_composite``) over the same depth-ordered splat
lists, so a pixel rendered alone equals that pixel of a full frame, bit for bit. Per point,
front to back from transmittance T = 1:

    alpha_i = opacity_i exp(-d^T conic_i d / 2), skipped when < 1/255;
    depth = z_i of the splat with T > 0.5 and T (1 - alpha_i) < 0.5 (T first drops below 0.5),
    and BACKGROUND_DEPTH_M where no splat does (T stays above 0.5, or lands on it exactly).

This is the rule of ``diff-gaussian-rasterization-w-depth`` (commit "updated to median depth"),
in float64 instead of float32. Its loop also caps alpha at 0.99 and stops before T would fall
below 1e-4; neither can change this depth: an alpha above 0.99 takes any T below 0.5, capped or
not, and while T > 0.5 the next T is above 0.5 x 0.01 > 1e-4.

Points are continuous pixel coordinates: pixel (i, j) covers [i, i + 1) x [j, j + 1) and is
rendered at its centre (i + 0.5, j + 0.5), as the rasterizer does (its ``ndc2Pix`` subtracts 0.5
from the projected centre and samples at integers).

Splats are binned into 16 x 16-pixel tiles first; only tiles that hold a requested point are
filled, which is what makes a few hundred points per frame cheap. A point then runs over the
splats of its tile whose footprint box meets its 4 x 4-pixel block (each tile's list cut once
per block holding points): a splat whose box misses the block has alpha below 1/255 at the
point and would be skipped anyway, so the cut changes no value, only the splats visited.
"""

from __future__ import annotations

import numba
import numpy as np

from pipeline.pstudio.splats import BLOCK, TILE, Splats2D, inside_image, point_tiles

BACKGROUND_DEPTH_M = 15.0  # the rasterizer's depth where transmittance never drops below 0.5


@numba.njit(cache=True)
def _tile_lists(xy, extent, conic, opacity, cutoff, depth, tiles_x, tiles_y, limit):
    """Per tile, the splats (in their depth order) whose footprint box meets it and that are no
    deeper than its ``limit`` [tiles] (-inf: a tile not wanted), each copied into its tile's list
    so that a tile's loop reads contiguous memory: (starts [tiles + 1], packed [E, 12]), a list
    entry being (u, v, a, b, c, opacity, z, the power below which alpha < 1/255, then the
    footprint box: u - extent x, u + extent x, v - extent y, v + extent y)."""
    n = xy.shape[0]
    ranges = np.empty((n, 4), np.int64)  # tile columns x0..x1, rows y0..y1 of each footprint
    for i in range(n):
        ranges[i, 0] = max(0, int(np.floor((xy[i, 0] - extent[i, 0]) / TILE)))
        ranges[i, 1] = min(tiles_x - 1, int(np.floor((xy[i, 0] + extent[i, 0]) / TILE)))
        ranges[i, 2] = max(0, int(np.floor((xy[i, 1] - extent[i, 1]) / TILE)))
        ranges[i, 3] = min(tiles_y - 1, int(np.floor((xy[i, 1] + extent[i, 1]) / TILE)))
    starts = np.zeros(tiles_x * tiles_y + 1, np.int64)
    for i in range(n):
        for ty in range(ranges[i, 2], ranges[i, 3] + 1):
            for tx in range(ranges[i, 0], ranges[i, 1] + 1):
                starts[ty * tiles_x + tx + 1] += depth[i] <= limit[ty * tiles_x + tx]
    starts = np.cumsum(starts)
    packed = np.empty((starts[-1], 12))
    fill = starts[:-1].copy()
    for i in range(n):
        for ty in range(ranges[i, 2], ranges[i, 3] + 1):
            for tx in range(ranges[i, 0], ranges[i, 1] + 1):
                tile = ty * tiles_x + tx
                if depth[i] <= limit[tile]:
                    k = fill[tile]
                    fill[tile] += 1
                    packed[k, 0], packed[k, 1] = xy[i, 0], xy[i, 1]
                    packed[k, 2], packed[k, 3], packed[k, 4] = conic[i, 0], conic[i, 1], conic[i, 2]
                    packed[k, 5], packed[k, 6], packed[k, 7] = opacity[i], depth[i], cutoff[i]
                    packed[k, 8], packed[k, 9] = xy[i, 0] - extent[i, 0], xy[i, 0] + extent[i, 0]
                    packed[k, 10], packed[k, 11] = xy[i, 1] - extent[i, 1], xy[i, 1] + extent[i, 1]
    return starts, packed


@numba.njit(cache=True)
def _block_lists(points, order, first, last, packed, start, end):
    """Cut a tile's list ``packed[start:end]`` for the blocks holding its points
    ``order[first:last]``: (slot [last - first] of each point's block, lists [S, end - start]
    and counts [S]: per slot, the offsets from ``start`` of the entries whose footprint box
    meets the block, in list order)."""
    corners = np.empty((last - first, 2))  # per slot: the block's left and top pixel edges
    slot = np.empty(last - first, np.int64)
    used = 0
    for q in range(first, last):
        p = order[q]
        left, top = np.floor(points[p, 0] / BLOCK) * BLOCK, np.floor(points[p, 1] / BLOCK) * BLOCK
        slot[q - first] = used
        for s in range(used):
            if corners[s, 0] == left and corners[s, 1] == top:
                slot[q - first] = s
        if slot[q - first] == used:
            corners[used, 0], corners[used, 1] = left, top
            used += 1
    lists = np.empty((used, end - start), np.int32)
    counts = np.zeros(used, np.int64)
    for k in range(start, end):
        for s in range(used):
            left, top = corners[s, 0], corners[s, 1]
            if (
                packed[k, 8] < left + BLOCK
                and packed[k, 9] >= left
                and packed[k, 10] < top + BLOCK
                and packed[k, 11] >= top
            ):
                lists[s, counts[s]] = k - start
                counts[s] += 1
    return slot, lists, counts


@numba.njit(cache=True)
def _composite(points, order, tiles, point_starts, starts, packed, out_depth, out_surface):
    """Median depth at each point over its block's list; the points of tile ``tiles[j]`` are
    ``order[point_starts[j]:point_starts[j + 1]]``. Once T <= 0.5 no later splat can set the
    depth, so the loop ends there."""
    for j in range(tiles.shape[0]):
        first, start = point_starts[j], starts[tiles[j]]
        slot, lists, counts = _block_lists(
            points, order, first, point_starts[j + 1], packed, start, starts[tiles[j] + 1]
        )
        for q in range(first, point_starts[j + 1]):
            p, s = order[q], slot[q - first]
            u, v = points[p, 0], points[p, 1]
            transmittance = 1.0
            out_depth[p], out_surface[p] = BACKGROUND_DEPTH_M, False
            for n in range(counts[s]):
                k = start + lists[s, n]
                dx, dy = packed[k, 0] - u, packed[k, 1] - v
                power = -0.5 * (packed[k, 2] * dx * dx + packed[k, 4] * dy * dy) - packed[k, 3] * dx * dy
                if power > 0.0 or power < packed[k, 7]:
                    continue
                alpha = packed[k, 5] * np.exp(power)
                if alpha < 1.0 / 255.0:
                    continue
                after = transmittance * (1.0 - alpha)
                if after < 0.5:  # here T > 0.5: the loop only goes on while it is
                    out_depth[p], out_surface[p] = packed[k, 6], True
                if after <= 0.5:
                    break
                transmittance = after


def render_depth_at(
    splats: Splats2D, points_uv: np.ndarray, limits: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Median depth at image points [P, 2] (continuous pixel coordinates).

    Returns (depth [P], surface [P] bool): depth is BACKGROUND_DEPTH_M where the transmittance
    never drops below 0.5 (surface False there) and NaN at points outside [0, width) x [0, height).

    limits: [P] depths beyond which a point's median depth is not wanted (a depth test that any
    farther surface fails). A point's splats deeper than its limit may be left out (a tile keeps
    those up to its points' largest limit): the depth is exact where it is within the limit, and
    where it lies beyond, the point may report no surface instead.
    """
    points = np.ascontiguousarray(points_uv, dtype=np.float64).reshape(-1, 2)
    tiles_x = -(-splats.width // TILE)
    tiles_y = -(-splats.height // TILE)
    inside = inside_image(points, splats.width, splats.height)
    inner = points[inside]
    point_tile = point_tiles(inner, splats.width)
    limit = np.full(tiles_x * tiles_y, -np.inf)
    if limits is None:
        limit[point_tile] = np.inf
    else:
        np.maximum.at(limit, point_tile, np.asarray(limits, dtype=np.float64).reshape(-1)[inside])
    # Contiguous fields (``project_splats``' are; others are copied): one compiled type of the kernel.
    columns = (splats.xy, splats.extent, splats.conic, splats.opacity, splats.cutoff, splats.depth)
    contiguous = [np.ascontiguousarray(column) for column in columns]
    starts, packed = _tile_lists(*contiguous, tiles_x, tiles_y, limit)
    order = np.argsort(point_tile, kind="stable")
    tiles, point_starts = np.unique(point_tile[order], return_index=True)
    point_starts = np.append(point_starts, len(order)).astype(np.int64)
    inner_depth = np.empty(len(inner))
    inner_surface = np.empty(len(inner), np.bool_)
    _composite(inner, order, tiles, point_starts, starts, packed, inner_depth, inner_surface)
    depth = np.full(len(points), np.nan)
    surface = np.zeros(len(points), np.bool_)
    depth[inside], surface[inside] = inner_depth, inner_surface
    return depth, surface


def render_depth_image(splats: Splats2D) -> tuple[np.ndarray, np.ndarray]:
    """Median depth [H, W] and surface [H, W] bool (``render_depth_at``) at every pixel centre
    (i + 0.5, j + 0.5)."""
    v, u = np.mgrid[0 : splats.height, 0 : splats.width]
    points = np.stack([u.ravel(), v.ravel()], axis=1) + 0.5
    depth, surface = render_depth_at(splats, points)
    return depth.reshape(splats.height, splats.width), surface.reshape(splats.height, splats.width)
