"""Depth from splats: front-to-back alpha compositing at chosen image points, or at every pixel.

Both paths run the same per-point loop (``_composite``) over the same depth-ordered splat
lists, so a pixel rendered alone equals that pixel of a full frame, bit for bit. Per point:

    alpha_i = min(0.99, opacity_i exp(-d^T conic_i d / 2)), skipped when < 1/255;
    stop before the splat that would bring the transmittance T below 1e-4;
    accumulated alpha A = sum alpha_i T_i;  depth = sum alpha_i T_i z_i / A,
    and no surface (NaN) where A < min_alpha.

Splats are binned into 16 x 16-pixel tiles first; only tiles that hold a requested point are
filled, which is what makes a few hundred points per frame cheap.
"""

from __future__ import annotations

import numba
import numpy as np

from pipeline.pstudio.splats import TILE, Splats2D, inside_image, point_tiles


@numba.njit(cache=True)
def _bin(xy, extent, tiles_x, tiles_y, wanted):
    """CSR lists of splat indices per tile, in the splats' (depth) order, for wanted tiles only."""
    n = xy.shape[0]
    counts = np.zeros(tiles_x * tiles_y + 1, np.int64)
    for stage in range(2):
        if stage == 1:
            starts = np.zeros(tiles_x * tiles_y + 1, np.int64)
            for k in range(tiles_x * tiles_y):
                starts[k + 1] = starts[k] + counts[k]
            entries = np.empty(starts[-1], np.int64)
            fill = starts[:-1].copy()
        for i in range(n):
            x0 = max(0, int(np.floor((xy[i, 0] - extent[i, 0]) / TILE)))
            x1 = min(tiles_x - 1, int(np.floor((xy[i, 0] + extent[i, 0]) / TILE)))
            y0 = max(0, int(np.floor((xy[i, 1] - extent[i, 1]) / TILE)))
            y1 = min(tiles_y - 1, int(np.floor((xy[i, 1] + extent[i, 1]) / TILE)))
            for ty in range(y0, y1 + 1):
                for tx in range(x0, x1 + 1):
                    tile = ty * tiles_x + tx
                    if wanted[tile]:
                        if stage == 0:
                            counts[tile] += 1
                        else:
                            entries[fill[tile]] = i
                            fill[tile] += 1
    return starts, entries


@numba.njit(cache=True)
def _pack(entries, xy, conic, opacity, depth):
    """Each tile list entry's splat, copied in list order: [E, 8] (u, v, a, b, c, opacity, z,
    the power below which alpha < 1/255), so a tile's loop reads contiguous memory."""
    packed = np.empty((entries.shape[0], 8))
    for k in range(entries.shape[0]):
        i = entries[k]
        packed[k, 0], packed[k, 1] = xy[i, 0], xy[i, 1]
        packed[k, 2], packed[k, 3], packed[k, 4] = conic[i, 0], conic[i, 1], conic[i, 2]
        packed[k, 5], packed[k, 6] = opacity[i], depth[i]
        packed[k, 7] = np.log(1.0 / (255.0 * opacity[i]))
    return packed


@numba.njit(parallel=True, cache=True)
def _composite(points, order, tiles, point_starts, starts, packed, out_weighted, out_alpha):
    """Front-to-back compositing at each point over its tile's splat list; the points of
    tile ``tiles[j]`` are ``order[point_starts[j]:point_starts[j + 1]]``."""
    for j in numba.prange(tiles.shape[0]):
        tile = tiles[j]
        for q in range(point_starts[j], point_starts[j + 1]):
            p = order[q]
            u, v = points[p, 0], points[p, 1]
            transmittance, weighted, accumulated = 1.0, 0.0, 0.0
            for k in range(starts[tile], starts[tile + 1]):
                dx, dy = packed[k, 0] - u, packed[k, 1] - v
                power = -0.5 * (packed[k, 2] * dx * dx + packed[k, 4] * dy * dy) - packed[k, 3] * dx * dy
                if power > 0.0 or power < packed[k, 7]:
                    continue
                alpha = min(0.99, packed[k, 5] * np.exp(power))
                if alpha < 1.0 / 255.0:
                    continue
                after = transmittance * (1.0 - alpha)
                if after < 1e-4:
                    break
                weighted += packed[k, 6] * alpha * transmittance
                accumulated += alpha * transmittance
                transmittance = after
            out_weighted[p] = weighted
            out_alpha[p] = accumulated


def render_depth_at(
    splats: Splats2D, points_uv: np.ndarray, min_alpha: float
) -> tuple[np.ndarray, np.ndarray]:
    """Depth and accumulated alpha at image points [P, 2] (continuous pixel coordinates).

    Returns (depth [P], alpha [P]); depth is NaN where alpha < min_alpha (no surface) and at
    points outside [0, width) x [0, height).
    """
    points = np.ascontiguousarray(points_uv, dtype=np.float64).reshape(-1, 2)
    tiles_x = -(-splats.width // TILE)
    tiles_y = -(-splats.height // TILE)
    inside = inside_image(points, splats.width, splats.height)
    inner = points[inside]
    point_tile = point_tiles(inner, splats.width)
    wanted = np.zeros(tiles_x * tiles_y, np.bool_)
    wanted[point_tile] = True
    starts, entries = _bin(splats.xy, splats.extent, tiles_x, tiles_y, wanted)
    packed = _pack(entries, splats.xy, splats.conic, splats.opacity, splats.depth)
    order = np.argsort(point_tile, kind="stable")
    tiles, point_starts = np.unique(point_tile[order], return_index=True)
    point_starts = np.append(point_starts, len(order)).astype(np.int64)
    weighted = np.zeros(len(inner))
    accumulated = np.zeros(len(inner))
    _composite(inner, order, tiles, point_starts, starts, packed, weighted, accumulated)
    depth = np.full(len(points), np.nan)
    alpha = np.zeros(len(points))
    alpha[inside] = accumulated
    with np.errstate(invalid="ignore", divide="ignore"):
        depth[inside] = np.where(accumulated >= min_alpha, weighted / accumulated, np.nan)
    return depth, alpha


def render_depth_image(splats: Splats2D, min_alpha: float) -> tuple[np.ndarray, np.ndarray]:
    """Full-frame depth [H, W] (NaN = no surface) and accumulated alpha [H, W], at pixel centres."""
    v, u = np.mgrid[0 : splats.height, 0 : splats.width]
    points = np.stack([u.ravel(), v.ravel()], axis=1).astype(np.float64)
    depth, alpha = render_depth_at(splats, points, min_alpha)
    return depth.reshape(splats.height, splats.width), alpha.reshape(splats.height, splats.width)
