"""Panoptic Studio annotation on hand-made one-camera scenes: pixel (i, j) is read at its centre
(i + 0.5, j + 0.5) and at floor(u), floor(v), and the renderer's 15 m background is no surface."""

from __future__ import annotations

import numpy as np

from pipeline.core.geometry import project, rotation_from_roll_pitch_yaw, transform_points
from pipeline.core.visibility import in_view
from pipeline.pstudio.multiview_masks import camera_pixel, multiview_mask_fraction
from pipeline.pstudio.records import Gaussians, UnitInput, Views
from pipeline.pstudio.settings import PstudioConfig
from pipeline.pstudio.splats import gaussian_constants
from pipeline.pstudio.tracks import attach_queries, track_visibility
from pipeline.settings.fields import with_rules

SIZE = 32
FOCAL = 500.0
PRINCIPAL = 16.0
REFINED = PstudioConfig()


def unit_with(pixels, depths, opacities, mask: np.ndarray | None = None, scale: float = 1e-6) -> UnitInput:
    """One frame, one camera (identity pose, f = 500, principal point (16, 16), 32 x 32) and
    foreground Gaussians (by default tiny: sigma ``scale`` 1 um, splats of 2D variance 0.3 px^2)
    whose centres project to ``pixels`` [N, 2] at ``depths`` [N]; ``mask`` [32, 32] is the camera's
    foreground mask."""
    pixels, depths = np.asarray(pixels, float), np.asarray(depths, float)
    means = np.column_stack([(pixels - PRINCIPAL) / FOCAL * depths[:, None], depths])
    count = len(depths)
    mask = np.zeros((SIZE, SIZE), bool) if mask is None else mask
    scales, opacities = np.full((count, 3), scale), np.asarray(opacities, float)
    return UnitInput(
        sequence="hand",
        camera_id=0,
        views=Views(
            camera_ids=np.array([0]),
            fx_fy_cx_cy=np.array([[FOCAL, FOCAL, PRINCIPAL, PRINCIPAL]]),
            w2c=np.eye(4)[None],
            width=SIZE,
            height=SIZE,
        ),
        gaussians=Gaussians(
            means=means[None],
            quaternions=np.tile([1.0, 0.0, 0.0, 0.0], (1, count, 1)),
            scales=scales,
            opacities=opacities,
            foreground=np.ones(count, bool),
        ),
        constants=gaussian_constants(scales, opacities),
        frames_jpeg=[],
        packed_mask=lambda view, t: np.packbits(mask),
    )


def test_a_query_pixel_is_rendered_at_its_centre():
    """The mask holds pixel (8, 8) alone; a Gaussian projects to (8.5, 8.5). At the centre its
    alpha is 0.9 (a surface at its own depth, unprojected onto it); at the corner (8, 8) it would
    be 0.9 exp(-0.5 / 0.6) = 0.39 (no surface, no query)."""
    mask = np.zeros((SIZE, SIZE), bool)
    mask[8, 8] = True
    unit = unit_with([[8.5, 8.5]], [2.0], [0.9], mask)
    frames, gaussians, distance = attach_queries(unit, 4, REFINED.max_attach_distance_m, 0)
    np.testing.assert_array_equal(frames, [0])
    np.testing.assert_array_equal(gaussians, [0])
    assert distance[0] < 1e-9


def test_a_far_attachment_is_refused_by_our_rule_and_kept_by_the_releases():
    """A wide Gaussian (sigma 0.1 m = 25 px at 2 m) centred on pixel (8.5, 8.5) covers mask pixel
    (20, 8): the surface rendered there, at the Gaussian's depth, lies 12 px x 2 m / 500 = 4.8 cm from
    its centre. ``pstudio.max_attach_distance_m`` 0.03 (refined) refuses that query; 0 (release)
    attaches it."""
    mask = np.zeros((SIZE, SIZE), bool)
    mask[8, 20] = True
    unit = unit_with([[8.5, 8.5]], [2.0], [0.9], mask, scale=0.1)
    refused = attach_queries(unit, 4, REFINED.max_attach_distance_m, 0)
    assert [len(part) for part in refused] == [0, 0, 0]
    release = with_rules(REFINED, "release")
    frames, gaussians, distance = attach_queries(unit, 4, release.max_attach_distance_m, 0)
    np.testing.assert_array_equal(gaussians, [0])
    np.testing.assert_allclose(distance, [0.048], atol=1e-9)


def test_a_mask_is_read_at_the_pixel_holding_the_projection():
    """Only mask pixel (column 10, row 20) is set: (10.9, 20.9) lies in it, (9.6, 19.6) does not
    (rounding to the nearest integer would swap them)."""
    mask = np.zeros((SIZE, SIZE), bool)
    mask[20, 10] = True
    unit = unit_with([[10.9, 20.9], [9.6, 19.6]], [2.0, 2.0], [0.9, 0.9], mask)
    np.testing.assert_array_equal(multiview_mask_fraction(unit, np.array([0, 1])), [1.0, 0.0])


def test_the_15_m_background_makes_nothing_visible():
    """Two Gaussians 15 m away, on their own pixels: opacity 0.3 leaves T = 0.7 there, so the
    depth is the 15 m background (no surface), equal to the point's depth yet not a sighting;
    opacity 0.9 is a surface at 15 m and is seen."""
    unit = unit_with([[8.5, 8.5], [24.5, 24.5]], [15.0, 15.0], [0.3, 0.9])
    tracks, visible, _ = track_visibility(unit, np.array([0, 1]), REFINED.depth_delta_m)
    np.testing.assert_allclose(tracks[0, :, 2], [15.0, 15.0])
    np.testing.assert_array_equal(visible, [[False, True]])


def _mask_fraction_per_camera(unit: UnitInput, gaussians: np.ndarray) -> np.ndarray:
    """The statistic's definition, camera by camera: transform_points, in_view, project, floor."""
    on_mask, seen_count = np.zeros(len(gaussians)), np.zeros(len(gaussians))
    for t in range(unit.gaussians.num_frames):
        centres = unit.gaussians.means[t, gaussians].astype(np.float64)
        for view in range(len(unit.views.camera_ids)):
            intrinsics = unit.views.fx_fy_cx_cy[view]
            points = transform_points(unit.views.w2c[view], centres)
            seen = in_view(points, intrinsics, unit.views.width, unit.views.height)
            pixels = np.floor(project(points[seen], intrinsics)).astype(np.int64)
            seen_count += seen
            on_mask[seen] += unit.mask(view, t)[pixels[:, 1], pixels[:, 0]]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(seen_count > 0, on_mask / seen_count, np.nan)


def test_camera_pixel_gives_the_bits_of_transform_points_and_project():
    """The statistic's per-centre projection against the arrays' functions, bit for bit (a sum in
    another order differs in about 0.3% of the coordinates here)."""
    rng = np.random.default_rng(5)
    angles = rng.uniform(-np.pi, np.pi, size=3)
    w2c = np.eye(4)
    w2c[:3, :3] = rotation_from_roll_pitch_yaw(*angles)
    w2c[:3, 3] = rng.normal(0.0, 2.0, size=3)
    intrinsics = np.array([1400.0, 1395.5, 640.2, 359.7])
    centres = rng.normal(0.0, 3.0, size=(20_000, 3)).astype(np.float32).astype(np.float64)
    points = transform_points(w2c, centres)
    expected = project(points, intrinsics)
    front = points[:, 2] > 0
    got = np.array([camera_pixel(*centre, w2c, intrinsics) for centre in centres])
    np.testing.assert_array_equal(got[:, 2], points[:, 2])
    np.testing.assert_array_equal(got[front, :2], expected[front])


def test_the_mask_statistic_matches_its_definition_camera_by_camera():
    """Random rigs of 27 cameras around float32 centres (some behind a camera, some outside its
    image) and random masks: the same fractions as projecting camera by camera."""
    rng = np.random.default_rng(4)
    width, height, frames, cameras = 64, 48, 3, 27
    for _ in range(30):
        count = int(rng.integers(1, 300))
        angles = rng.uniform(-np.pi, np.pi, size=(cameras, 3))
        w2c = np.tile(np.eye(4), (cameras, 1, 1))
        w2c[:, :3, :3] = rotation_from_roll_pitch_yaw(angles[:, 0], angles[:, 1], angles[:, 2])
        w2c[:, :3, 3] = rng.normal(0.0, 0.5, size=(cameras, 3)) + [0.0, 0.0, 3.0]
        intrinsics = np.column_stack([rng.uniform(20, 60, (cameras, 2)), rng.uniform(20, 40, (cameras, 2))])
        means = rng.normal(0.0, 1.0, size=(frames, count, 3)).astype(np.float32)
        masks = rng.random((frames, cameras, height, width)) < 0.5
        unit = UnitInput(
            sequence="rig",
            camera_id=0,
            views=Views(np.arange(cameras), intrinsics, w2c, width, height),
            gaussians=Gaussians(
                means, np.zeros((frames, count, 4)), np.ones((count, 3)), np.ones(count), np.ones(count, bool)
            ),
            constants=gaussian_constants(np.ones((count, 3)), np.ones(count)),
            frames_jpeg=[],
            packed_mask=lambda view, t, masks=masks: np.packbits(masks[t, view]),
        )
        gaussians = rng.permutation(count)[: max(1, count // 2)]
        fractions = multiview_mask_fraction(unit, gaussians)
        assert ((fractions > 0) & (fractions < 1)).any() or count < 20
        np.testing.assert_array_equal(fractions, _mask_fraction_per_camera(unit, gaussians))
