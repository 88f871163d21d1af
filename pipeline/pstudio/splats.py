"""3D Gaussian Splatting projection (Kerbl et al. 2023, EWA splatting) of one frame into one camera.

The maths of the reference CUDA rasterizer's preprocessing, in float64:

- view-space centre p = W m + t; culled when p_z <= 0.2 (the rasterizer's frustum test);
- Sigma = R S S^T R^T from the quaternion (w, x, y, z) normalised as torch's ``normalize`` does,
  q / max(|q|, 1e-12) (a zero quaternion stays zero: R is the identity), and the scales;
- Sigma' = J W Sigma W^T J^T with the perspective Jacobian J at p, whose x/z and y/z are clamped
  to 1.3 x the half field of view; then 0.3 px^2 added to the diagonal (low-pass filter);
- conic = Sigma'^-1; a splat with det(Sigma') = 0 is dropped.

One deliberate difference: a splat's screen footprint is the exact ellipse where its alpha
reaches 1/255 (the compositing cut-off), not the rasterizer's 3-sigma square rounded to
16-pixel tiles. A pixel's value then depends on no tiling: it equals compositing over all
Gaussians (tests/pstudio/test_render.py checks this against a brute-force reference).

What no frame changes (scales, opacities and what follows from them) is computed once per
sequence (``gaussian_constants``); per frame, only the means and rotations are read (float32 as
stored, or float64). When depth is wanted at some points, a splat is dropped on its projected
centre and a bound of its footprint (its largest scale, whatever its rotation) before its
covariance is computed: only the splats that can reach a BLOCK x BLOCK-pixel block holding one
of the points are projected in full, and of those, the ones whose footprint does are kept; with a
depth limit per point, only those no deeper than the largest limit of a block their footprint
covers (a track's depth test never needs a splat deeper than its own limit, so the frame's single
deepest limit would keep far more splats than any track reads). The bound of every splat is
tested against the blocks' summed-area table, or, when they are few (FEW_BLOCKS), against their
list.

The kernels (here and in render.py) are serial: the pipeline's parallelism is across units, one
single-threaded worker per core. On one thread numba's parallel loops are no faster, and they take
about three times as long to compile.

Pixel convention: TAP-Vid's (docs/formats.md), as the reference rasterizer's: u = fx x / z + cx
is a continuous coordinate, pixel (i, j) covers [i, i + 1) x [j, j + 1) and its centre is
(i + 0.5, j + 0.5).
"""

from __future__ import annotations

import dataclasses

import numba
import numpy as np

from pipeline.core.kernel_arrays import read_only
from pipeline.pstudio.records import GaussianConstants

TILE = 16  # pixels per side of the square tiles splats are binned into
BLOCK = 4  # pixels per side of the blocks a point's splat list is cut to (TILE / BLOCK blocks a side)
CHUNK = 1024  # splats bounded together before their boxes are tested (_candidates)
PREPROCESS_CHUNK = 128  # candidates projected together (_preprocess): their columns stay in L1
# The widest box (blocks a side) tested against depth limits, 2 x 4 - 1: block_limits' windows are
# 1, 2 and 4 blocks a side, and two cover a box's side. A wider box is kept untested.
LIMIT_BOX_BLOCKS = 7
# Up to this many wanted blocks, the cull compares each box with the blocks' list (16 boxes at a
# time, ``_boxes_meet_blocks``) instead of reading the summed-area table (four gathers a box): the
# bench's 300,000 splats are culled in 2.1 ms for one block and 4.4 ms for 48, against 5.7 ms with
# the table (the two meet near 75), as when a frame's few query pixels are attached.
FEW_BLOCKS = 64


@numba.njit(cache=True)
def _reach_and_variance(scales, opacity, reach, max_variance, cutoff):
    for i in range(opacity.shape[0]):
        reach[i] = 2.0 * np.log(255.0 * opacity[i])
        largest = max(scales[i, 0], scales[i, 1], scales[i, 2])
        max_variance[i] = largest * largest
        cutoff[i] = np.log(1.0 / (255.0 * opacity[i]))


def gaussian_constants(scales: np.ndarray, opacities: np.ndarray) -> GaussianConstants:
    """The constants of Gaussians with scales [N, 3] (standard deviations along the local axes)
    and opacities [N] in [0, 1]."""
    scales = np.ascontiguousarray(scales, dtype=np.float64)
    opacity = np.ascontiguousarray(opacities, dtype=np.float64)
    reach, max_variance, cutoff = np.empty(len(opacity)), np.empty(len(opacity)), np.empty(len(opacity))
    _reach_and_variance(scales, opacity, reach, max_variance, cutoff)
    return GaussianConstants(scales, opacity, reach, max_variance, cutoff)


@dataclasses.dataclass
class Splats2D:
    """Splats of one frame seen by one camera, culled and sorted front to back (M of them), each
    field an array of its own (``project_splats``' are C-contiguous, as the render kernels read them).

    xy: [M, 2] projected centres (pixels). conic: [M, 3] (a, b, c) of the inverse 2D
    covariance. opacity: [M]. cutoff: [M] ``GaussianConstants.cutoff``. depth: [M] view-space z
    of the centre (metres).
    extent: [M, 2] half-width and half-height of the 1/255 footprint's bounding box (pixels).
    index: [M] index of each splat in the input arrays.
    """

    xy: np.ndarray
    conic: np.ndarray
    opacity: np.ndarray
    cutoff: np.ndarray
    depth: np.ndarray
    extent: np.ndarray
    index: np.ndarray
    width: int
    height: int

    def __len__(self) -> int:
        return len(self.depth)


@numba.njit(cache=True, error_model="numpy")
def _boxes_reach(u, v, ext_x, ext_y, width, height, wanted, flags):
    """flags[k] = the box k [u +- ext_x] x [v +- ext_y] (centres u, v [M], half sizes ext_x, ext_y
    [M], finite) meets the image and a wanted block (``wanted``: ``wanted_blocks``' summed-area
    table). Without branches: the block range clamped to the table (a box off the image is refused
    by its own test), so that mispredicted tests cost nothing. (Not vectorised: the four table
    reads are gathers; a vectorised pass for the block corners and a scalar one for the reads is
    no faster.)"""
    last_x, last_y = wanted.shape[1] - 2, wanted.shape[0] - 2
    for k in range(u.shape[0]):
        left, right, top, bottom = u[k] - ext_x[k], u[k] + ext_x[k], v[k] - ext_y[k], v[k] + ext_y[k]
        inside = (right >= 0) & (left < width) & (bottom >= 0) & (top < height)
        x0 = int(np.floor(min(max(left / BLOCK, 0.0), last_x)))
        x1 = int(np.floor(min(max(right / BLOCK, 0.0), last_x))) + 1
        y0 = int(np.floor(min(max(top / BLOCK, 0.0), last_y)))
        y1 = int(np.floor(min(max(bottom / BLOCK, 0.0), last_y))) + 1
        flags[k] = inside & (wanted[y1, x1] - wanted[y0, x1] - wanted[y1, x0] + wanted[y0, x0] > 0)


@numba.njit(cache=True, error_model="numpy")
def _boxes_meet_blocks(u, v, ext_x, ext_y, width, height, last_x, last_y, blocks, corners, flags):
    """flags[k] as ``_boxes_reach`` sets it, from the list of the wanted blocks (``blocks`` [2, B]
    int16: their columns, then their rows; ``few_blocks``) instead of the table: the box's block
    range, clamped to columns 0 .. ``last_x`` and rows 0 .. ``last_y`` as there, compared with every
    block, all boxes at once (as int16, 16 at a time). ``corners`` [5, >= M] int16: scratch. (The
    range is truncated, not floored: it is clamped to 0 first, so the two agree.)"""
    count = u.shape[0]
    x0, x1, y0, y1 = corners[0, :count], corners[1, :count], corners[2, :count], corners[3, :count]
    hits = corners[4, :count]
    for k in range(count):
        left, right, top, bottom = u[k] - ext_x[k], u[k] + ext_x[k], v[k] - ext_y[k], v[k] + ext_y[k]
        inside = (right >= 0) & (left < width) & (bottom >= 0) & (top < height)
        x0[k] = np.int16(min(max(left / BLOCK, 0.0), last_x))
        x1[k] = np.int16(min(max(right / BLOCK, 0.0), last_x)) + np.int16(1) if inside else np.int16(-1)
        y0[k] = np.int16(min(max(top / BLOCK, 0.0), last_y))
        y1[k] = np.int16(min(max(bottom / BLOCK, 0.0), last_y)) + np.int16(1)
        hits[k] = 0
    for b in range(blocks.shape[1]):
        column, row = blocks[0, b], blocks[1, b]
        for k in range(count):
            hits[k] |= np.int16((x0[k] <= column) & (column < x1[k]) & (y0[k] <= row) & (row < y1[k]))
    for k in range(count):
        flags[k] = hits[k] != 0


@numba.njit(cache=True, error_model="numpy")
def _boxes_within_limits(u, v, ext_x, ext_y, depth, limits, flags):
    """Where flags[k] (the box k [u +- ext_x] x [v +- ext_y] meets the image and a wanted block):
    flags[k] = one of the blocks it covers has a depth limit no shallower than depth[k], read as
    the largest of four windows of ``block_limits`` [3, 3, blocks_y, blocks_x] (2^kx x 2^ky
    blocks, the largest that fit, from the box's corners); a box wider than LIMIT_BOX_BLOCKS
    blocks either way stays flagged."""
    last_x, last_y = limits.shape[3] - 1, limits.shape[2] - 1
    for k in range(u.shape[0]):
        x0 = int(np.floor(min(max((u[k] - ext_x[k]) / BLOCK, 0.0), last_x)))
        x1 = int(np.floor(min(max((u[k] + ext_x[k]) / BLOCK, 0.0), last_x)))
        y0 = int(np.floor(min(max((v[k] - ext_y[k]) / BLOCK, 0.0), last_y)))
        y1 = int(np.floor(min(max((v[k] + ext_y[k]) / BLOCK, 0.0), last_y)))
        if not flags[k] or x1 - x0 >= LIMIT_BOX_BLOCKS or y1 - y0 >= LIMIT_BOX_BLOCKS:
            continue
        kx = (x1 - x0 >= 1) + (x1 - x0 >= 3)  # floor(log2(blocks across))
        ky = (y1 - y0 >= 1) + (y1 - y0 >= 3)
        x2, y2 = x1 + 1 - (1 << kx), y1 + 1 - (1 << ky)
        window = limits[ky, kx]
        deepest = max(max(window[y0, x0], window[y0, x2]), max(window[y2, x0], window[y2, x2]))
        flags[k] = deepest >= depth[k]


@numba.njit(cache=True, error_model="numpy")
def _footprint_boxes(
    xs,
    ys,
    zs,
    opacity,
    reach,
    max_variance,
    w2c,
    intrinsics,
    width,
    height,
    max_depth,
    u,
    v,
    half_width,
    half_height,
):
    """Per splat (centres xs, ys, zs [M], float64) a box holding its footprint
    (``_candidates``): centre u, v [M], half_width, half_height [M]; a box far off the image
    (u = -1e30) when it is culled: behind the near plane or deeper than ``max_depth``,
    transparent or not finite.

    Without branches, over columns: LLVM runs it four splats at a time (AVX2). (Rows of [M, 3]
    and a Python error model, which checks every division for zero, kept it one at a time, at
    twice the time; the numbers are the same, each operation being rounded the same way.)"""
    fx, fy, cx, cy = intrinsics[0], intrinsics[1], intrinsics[2], intrinsics[3]
    lim_x = 1.3 * 0.5 * width / fx
    lim_y = 1.3 * 0.5 * height / fy
    # |g|^2 for g = j00 W_0 + j02 W_2 (rows of W's rotation) is j00^2 |W_0|^2 + 2 j00 j02 W_0.W_2
    # + j02^2 |W_2|^2: these products once, not per splat (rounding covered by the widening).
    n0 = w2c[0, 0] * w2c[0, 0] + w2c[0, 1] * w2c[0, 1] + w2c[0, 2] * w2c[0, 2]
    n1 = w2c[1, 0] * w2c[1, 0] + w2c[1, 1] * w2c[1, 1] + w2c[1, 2] * w2c[1, 2]
    n2 = w2c[2, 0] * w2c[2, 0] + w2c[2, 1] * w2c[2, 1] + w2c[2, 2] * w2c[2, 2]
    d02 = 2.0 * (w2c[0, 0] * w2c[2, 0] + w2c[0, 1] * w2c[2, 1] + w2c[0, 2] * w2c[2, 2])
    d12 = 2.0 * (w2c[1, 0] * w2c[2, 0] + w2c[1, 1] * w2c[2, 1] + w2c[1, 2] * w2c[2, 2])
    for k in range(xs.shape[0]):
        mx, my, mz = xs[k], ys[k], zs[k]
        pz = w2c[2, 0] * mx + w2c[2, 1] * my + w2c[2, 2] * mz + w2c[2, 3]
        px = w2c[0, 0] * mx + w2c[0, 1] * my + w2c[0, 2] * mz + w2c[0, 3]
        py = w2c[1, 0] * mx + w2c[1, 1] * my + w2c[1, 2] * mz + w2c[1, 3]
        live = (pz > 0.2) & (pz <= max_depth) & (opacity[k] >= 1.0 / 255.0) & np.isfinite(px + py + pz)
        inverse = 1.0 / pz if live else 1.0
        x, y = px * inverse if live else 0.0, py * inverse if live else 0.0
        tx, ty = -min(lim_x, max(-lim_x, x)), -min(lim_y, max(-lim_y, y))  # j02 / j00, j12 / j11
        g = fx * fx * inverse * inverse * (n0 + tx * (d02 + tx * n2))
        h = fy * fy * inverse * inverse * (n1 + ty * (d12 + ty * n2))
        spread = reach[k] if live else 0.0
        u[k] = fx * x + cx if live else -1e30
        v[k] = fy * y + cy
        half_width[k] = np.sqrt(spread * (max_variance[k] * g + 0.3)) * (1 + 1e-6) + 1e-6
        half_height[k] = np.sqrt(spread * (max_variance[k] * h + 0.3)) * (1 + 1e-6) + 1e-6


@numba.njit(cache=True)
def _candidates(
    means, opacity, reach, max_variance, w2c, intrinsics, width, height, max_depth, wanted, few, flags
):
    """flags[i] = splat i, no deeper than ``max_depth``, may meet a wanted block (``wanted``:
    ``wanted_blocks``; ``few``: ``few_blocks``, their list when they are few, else empty), from its
    centre (means [N, 3], float32 or float64) and a bound of its footprint: Sigma'_xx = |g R S|^2 +
    0.3 <= max_variance |g|^2 + 0.3 with g = row 0 of J W (R a rotation), likewise Sigma'_yy;
    widened by 1e-6 for rounding.

    Chunk by chunk: the chunk's centres copied into columns (in L1, as the vectorised bounds want
    them), then the boxes (``_footprint_boxes``), then their tests (``_boxes_meet_blocks`` on the
    list, else ``_boxes_reach`` on the table). (In one loop with the test, each mispredicted test
    waits on a division and a square root: about three times slower.)"""
    xs, ys, zs = np.empty(CHUNK), np.empty(CHUNK), np.empty(CHUNK)
    u, v, half_width, half_height = np.empty(CHUNK), np.empty(CHUNK), np.empty(CHUNK), np.empty(CHUNK)
    corners = np.empty((5, CHUNK), np.int16)
    last_x, last_y = wanted.shape[1] - 2, wanted.shape[0] - 2
    for chunk in range((means.shape[0] + CHUNK - 1) // CHUNK):
        first, last = chunk * CHUNK, min((chunk + 1) * CHUNK, means.shape[0])
        count = last - first
        for j in range(count):
            xs[j], ys[j], zs[j] = means[first + j, 0], means[first + j, 1], means[first + j, 2]
        _footprint_boxes(
            xs[:count],
            ys[:count],
            zs[:count],
            opacity[first:last],
            reach[first:last],
            max_variance[first:last],
            w2c,
            intrinsics,
            width,
            height,
            max_depth,
            u[:count],
            v[:count],
            half_width[:count],
            half_height[:count],
        )
        if few.shape[1]:
            _boxes_meet_blocks(
                u[:count],
                v[:count],
                half_width[:count],
                half_height[:count],
                width,
                height,
                last_x,
                last_y,
                few,
                corners,
                flags[first:last],
            )
        else:
            _boxes_reach(
                u[:count],
                v[:count],
                half_width[:count],
                half_height[:count],
                width,
                height,
                wanted,
                flags[first:last],
            )


@numba.njit(cache=True, error_model="numpy")
def _covariances(columns, count, w2c, intrinsics, width, height, out):
    """Columns 0..count of ``columns`` [11, C] (rows: mean x, y, z, quaternion w, x, y, z, scale x,
    y, z, reach; float64) -> rows of ``out`` [9, C]: u, v, Sigma'_xx, Sigma'_xy, Sigma'_yy, z, -,
    -, det(Sigma'). Without branches over columns, so that LLVM runs it four splats at a time."""
    fx, fy, cx, cy = intrinsics[0], intrinsics[1], intrinsics[2], intrinsics[3]
    lim_x = 1.3 * 0.5 * width / fx
    lim_y = 1.3 * 0.5 * height / fy
    w00, w01, w02, w03 = w2c[0, 0], w2c[0, 1], w2c[0, 2], w2c[0, 3]
    w10, w11, w12, w13 = w2c[1, 0], w2c[1, 1], w2c[1, 2], w2c[1, 3]
    w20, w21, w22, w23 = w2c[2, 0], w2c[2, 1], w2c[2, 2], w2c[2, 3]
    for k in range(count):
        mx, my, mz = columns[0, k], columns[1, k], columns[2, k]
        px = w00 * mx + w01 * my + w02 * mz + w03
        py = w10 * mx + w11 * my + w12 * mz + w13
        pz = w20 * mx + w21 * my + w22 * mz + w23
        tx = min(lim_x, max(-lim_x, px / pz)) * pz
        ty = min(lim_y, max(-lim_y, py / pz)) * pz
        j00, j02 = fx / pz, -fx * tx / (pz * pz)
        j11, j12 = fy / pz, -fy * ty / (pz * pz)
        qw, qx, qy, qz = columns[3, k], columns[4, k], columns[5, k], columns[6, k]
        # As torch.nn.functional.normalize (Dynamic 3D Gaussians' renderer): q / max(|q|, 1e-12).
        norm = max(np.sqrt(qw * qw + qx * qx + qy * qy + qz * qz), 1e-12)
        qw, qx, qy, qz = qw / norm, qx / norm, qy / norm, qz / norm
        r00, r01, r02 = 1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qw * qz), 2 * (qx * qz + qw * qy)
        r10, r11, r12 = 2 * (qx * qy + qw * qz), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qw * qx)
        r20, r21, r22 = 2 * (qx * qz - qw * qy), 2 * (qy * qz + qw * qx), 1 - 2 * (qx * qx + qy * qy)
        sx, sy, sz = columns[7, k], columns[8, k], columns[9, k]
        # M = W R S (columns scaled), so that Sigma' = J M M^T J^T.
        m00 = (w00 * r00 + w01 * r10 + w02 * r20) * sx
        m01 = (w00 * r01 + w01 * r11 + w02 * r21) * sy
        m02 = (w00 * r02 + w01 * r12 + w02 * r22) * sz
        m10 = (w10 * r00 + w11 * r10 + w12 * r20) * sx
        m11 = (w10 * r01 + w11 * r11 + w12 * r21) * sy
        m12 = (w10 * r02 + w11 * r12 + w12 * r22) * sz
        m20 = (w20 * r00 + w21 * r10 + w22 * r20) * sx
        m21 = (w20 * r01 + w21 * r11 + w22 * r21) * sy
        m22 = (w20 * r02 + w21 * r12 + w22 * r22) * sz
        a0, a1, a2 = j00 * m00 + j02 * m20, j00 * m01 + j02 * m21, j00 * m02 + j02 * m22
        b0, b1, b2 = j11 * m10 + j12 * m20, j11 * m11 + j12 * m21, j11 * m12 + j12 * m22
        cov_a = a0 * a0 + a1 * a1 + a2 * a2 + 0.3
        cov_b = a0 * b0 + a1 * b1 + a2 * b2
        cov_c = b0 * b0 + b1 * b1 + b2 * b2 + 0.3
        out[0, k], out[1, k] = fx * px / pz + cx, fy * py / pz + cy
        out[2, k], out[3, k], out[4, k] = cov_a, cov_b, cov_c
        out[5, k], out[8, k] = pz, cov_a * cov_c - cov_b * cov_b


@numba.njit(cache=True, error_model="numpy")
def _conics(columns, count, out):
    """``_covariances``' rows of ``out`` [9, C] -> rows 2-4 the conic (a, b, c) = Sigma'^-1 and
    rows 6-7 the box half sizes of the ellipse where alpha reaches 1/255, d^T Sigma'^-1 d <=
    reach = 2 ln(255 opacity) (``columns`` row 10). A loop of its own: with all nine outputs
    written in one loop, LLVM did not vectorise it."""
    for k in range(count):
        cov_a, cov_b, cov_c, det = out[2, k], out[3, k], out[4, k], out[8, k]
        out[6, k] = np.sqrt(columns[10, k] * cov_a) * (1 + 1e-9) + 1e-9
        out[7, k] = np.sqrt(columns[10, k] * cov_c) * (1 + 1e-9) + 1e-9
        out[2, k], out[3, k], out[4, k] = cov_c / det, -cov_b / det, cov_a / det


@numba.njit(cache=True)
def _preprocess(
    candidates,
    means,
    quaternions,
    scales,
    opacity,
    reach,
    cutoff,
    w2c,
    intrinsics,
    width,
    height,
    wanted,
    limits,
    out,
    keep,
):
    """Per candidate k (splat i = candidates[k]): out[k] = (u, v, conic a, b, c, z, extent x,
    extent y, opacity, cutoff); keep[k] = det(Sigma') > 0 and its footprint meets a wanted block
    whose limit (``limits``: ``block_limits``, or None) is no shallower than z.
    Means [N, 3] and quaternions [N, 4] may be float32 (read as float64).

    PREPROCESS_CHUNK candidates at a time: gathered into columns, projected by the vectorised
    ``_covariances`` and ``_conics``, their boxes tested by ``_boxes_reach``, then written out
    (one loop writing all nine outputs is not vectorised by LLVM; two kernels are, four splats
    side by side)."""
    columns = np.empty((11, PREPROCESS_CHUNK))
    rows = np.empty((9, PREPROCESS_CHUNK))
    reaches = np.empty(PREPROCESS_CHUNK, np.bool_)
    for first in range(0, candidates.shape[0], PREPROCESS_CHUNK):
        count = min(PREPROCESS_CHUNK, candidates.shape[0] - first)
        for j in range(count):
            i = candidates[first + j]
            columns[0, j], columns[1, j], columns[2, j] = means[i, 0], means[i, 1], means[i, 2]
            columns[3, j], columns[4, j] = quaternions[i, 0], quaternions[i, 1]
            columns[5, j], columns[6, j] = quaternions[i, 2], quaternions[i, 3]
            columns[7, j], columns[8, j], columns[9, j] = scales[i, 0], scales[i, 1], scales[i, 2]
            columns[10, j] = reach[i]
        _covariances(columns, count, w2c, intrinsics, width, height, rows)
        _conics(columns, count, rows)
        _boxes_reach(
            rows[0, :count],
            rows[1, :count],
            rows[6, :count],
            rows[7, :count],
            width,
            height,
            wanted,
            reaches[:count],
        )
        if limits is not None:
            _boxes_within_limits(
                rows[0, :count],
                rows[1, :count],
                rows[6, :count],
                rows[7, :count],
                rows[5, :count],
                limits,
                reaches[:count],
            )
        for j in range(count):
            k, i = first + j, candidates[first + j]
            keep[k] = reaches[j] and rows[8, j] > 0.0
            for field in range(8):
                out[k, field] = rows[field, j]
            out[k, 8], out[k, 9] = opacity[i], cutoff[i]  # read here in index order, not gathered later


def _depth_index_keys(depth: np.ndarray, bits: int) -> np.ndarray:
    """[M] uint64: each depth's bits [M] with its lowest ``bits`` replaced by its index."""
    shift = np.uint64(bits)
    return ((depth.view(np.uint64) >> shift) << shift) | np.arange(len(depth), dtype=np.uint64)


def _order_of_sorted_keys(keys: np.ndarray, bits: int, depth: np.ndarray) -> np.ndarray:
    """The indices [M] held by sorted ``_depth_index_keys`` [M], each run of keys that agree above
    the index bits (depths within ~2^-33 of each other, relatively) put in (depth, index) order."""
    shift = np.uint64(bits)
    order = (keys & ((np.uint64(1) << shift) - np.uint64(1))).astype(np.int64)
    high = keys >> shift
    tied = high[1:] == high[:-1]
    if not tied.any():
        return order
    in_run = np.zeros(len(keys), bool)
    in_run[1:] |= tied
    in_run[:-1] |= tied
    rows = np.flatnonzero(in_run)  # runs are contiguous and in key order: sorted back in place
    members = order[rows]
    order[rows] = members[np.lexsort((members, depth[members], high[rows]))]
    return order


def front_to_back(depth: np.ndarray) -> np.ndarray:
    """The order [M] of depths [M] from near to far, ties in index order: the stable argsort.

    Positive depths (a projected splat's z is above 0.2) are ordered by one sort of 64-bit keys,
    each depth's bits with its index in place of the lowest ones: positive doubles order as their
    bits, so the keys order by depth, then index, except among depths that agree above the index
    bits, which are put in order after. NumPy's sort of integers is vectorised and its argsort is
    not, so this is faster than a stable argsort."""
    depth = np.ascontiguousarray(depth, dtype=np.float64)
    if not (np.all(depth > 0) and np.all(depth < np.inf)):
        return np.argsort(depth, kind="stable")
    bits = max(1, (len(depth) - 1).bit_length())
    keys = _depth_index_keys(depth, bits)
    keys.sort()
    return _order_of_sorted_keys(keys, bits, depth)


def project_splats(
    means: np.ndarray,
    quaternions: np.ndarray,
    constants: GaussianConstants,
    w2c: np.ndarray,
    fx_fy_cx_cy: np.ndarray,
    width: int,
    height: int,
    points_uv: np.ndarray | None = None,
    limits: np.ndarray | None = None,
) -> Splats2D:
    """Project N Gaussians into a camera: those that can touch the image, sorted front to back
    (ties in index order).

    With ``points_uv`` [P, 2], keep only the splats that can touch a block holding one of those
    points: enough to render depth there, and much less to project, sort and bin. With
    ``limits`` [P] too (view-space z, metres; ValueError without ``points_uv``), only those no
    deeper than the largest limit of the points in a block they touch: enough for
    ``render.render_depth_at`` with those limits (a point's splats deeper than its limit may be
    left out).

    Args:
      means: [N, 3] world centres. quaternions: [N, 4] (w, x, y, z), unnormalised; float32 or
        float64. constants: ``gaussian_constants`` of the N Gaussians.
      w2c: [4, 4] world-to-camera (OpenCV axes). fx_fy_cx_cy: [4].
    """
    means = read_only(means)
    w2c = np.ascontiguousarray(w2c, dtype=np.float64)
    intrinsics = np.asarray(fx_fy_cx_cy, dtype=np.float64)
    wanted = wanted_blocks(points_uv, width, height)
    depth_limits = None
    if limits is not None:
        if points_uv is None:
            raise ValueError("project_splats: limits [P] are depths of points_uv [P, 2], which is None")
        depth_limits = block_limits(points_uv, limits, width, height)
    max_depth = np.inf if depth_limits is None else depth_limits[0, 0].max()
    view = (w2c, intrinsics, int(width), int(height))
    candidates = cull(means, constants, view, float(max_depth), wanted)
    out, keep = preprocess(candidates, means, quaternions, constants, view, wanted, depth_limits)
    rows = np.flatnonzero(keep)
    rows = rows[front_to_back(out[rows, 5])]
    m = len(rows)
    splats = Splats2D(
        xy=np.empty((m, 2)),
        conic=np.empty((m, 3)),
        opacity=np.empty(m),
        cutoff=np.empty(m),
        depth=np.empty(m),
        extent=np.empty((m, 2)),
        index=candidates[rows],
        width=int(width),
        height=int(height),
    )
    fields = (splats.xy, splats.conic, splats.opacity, splats.cutoff, splats.depth, splats.extent)
    _gather_fields(out, rows, *fields)
    return splats


@numba.njit(cache=True)
def _gather_fields(out, rows, xy, conic, opacity, cutoff, depth, extent):
    """``preprocess``' rows [K, 10] taken in the order ``rows`` [M] into each field's own contiguous
    array (``Splats2D``'s), in one pass."""
    for k in range(rows.shape[0]):
        r = rows[k]
        xy[k, 0], xy[k, 1] = out[r, 0], out[r, 1]
        conic[k, 0], conic[k, 1], conic[k, 2] = out[r, 2], out[r, 3], out[r, 4]
        depth[k] = out[r, 5]
        extent[k, 0], extent[k, 1] = out[r, 6], out[r, 7]
        opacity[k], cutoff[k] = out[r, 8], out[r, 9]


def cull(
    means: np.ndarray, constants: GaussianConstants, view: tuple, max_depth: float, wanted: np.ndarray
) -> np.ndarray:
    """Indices [K] of the Gaussians (centres [N, 3]) that can touch the image of ``view`` (w2c,
    fx_fy_cx_cy, width, height), no deeper than ``max_depth``, within the ``wanted`` blocks."""
    w2c, intrinsics, width, height = view
    c = constants
    flags = np.empty(len(means), np.bool_)
    _candidates(
        means,
        c.opacity,
        c.reach,
        c.max_variance,
        w2c,
        intrinsics,
        width,
        height,
        max_depth,
        wanted,
        few_blocks(wanted),
        flags,
    )
    return np.flatnonzero(flags)


def preprocess(
    candidates: np.ndarray,
    means: np.ndarray,
    quaternions: np.ndarray,
    constants: GaussianConstants,
    view: tuple,
    wanted: np.ndarray | None,
    depth_limits: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray]:
    """The candidates' splats in the image: rows [K, 10] (x, y, conic a b c, depth, extent x y,
    opacity, cutoff) and which are kept [K] (those that reach a wanted block, within its limit)."""
    w2c, intrinsics, width, height = view
    c = constants
    out = np.empty((len(candidates), 10))
    keep = np.empty(len(candidates), np.bool_)
    _preprocess(
        candidates,
        means,
        read_only(quaternions),
        c.scales,
        c.opacity,
        c.reach,
        c.cutoff,
        w2c,
        intrinsics,
        width,
        height,
        wanted,
        depth_limits,
        out,
        keep,
    )
    return out, keep


def inside_image(points_uv: np.ndarray, width: int, height: int) -> np.ndarray:
    """[P] True where points [P, 2] lie in [0, width) x [0, height)."""
    u, v = points_uv[:, 0], points_uv[:, 1]
    return (u >= 0) & (u < width) & (v >= 0) & (v < height)


def point_tiles(points_uv: np.ndarray, width: int) -> np.ndarray:
    """Row-major tile index [P] of image points [P, 2] inside the image."""
    tiles_x = -(-width // TILE)
    return (points_uv[:, 1] // TILE).astype(np.int64) * tiles_x + (points_uv[:, 0] // TILE).astype(np.int64)


def wanted_blocks(points_uv: np.ndarray | None, width: int, height: int) -> np.ndarray:
    """Summed-area table [blocks_y + 1, blocks_x + 1] of the blocks holding a point of
    ``points_uv`` [P, 2] (all blocks if None): entry (y, x) counts the wanted blocks above row y
    and left of column x, so any box's count takes four reads."""
    blocks_x, blocks_y = -(-width // BLOCK), -(-height // BLOCK)
    wanted = np.zeros((blocks_y + 1, blocks_x + 1), np.int64)
    if points_uv is None:
        wanted[1:, 1:] = 1
    else:
        points = np.asarray(points_uv, dtype=np.float64).reshape(-1, 2)
        inner = points[inside_image(points, width, height)]
        wanted[(inner[:, 1] // BLOCK).astype(np.int64) + 1, (inner[:, 0] // BLOCK).astype(np.int64) + 1] = 1
    return wanted.cumsum(axis=0).cumsum(axis=1)


def few_blocks(wanted: np.ndarray) -> np.ndarray:
    """The blocks a ``wanted_blocks`` table [blocks_y + 1, blocks_x + 1] counts, as [2, B] int16
    (columns, then rows) when there are 1 to FEW_BLOCKS of them, else [2, 0]."""
    count = int(wanted[-1, -1])
    if not 0 < count <= FEW_BLOCKS or max(wanted.shape) > np.iinfo(np.int16).max:
        return np.empty((2, 0), np.int16)
    rows, columns = np.nonzero(np.diff(np.diff(wanted, axis=0), axis=1))
    return np.stack([columns, rows]).astype(np.int16)


def block_limits(points_uv: np.ndarray, limits: np.ndarray, width: int, height: int) -> np.ndarray:
    """[3, 3, blocks_y, blocks_x]: entry (ky, kx, y, x) the largest of ``limits`` [P] over the
    points [P, 2] in the blocks y .. y + 2^ky - 1, x .. x + 2^kx - 1 (-inf where there are none),
    so that any box of up to LIMIT_BOX_BLOCKS blocks a side takes four reads."""
    points = np.asarray(points_uv, dtype=np.float64).reshape(-1, 2)
    inside = inside_image(points, width, height)
    blocks_x, blocks_y = -(-width // BLOCK), -(-height // BLOCK)
    windows = np.full((3, 3, blocks_y, blocks_x), -np.inf)
    rows, cols = (points[inside, 1] // BLOCK).astype(np.int64), (points[inside, 0] // BLOCK).astype(np.int64)
    np.maximum.at(windows[0, 0], (rows, cols), np.asarray(limits, dtype=np.float64).reshape(-1)[inside])
    for k in (1, 2):
        half = 1 << (k - 1)
        windows[0, k] = windows[0, k - 1]
        np.maximum(windows[0, k, :, :-half], windows[0, k - 1, :, half:], out=windows[0, k, :, :-half])
    for k in (1, 2):
        half = 1 << (k - 1)
        windows[k] = windows[k - 1]
        np.maximum(windows[k, :, :-half], windows[k - 1, :, half:], out=windows[k, :, :-half])
    return windows
