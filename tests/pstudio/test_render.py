"""Splat depth rendering against a slow, independent per-pixel reference and hand-worked cases."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pipeline.pstudio.render import render_depth_at, render_depth_image
from pipeline.pstudio.sample.studio_world import HEIGHT, WIDTH
from pipeline.pstudio.splats import Splats2D, front_to_back, gaussian_constants, project_splats


def project(means, quaternions, scales, opacities, w2c, fx_fy_cx_cy, width, height, points_uv=None):
    """``project_splats`` of Gaussians given by scales and opacities."""
    constants = gaussian_constants(scales, opacities)
    return project_splats(means, quaternions, constants, w2c, fx_fy_cx_cy, width, height, points_uv)


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


def reference_depth(splats, pixel):
    """Brute-force median depth at one point over every Gaussian, written from the rasterizer's
    loop (alpha capped at 0.99, 1/255 skip, stop under T = 1e-4, depth where T first drops
    below 0.5, else 15 m): (depth, surface)."""
    centre, cov, z, opacity = splats
    offset = centre - pixel
    mahalanobis = np.einsum("ni,ni->n", offset, np.linalg.solve(cov, offset[:, :, None])[:, :, 0])
    transmittance, depth, surface = 1.0, 15.0, False
    for i in range(len(z)):
        alpha = min(0.99, opacity[i] * math.exp(-0.5 * mahalanobis[i]))
        if alpha < 1 / 255:
            continue
        if transmittance * (1 - alpha) < 1e-4:
            break
        if transmittance > 0.5 and transmittance * (1 - alpha) < 0.5:
            depth, surface = z[i], True
        transmittance *= 1 - alpha
    return depth, surface


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
    splats = project(**frame, width=WIDTH, height=HEIGHT)
    full_depth, full_surface = render_depth_image(splats)
    rng = np.random.default_rng(1)
    # Random points, plus points in pixels beside a silhouette or a depth step of over 5 cm.
    step = np.zeros_like(full_surface)
    step[:, 1:] = (full_surface[:, 1:] != full_surface[:, :-1]) | (np.abs(np.diff(full_depth, axis=1)) > 0.05)
    edges = np.argwhere(step)
    pixels = np.concatenate(
        [
            rng.uniform([0, 0], [WIDTH, HEIGHT], size=(60, 2)),
            edges[rng.choice(len(edges), 60, replace=False)][:, ::-1] + rng.uniform(0, 1, (60, 2)),
        ]
    )
    depth, surface = render_depth_at(splats, pixels)
    reference = reference_splats(**frame)
    expected = [reference_depth(reference, pixel) for pixel in pixels]
    np.testing.assert_array_equal(surface, [hit for _, hit in expected])
    np.testing.assert_allclose(depth, [z for z, _ in expected], rtol=0, atol=1e-9)
    assert surface.sum() >= 60
    assert (~surface).sum() >= 20


def test_selected_pixels_equal_the_full_frame(frame):
    """The pipeline's path (only the splats that reach the selected points' tiles) against a
    full-frame render: bit-identical at those pixels' centres."""
    full_depth, full_surface = render_depth_image(project(**frame, width=WIDTH, height=HEIGHT))
    rng = np.random.default_rng(2)
    cols, rows = rng.integers(0, WIDTH, 300), rng.integers(0, HEIGHT, 300)
    pixels = np.stack([cols, rows], 1) + 0.5
    selected = project(**frame, width=WIDTH, height=HEIGHT, points_uv=pixels)
    depth, surface = render_depth_at(selected, pixels)
    np.testing.assert_array_equal(depth, full_depth[rows, cols])
    np.testing.assert_array_equal(surface, full_surface[rows, cols])
    assert surface.sum() > 50
    few = pixels[:5]
    assert len(project(**frame, width=WIDTH, height=HEIGHT, points_uv=few)) < len(selected)


def on_axis(quaternion, scales) -> Splats2D:
    """One Gaussian of opacity 0.8 at z = 2 m on the optical axis (fx 500, fy 400, the identity
    camera), projected."""
    return project(
        np.array([[0.0, 0.0, 2.0]]),
        np.array([quaternion], float),
        np.array([scales], float),
        np.array([0.8]),
        np.eye(4),
        np.array([500.0, 400.0, 320.0, 180.0]),
        WIDTH,
        HEIGHT,
    )


def test_isotropic_gaussian_projects_to_scaled_disc():
    """A sphere of sigma 0.01 m at z = 2 on the axis: 2D variance (f sigma / z)^2 + 0.3 px^2."""
    splats = on_axis([2.0, 0.0, 0.0, 0.0], [0.01, 0.01, 0.01])
    var_x, var_y = (500 * 0.01 / 2) ** 2 + 0.3, (400 * 0.01 / 2) ** 2 + 0.3
    np.testing.assert_allclose(splats.xy, [[320.0, 180.0]])
    np.testing.assert_allclose(splats.conic, [[1 / var_x, 0.0, 1 / var_y]], atol=1e-12)
    # Footprint: alpha = 0.8 exp(-d^2 / 2 var) reaches 1/255 at d = sqrt(2 var ln(204)).
    np.testing.assert_allclose(
        splats.extent, [[np.sqrt(2 * var_x * np.log(204)), np.sqrt(2 * var_y * np.log(204))]]
    )


def test_a_zero_quaternion_is_the_identity_rotation():
    """Dynamic 3D Gaussians normalise rotations as torch's ``normalize`` does, q / max(|q|, 1e-12),
    so a zero quaternion stays zero and the rasterizer's rotation matrix of it is the identity:
    a flat Gaussian (3 cm x 1 cm) with q = 0 projects as with q = (1, 0, 0, 0), not as turned
    by 90 degrees about the view axis."""
    flat = [0.03, 0.01, 0.01]
    zero, identity = on_axis([0.0] * 4, flat).conic, on_axis([1.0, 0.0, 0.0, 0.0], flat).conic
    turned = on_axis([np.sqrt(0.5), 0.0, 0.0, np.sqrt(0.5)], flat).conic
    np.testing.assert_array_equal(zero, identity)
    assert not np.allclose(identity, turned)


def splats_2d(depths, opacities, offsets=None) -> Splats2D:
    """Hand-made round splats of 2D variance 4 px^2 centred at pixel (8, 8) + offsets."""
    count = len(depths)
    offsets = np.zeros((count, 2)) if offsets is None else np.asarray(offsets, float)
    opacities = np.asarray(opacities, float)
    return Splats2D(
        xy=np.array([8.0, 8.0]) + offsets,
        conic=np.tile([0.25, 0.0, 0.25], (count, 1)),
        opacity=opacities,
        cutoff=np.log(1 / (255 * opacities)),
        depth=np.asarray(depths, float),
        extent=np.full((count, 2), 20.0),
        index=np.arange(count),
        width=32,
        height=32,
    )


def median_at_centre(depths, opacities, offsets=None):
    """(depth, surface) at (8, 8) of ``splats_2d``."""
    depth, surface = render_depth_at(splats_2d(depths, opacities, offsets), np.array([[8.0, 8.0]]))
    return depth[0], bool(surface[0])


def test_median_depth_is_where_transmittance_crosses_one_half():
    # 0.4 in front of 0.9: T = 0.6, then 0.06; the second splat crosses 0.5. The alpha-weighted
    # mean would be (0.4 x 1 + 0.54 x 3) / 0.94 = 2.15 m.
    assert median_at_centre([1.0, 3.0], [0.4, 0.9]) == (3.0, True)
    # 0.6 in front: T = 0.4 after the first splat, which holds the median whatever lies behind.
    assert median_at_centre([1.0, 3.0], [0.6, 0.9]) == (1.0, True)
    # Three of 0.25: T = 0.75, 0.5625, 0.421875: the third.
    assert median_at_centre([1.0, 2.0, 3.0], [0.25, 0.25, 0.25]) == (3.0, True)
    # 3 px off a splat of variance 4, alpha = 0.9 exp(-9/8) = 0.29: T = 0.71 never below 0.5.
    depth, surface = render_depth_at(splats_2d([2.0], [0.9]), np.array([[11.0, 8.0]]))
    assert (depth[0], surface[0]) == (15.0, False)


def test_transmittance_never_below_one_half_gives_the_15_m_background():
    # T = 0.8, then 0.56.
    assert median_at_centre([1.0, 2.0], [0.2, 0.3]) == (15.0, False)
    # T = 0.5 exactly after the first splat: not below 0.5 there, and not above it before the
    # second (the rasterizer's strict T > 0.5 and T (1 - alpha) < 0.5): no median, though T ends
    # at 0.05.
    assert median_at_centre([1.0, 2.0], [0.5, 0.9]) == (15.0, False)


def test_contributions_below_1_over_255_are_skipped():
    # T = 0.501 after the first splat; the second, 6.75 px off (alpha = 0.9 exp(-6.75^2 / 8)
    # = 0.0030 < 1/255), would take T to 0.4995 but is skipped; the third crosses.
    assert median_at_centre([1.0, 2.0, 3.0], [0.499, 0.9, 0.9], [[0, 0], [6.75, 0], [0, 0]]) == (3.0, True)
    # 6 px off: alpha = 0.9 exp(-4.5) = 0.0100 counts, T = 0.496: the second splat crosses.
    assert median_at_centre([1.0, 2.0, 3.0], [0.499, 0.9, 0.9], [[0, 0], [6.0, 0], [0, 0]]) == (2.0, True)


def test_pixel_i_j_is_rendered_at_its_centre():
    """A tiny Gaussian on the axis, with the principal point at (100.5, 50.5): its splat (2D
    variance 0.3 px^2, the low-pass) gives alpha 0.9 at pixel (100, 50)'s centre, 0.9 exp(-1/0.6)
    = 0.17 one pixel away, and 0.9 exp(-0.5/0.6) = 0.39 at the pixel's corner (100, 50)."""
    splats = project(
        np.array([[0.0, 0.0, 2.0]]),
        np.array([[1.0, 0.0, 0.0, 0.0]]),
        np.full((1, 3), 1e-6),
        np.array([0.9]),
        np.eye(4),
        np.array([500.0, 500.0, 100.5, 50.5]),
        WIDTH,
        HEIGHT,
    )
    depth, surface = render_depth_image(splats)
    np.testing.assert_array_equal(np.argwhere(surface), [[50, 100]])
    assert depth[50, 100] == 2.0
    assert (depth[~surface] == 15.0).all()
    _, hit = render_depth_at(splats, np.array([[100.0, 50.0], [100.5, 50.5]]))
    np.testing.assert_array_equal(hit, [False, True])


def test_front_to_back_is_the_stable_argsort():
    """Depths a few ulps apart (they agree above the index bits of the sort keys), exact ties, and
    depths the keys cannot order (zero, negative, infinite, NaN) all come out in the stable
    argsort's order."""
    rng = np.random.default_rng(11)
    for trial in range(300):
        base = rng.uniform(0.3, 12.0, size=rng.integers(1, 30))
        depth = rng.choice(base, size=rng.integers(0, 3000))
        ulps = rng.integers(0, 4, size=len(depth)).astype(np.uint64)
        depth = (depth.view(np.uint64) + ulps).view(np.float64)
        if trial % 10 == 0 and len(depth):
            depth[rng.integers(len(depth))] = rng.choice([0.0, -1.0, np.inf, np.nan])
        np.testing.assert_array_equal(front_to_back(depth), np.argsort(depth, kind="stable"))


def test_points_outside_the_image_have_no_depth():
    depth, surface = render_depth_at(splats_2d([2.0], [0.9]), np.array([[-0.5, 8.0], [8.0, 32.0]]))
    assert np.isnan(depth).all()
    assert not surface.any()


def test_splats_at_equal_depth_keep_index_order():
    """Splats sorted front to back keep ties in index order, as a stable sort would."""
    rng = np.random.default_rng(7)
    for _ in range(200):
        depth = rng.integers(0, rng.integers(1, 40), size=rng.integers(0, 300)).astype(np.float64)
        order = front_to_back(depth)
        assert (np.diff(depth[order]) >= 0).all()
        ties = np.diff(depth[order]) == 0
        assert (np.diff(order)[ties] > 0).all()
    distinct = rng.permutation(1000).astype(np.float64)
    np.testing.assert_array_equal(distinct[front_to_back(distinct)], np.arange(1000))
