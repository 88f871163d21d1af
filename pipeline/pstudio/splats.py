"""3D Gaussian Splatting projection (Kerbl et al. 2023, EWA splatting) of one frame into one camera.

The maths of the reference CUDA rasterizer's preprocessing, in float64:

- view-space centre p = W m + t; culled when p_z <= 0.2 (the rasterizer's frustum test);
- Sigma = R S S^T R^T from the normalised quaternion (w, x, y, z) and scales;
- Sigma' = J W Sigma W^T J^T with the perspective Jacobian J at p, whose x/z and y/z are clamped
  to 1.3 x the half field of view; then 0.3 px^2 added to the diagonal (low-pass filter);
- conic = Sigma'^-1; a splat with det(Sigma') = 0 is dropped.

One deliberate difference: a splat's screen footprint is the exact ellipse where its alpha
reaches 1/255 (the compositing cut-off), not the rasterizer's 3-sigma square rounded to
16-pixel tiles. A pixel's value then depends on no tiling: it equals compositing over all
Gaussians (tests/test_pstudio_render.py checks this against a brute-force reference).

Pixel convention: OpenCV's (pixel centres at integer coordinates, u = fx x / z + cx). The
reference rasterizer samples at u + 0.5 instead; for depth lookups at the track's own
projection this half-pixel shift has no bearing on the result.
"""

from __future__ import annotations

import dataclasses

import numba
import numpy as np

TILE = 16  # pixels per side of the square tiles splats are binned into


@dataclasses.dataclass
class Splats2D:
    """Splats of one frame seen by one camera, culled and sorted front to back (M of them).

    xy: [M, 2] projected centres (pixels). conic: [M, 3] (a, b, c) of the inverse 2D
    covariance. opacity: [M]. depth: [M] view-space z of the centre (metres).
    extent: [M, 2] half-width and half-height of the 1/255 footprint's bounding box (pixels).
    index: [M] index of each splat in the input arrays.
    """

    xy: np.ndarray
    conic: np.ndarray
    opacity: np.ndarray
    depth: np.ndarray
    extent: np.ndarray
    index: np.ndarray
    width: int
    height: int

    def __len__(self) -> int:
        return len(self.depth)


@numba.njit(parallel=True, cache=True)
def _preprocess(means, quaternions, scales, opacities, w2c, intrinsics, width, height, wanted, out, keep):
    """Per splat: out[i] = (u, v, conic a, b, c, z, extent x, extent y); keep[i] = its footprint
    touches a wanted tile (``wanted``: [tiles_y * tiles_x] bool, row-major)."""
    fx, fy, cx, cy = intrinsics[0], intrinsics[1], intrinsics[2], intrinsics[3]
    lim_x = 1.3 * 0.5 * width / fx
    lim_y = 1.3 * 0.5 * height / fy
    for i in numba.prange(means.shape[0]):
        keep[i] = False
        px = w2c[0, 0] * means[i, 0] + w2c[0, 1] * means[i, 1] + w2c[0, 2] * means[i, 2] + w2c[0, 3]
        py = w2c[1, 0] * means[i, 0] + w2c[1, 1] * means[i, 1] + w2c[1, 2] * means[i, 2] + w2c[1, 3]
        pz = w2c[2, 0] * means[i, 0] + w2c[2, 1] * means[i, 1] + w2c[2, 2] * means[i, 2] + w2c[2, 3]
        if pz <= 0.2 or opacities[i] < 1.0 / 255.0 or not np.isfinite(px + py + pz):
            continue
        qw, qx, qy, qz = quaternions[i, 0], quaternions[i, 1], quaternions[i, 2], quaternions[i, 3]
        norm = np.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
        qw, qx, qy, qz = qw / norm, qx / norm, qy / norm, qz / norm
        r00, r01, r02 = 1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qw * qz), 2 * (qx * qz + qw * qy)
        r10, r11, r12 = 2 * (qx * qy + qw * qz), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qw * qx)
        r20, r21, r22 = 2 * (qx * qz - qw * qy), 2 * (qy * qz + qw * qx), 1 - 2 * (qx * qx + qy * qy)
        sx, sy, sz = scales[i, 0], scales[i, 1], scales[i, 2]
        # M = W R S (columns scaled), so that Sigma' = J M M^T J^T.
        m00 = (w2c[0, 0] * r00 + w2c[0, 1] * r10 + w2c[0, 2] * r20) * sx
        m01 = (w2c[0, 0] * r01 + w2c[0, 1] * r11 + w2c[0, 2] * r21) * sy
        m02 = (w2c[0, 0] * r02 + w2c[0, 1] * r12 + w2c[0, 2] * r22) * sz
        m10 = (w2c[1, 0] * r00 + w2c[1, 1] * r10 + w2c[1, 2] * r20) * sx
        m11 = (w2c[1, 0] * r01 + w2c[1, 1] * r11 + w2c[1, 2] * r21) * sy
        m12 = (w2c[1, 0] * r02 + w2c[1, 1] * r12 + w2c[1, 2] * r22) * sz
        m20 = (w2c[2, 0] * r00 + w2c[2, 1] * r10 + w2c[2, 2] * r20) * sx
        m21 = (w2c[2, 0] * r01 + w2c[2, 1] * r11 + w2c[2, 2] * r21) * sy
        m22 = (w2c[2, 0] * r02 + w2c[2, 1] * r12 + w2c[2, 2] * r22) * sz
        tx = min(lim_x, max(-lim_x, px / pz)) * pz
        ty = min(lim_y, max(-lim_y, py / pz)) * pz
        j00, j02 = fx / pz, -fx * tx / (pz * pz)
        j11, j12 = fy / pz, -fy * ty / (pz * pz)
        a0, a1, a2 = j00 * m00 + j02 * m20, j00 * m01 + j02 * m21, j00 * m02 + j02 * m22
        b0, b1, b2 = j11 * m10 + j12 * m20, j11 * m11 + j12 * m21, j11 * m12 + j12 * m22
        cov_a = a0 * a0 + a1 * a1 + a2 * a2 + 0.3
        cov_b = a0 * b0 + a1 * b1 + a2 * b2
        cov_c = b0 * b0 + b1 * b1 + b2 * b2 + 0.3
        det = cov_a * cov_c - cov_b * cov_b
        if det <= 0.0:
            continue
        # alpha >= 1/255  <=>  d^T Sigma'^-1 d <= 2 ln(255 opacity): that ellipse's bounding box.
        reach = 2.0 * np.log(255.0 * opacities[i])
        ext_x = np.sqrt(reach * cov_a) * (1 + 1e-9) + 1e-9
        ext_y = np.sqrt(reach * cov_c) * (1 + 1e-9) + 1e-9
        u = fx * px / pz + cx
        v = fy * py / pz + cy
        if u + ext_x < 0 or u - ext_x >= width or v + ext_y < 0 or v - ext_y >= height:
            continue
        tiles_x = (width + TILE - 1) // TILE
        x0, x1 = (
            max(0, int(np.floor((u - ext_x) / TILE))),
            min(tiles_x - 1, int(np.floor((u + ext_x) / TILE))),
        )
        y0 = max(0, int(np.floor((v - ext_y) / TILE)))
        y1 = min((height + TILE - 1) // TILE - 1, int(np.floor((v + ext_y) / TILE)))
        touches = False
        for ty in range(y0, y1 + 1):
            for tx in range(x0, x1 + 1):
                touches = touches or wanted[ty * tiles_x + tx]
        if not touches:
            continue
        out[i, 0], out[i, 1] = u, v
        out[i, 2], out[i, 3], out[i, 4] = cov_c / det, -cov_b / det, cov_a / det
        out[i, 5], out[i, 6], out[i, 7] = pz, ext_x, ext_y
        keep[i] = True


def project_splats(
    means: np.ndarray,
    quaternions: np.ndarray,
    scales: np.ndarray,
    opacities: np.ndarray,
    w2c: np.ndarray,
    fx_fy_cx_cy: np.ndarray,
    width: int,
    height: int,
    points_uv: np.ndarray | None = None,
) -> Splats2D:
    """Project N Gaussians into a camera: those that can touch the image, sorted front to back.

    With ``points_uv`` [P, 2], keep only the splats that can touch a tile holding one of those
    points: enough to render depth there, and much less to sort and bin.

    Args:
      means: [N, 3] world centres. quaternions: [N, 4] (w, x, y, z), unnormalised.
      scales: [N, 3] standard deviations along the local axes. opacities: [N] in [0, 1].
      w2c: [4, 4] world-to-camera (OpenCV axes). fx_fy_cx_cy: [4].
    """
    as_f64 = [np.ascontiguousarray(a, dtype=np.float64) for a in (means, quaternions, scales, opacities)]
    out = np.empty((len(means), 8))
    keep = np.empty(len(means), dtype=np.bool_)
    _preprocess(
        *as_f64,
        np.ascontiguousarray(w2c, dtype=np.float64),
        np.asarray(fx_fy_cx_cy, dtype=np.float64),
        int(width),
        int(height),
        wanted_tiles(points_uv, width, height),
        out,
        keep,
    )
    index = np.nonzero(keep)[0]
    index = index[np.argsort(out[index, 5], kind="stable")]
    kept = out[index]
    return Splats2D(
        xy=kept[:, 0:2],
        conic=kept[:, 2:5],
        opacity=np.asarray(opacities, dtype=np.float64)[index],
        depth=kept[:, 5],
        extent=kept[:, 6:8],
        index=index,
        width=int(width),
        height=int(height),
    )


def point_tiles(points_uv: np.ndarray, width: int) -> np.ndarray:
    """Row-major tile index [P] of image points [P, 2] inside the image."""
    tiles_x = -(-width // TILE)
    return (points_uv[:, 1] // TILE).astype(np.int64) * tiles_x + (points_uv[:, 0] // TILE).astype(np.int64)


def inside_image(points_uv: np.ndarray, width: int, height: int) -> np.ndarray:
    """[P] True where points [P, 2] lie in [0, width) x [0, height)."""
    u, v = points_uv[:, 0], points_uv[:, 1]
    return (u >= 0) & (u < width) & (v >= 0) & (v < height)


def wanted_tiles(points_uv: np.ndarray | None, width: int, height: int) -> np.ndarray:
    """[tiles_y * tiles_x] bool: the tiles holding a point of ``points_uv`` [P, 2] (all if None)."""
    count = -(-width // TILE) * -(-height // TILE)
    if points_uv is None:
        return np.ones(count, np.bool_)
    points = np.asarray(points_uv, dtype=np.float64).reshape(-1, 2)
    wanted = np.zeros(count, np.bool_)
    wanted[point_tiles(points[inside_image(points, width, height)], width)] = True
    return wanted
