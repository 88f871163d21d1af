"""Splat depth rendering against a slow, independent per-pixel reference and hand-worked cases."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pipeline.pstudio.render import render_depth_at, render_depth_image
from pipeline.pstudio.splats import Splats2D, project_splats
from pipeline.samples.studio_world import HEIGHT, WIDTH


def reference_splats(means, quaternions, scales, opacities, w2c, fx_fy_cx_cy):
    """Every Gaussian's screen centre [N, 2], 2D covariance [N, 2, 2], depth [N] and opacity,
    written from the paper's definitions with plain matrices, front to back, near-culled."""
    fx, fy, cx, cy = fx_fy_cx_cy
    rotation_wc = w2c[:3, :3]
    view = means @ rotation_wc.T + w2c[:3, 3]
    q = quaternions / np.linalg.norm(quaternions, axis=1, keepdims=True)
    rotations = Rotation.from_quat(q, scalar_first=True).as_matrix()
    sigma = rotations @ (scales[:, :, None] ** 2 * np.swapaxes(rotations, 1, 2))
    x, y, z = view.T
    tx = np.clip(x / z, -1.3 * WIDTH / (2 * fx), 1.3 * WIDTH / (2 * fx)) * z
    ty = np.clip(y / z, -1.3 * HEIGHT / (2 * fy), 1.3 * HEIGHT / (2 * fy)) * z
    jacobian = np.zeros((len(z), 2, 3))
    jacobian[:, 0, 0], jacobian[:, 0, 2] = fx / z, -fx * tx / z**2
    jacobian[:, 1, 1], jacobian[:, 1, 2] = fy / z, -fy * ty / z**2
    t = jacobian @ rotation_wc
    cov = t @ sigma @ np.swapaxes(t, 1, 2) + 0.3 * np.eye(2)
    centre = np.stack([fx * x / z + cx, fy * y / z + cy], 1)
    order = [i for i in np.argsort(z, kind="stable") if z[i] > 0.2]
    return centre[order], cov[order], z[order], opacities[order]


def reference_depth(splats, pixel, min_alpha=0.5):
    """Brute-force compositing at one pixel over every Gaussian: (depth or NaN, accumulated alpha)."""
    centre, cov, z, opacity = splats
    offset = centre - pixel
    mahalanobis = np.einsum("ni,ni->n", offset, np.linalg.solve(cov, offset[:, :, None])[:, :, 0])
    transmittance, weighted, accumulated = 1.0, 0.0, 0.0
    for i in range(len(z)):
        alpha = min(0.99, opacity[i] * math.exp(-0.5 * mahalanobis[i]))
        if alpha < 1 / 255:
            continue
        if transmittance * (1 - alpha) < 1e-4:
            break
        weighted += alpha * transmittance * z[i]
        accumulated += alpha * transmittance
        transmittance *= 1 - alpha
    depth = weighted / accumulated if accumulated >= min_alpha else math.nan
    return depth, accumulated


@pytest.fixture(scope="module")
def frame(pstudio_sample):
    """Frame 20 of the sample as params.npz stores it, seen by camera 0 (the ball in front of
    the ellipsoid)."""
    root, _ = pstudio_sample
    params = np.load(f"{root}/output/pretrained/dome/params.npz")
    meta = json.load(open(f"{root}/data/dome/train_meta.json"))
    k = np.array(meta["k"][20][0])
    return {
        "means": params["means3D"][20].astype(np.float64),
        "quaternions": params["unnorm_rotations"][20].astype(np.float64),
        "scales": np.exp(params["log_scales"].astype(np.float64)),
        "opacities": 1 / (1 + np.exp(-params["logit_opacities"][:, 0].astype(np.float64))),
        "w2c": np.array(meta["w2c"][20][0]),
        "fx_fy_cx_cy": np.array([k[0, 0], k[1, 1], k[0, 2], k[1, 2]]),
    }


def test_depth_matches_brute_force_reference(frame):
    splats = project_splats(**frame, width=WIDTH, height=HEIGHT)
    full_depth, full_alpha = render_depth_image(splats, 0.5)
    rng = np.random.default_rng(1)
    # Random pixels, plus pixels where alpha is between 0.2 and 0.8 (silhouettes, blends).
    edges = np.argwhere((full_alpha > 0.2) & (full_alpha < 0.8))
    pixels = np.concatenate(
        [
            rng.uniform([0, 0], [WIDTH, HEIGHT], size=(60, 2)),
            edges[rng.choice(len(edges), 40, replace=False)][:, ::-1] + rng.uniform(-0.5, 0.5, (40, 2)),
        ]
    )
    depth, alpha = render_depth_at(splats, pixels, 0.5)
    reference = reference_splats(**frame)
    surfaces = 0
    for pixel, ours, ours_alpha in zip(pixels, depth, alpha, strict=True):
        expected, expected_alpha = reference_depth(reference, pixel)
        assert ours_alpha == pytest.approx(expected_alpha, abs=1e-9)
        if math.isnan(expected):
            assert math.isnan(ours)
        else:
            surfaces += 1
            assert abs(ours - expected) < 1e-3, (pixel, ours, expected)
    assert surfaces >= 50


def test_selected_pixels_equal_the_full_frame(frame):
    """The pipeline's path (only the splats that reach the selected pixels' tiles) against a
    full-frame render: bit-identical at those pixels."""
    full_depth, full_alpha = render_depth_image(project_splats(**frame, width=WIDTH, height=HEIGHT), 0.5)
    rng = np.random.default_rng(2)
    cols, rows = rng.integers(0, WIDTH, 300), rng.integers(0, HEIGHT, 300)
    pixels = np.stack([cols, rows], 1).astype(float)
    selected = project_splats(**frame, width=WIDTH, height=HEIGHT, points_uv=pixels)
    depth, alpha = render_depth_at(selected, pixels, 0.5)
    np.testing.assert_array_equal(alpha, full_alpha[rows, cols])
    np.testing.assert_array_equal(depth, full_depth[rows, cols])
    assert np.isfinite(depth).sum() > 50
    few = pixels[:5]
    assert len(project_splats(**frame, width=WIDTH, height=HEIGHT, points_uv=few)) < len(selected)


def test_isotropic_gaussian_projects_to_scaled_disc():
    """A sphere of sigma 0.01 m at z = 2 on the axis: 2D variance (f sigma / z)^2 + 0.3 px^2."""
    splats = project_splats(
        np.array([[0.0, 0.0, 2.0]]),
        np.array([[2.0, 0.0, 0.0, 0.0]]),
        np.array([[0.01, 0.01, 0.01]]),
        np.array([0.8]),
        np.eye(4),
        np.array([500.0, 400.0, 320.0, 180.0]),
        WIDTH,
        HEIGHT,
    )
    var_x, var_y = (500 * 0.01 / 2) ** 2 + 0.3, (400 * 0.01 / 2) ** 2 + 0.3
    np.testing.assert_allclose(splats.xy, [[320.0, 180.0]])
    np.testing.assert_allclose(splats.conic, [[1 / var_x, 0.0, 1 / var_y]], atol=1e-12)
    # Footprint: alpha = 0.8 exp(-d^2 / 2 var) reaches 1/255 at d = sqrt(2 var ln(204)).
    np.testing.assert_allclose(
        splats.extent, [[np.sqrt(2 * var_x * np.log(204)), np.sqrt(2 * var_y * np.log(204))]]
    )


def splats_2d(depths, opacities, offsets=None) -> Splats2D:
    """Hand-made round splats of 2D variance 4 px^2 centred at pixel (8, 8) + offsets."""
    count = len(depths)
    offsets = np.zeros((count, 2)) if offsets is None else np.asarray(offsets, float)
    return Splats2D(
        xy=np.array([8.0, 8.0]) + offsets,
        conic=np.tile([0.25, 0.0, 0.25], (count, 1)),
        opacity=np.asarray(opacities, float),
        depth=np.asarray(depths, float),
        extent=np.full((count, 2), 20.0),
        index=np.arange(count),
        width=32,
        height=32,
    )


def test_compositing_hand_worked():
    # Four splats of opacity 0.95 at the pixel: weights 0.95, 0.0475, 0.002375 leave T = 1.25e-4;
    # the fourth would take T to 6.25e-6 < 1e-4, so compositing stops before it.
    depth, alpha = render_depth_at(splats_2d([1.0, 2.0, 3.0, 4.0], [0.95] * 4), np.array([[8.0, 8.0]]), 0.5)
    assert alpha[0] == pytest.approx(1 - 1.25e-4)
    assert depth[0] == pytest.approx((0.95 * 1 + 0.0475 * 2 + 0.002375 * 3) / (1 - 1.25e-4))
    # Alpha is capped at 0.99: an opaque splat leaves 1% to the next (opacity 0.5: weight 0.005).
    depth, alpha = render_depth_at(splats_2d([1.0, 5.0], [1.0, 0.5]), np.array([[8.0, 8.0]]), 0.5)
    assert alpha[0] == pytest.approx(0.995)
    assert depth[0] == pytest.approx((0.99 * 1 + 0.005 * 5) / 0.995)
    # 3 px off a splat of variance 4: alpha = 0.5 exp(-9/8) = 0.162; below 0.5 alpha: no surface.
    depth, alpha = render_depth_at(splats_2d([2.0], [0.5]), np.array([[11.0, 8.0]]), 0.5)
    assert alpha[0] == pytest.approx(0.5 * math.exp(-9 / 8))
    assert math.isnan(depth[0])
    # A contribution below 1/255 is skipped: 8 px off, alpha = 0.9 exp(-8) = 3.0e-4.
    depth, alpha = render_depth_at(
        splats_2d([2.0, 3.0], [0.9, 0.9], [[8.0, 0.0], [0.0, 0.0]]), np.array([[8.0, 8.0]]), 0.5
    )
    assert depth[0] == pytest.approx(3.0)
    assert alpha[0] == pytest.approx(0.9)
    # Outside the image: no depth.
    depth, alpha = render_depth_at(splats_2d([2.0], [0.9]), np.array([[-1.0, 8.0], [8.0, 32.0]]), 0.5)
    assert np.isnan(depth).all() and (alpha == 0).all()
