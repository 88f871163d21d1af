"""ADT geometry on synthetic arrays with analytic truth: the upright rotation, rigid attachment,
depth-test visibility with the hand term, and a whole chunk through ``candidate_clip``."""

import numpy as np
import pytest

from pipeline.adt.queries import draw_query_pixels, query_pixel_pools
from pipeline.adt.records import Chunk, DepthMetres, Frame, IdRuns, Instances
from pipeline.adt.rectify import (
    CAM_ROT_FROM_CAM,
    rotate_cw,
    rotate_pixels_cw,
    stored_cam_from_world,
    stored_intrinsics,
    unrotate_pixels_cw,
)
from pipeline.adt.settings import AdtConfig
from pipeline.adt.tracks import attach, candidate_clip, carry
from pipeline.adt.visibility import frame_visibility, interior, sample_depth
from pipeline.settings.fields import with_overrides
from pipeline.settings.run_config import RunConfig
from pipeline.sources import RunChoices

S, F = 512, 280.0
# The generator's camera has its principal point at projectaria-tools' (256, 256), pixel centres at
# integers: (256.5, 256.5) with centres at +0.5. After the clockwise turn (x, y) -> (512 - y, x).
K_UNROTATED = np.array([F, F, 256.5, 256.5])
K = np.array([F, F, 255.5, 256.5])
CX, CY = K[2], K[3]


def rot_z(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def pose(rotation, translation):
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = rotation, translation
    return out


def pinhole(points, k=K):
    return np.stack([k[0] * points[:, 0] / points[:, 2] + k[2], k[1] * points[:, 1] / points[:, 2] + k[3]], 1)


def test_rotate_cw_moves_pixels_clockwise():
    image = np.zeros((S, S), np.int32)
    image[10, 300] = 1  # row 10, column 300: near the top edge
    rotated = rotate_cw(image)
    # Clockwise: the top edge becomes the right edge; (row v, col u) -> (row u, col S-1-v).
    assert rotated[300, S - 1 - 10] == 1
    assert rotated.sum() == 1
    corners = np.zeros((4, 4), int)
    corners[0, 0] = 1  # top-left goes to top-right under a clockwise quarter turn
    assert rotate_cw(corners)[0, 3] == 1


def test_stored_intrinsics_are_the_rotated_generator_camera():
    np.testing.assert_array_equal(stored_intrinsics(512, 280.0), [280.0, 280.0, 255.5, 256.5])
    np.testing.assert_array_equal(stored_intrinsics(64, 50.0), [50.0, 50.0, 31.5, 32.5])


def test_rotated_camera_projects_onto_rotated_pixels():
    rng = np.random.default_rng(0)
    points = rng.uniform([-1, -1, 0.5], [1, 1, 4], size=(200, 3))
    rotated_points = points @ CAM_ROT_FROM_CAM[:3, :3].T
    # The unrotated camera's axis (256.5, 256.5) lands at (255.5, 256.5): K serves the rotated one.
    expected = rotate_pixels_cw(pinhole(points, K_UNROTATED), S)
    np.testing.assert_allclose(pinhole(rotated_points), expected, atol=1e-9)
    np.testing.assert_allclose(unrotate_pixels_cw(expected, S), pinhole(points, K_UNROTATED), atol=1e-9)
    # Pixel contents agree: mark the pixel under each point in the unrotated image, rotate the
    # image, and the rotated camera's projection falls in the marked pixel.
    image = np.zeros((S, S), np.int32)
    uv = pinhole(points, K_UNROTATED)
    keep = (uv >= 0).all(1) & (uv < S).all(1)
    image[np.floor(uv[keep, 1]).astype(int), np.floor(uv[keep, 0]).astype(int)] = np.arange(1, keep.sum() + 1)
    rotated = rotate_cw(image)
    xy = pinhole(rotated_points[keep])
    assert (
        rotated[np.floor(xy[:, 1]).astype(int), np.floor(xy[:, 0]).astype(int)]
        == np.arange(1, keep.sum() + 1)
    ).all()


def test_stored_extrinsics_compose_camera_pose_and_rotation():
    world_from_camera = pose(rot_z(0.3), [1.0, 2.0, 3.0])
    point_world = np.array([1.5, 2.5, 4.0])
    in_camera = world_from_camera[:3, :3].T @ (point_world - world_from_camera[:3, 3])
    expected = np.array([-in_camera[1], in_camera[0], in_camera[2]])  # X' = -Y, Y' = X
    got = stored_cam_from_world(world_from_camera) @ np.append(point_world, 1.0)
    np.testing.assert_allclose(got[:3], expected, atol=1e-12)


def test_attach_then_carry_follows_the_object_pose():
    rng = np.random.default_rng(1)
    points_object = rng.uniform(-0.2, 0.2, size=(50, 3))
    obj_q, obj_t = pose(rot_z(0.2), [0.1, -0.1, 2.0]), pose(rot_z(0.9), [0.4, 0.1, 2.5])
    cam_q = np.linalg.inv(pose(rot_z(0.05), [0.0, 0.0, -0.3]))
    cam_t = np.linalg.inv(pose(rot_z(-0.1), [0.2, 0.0, -0.1]))
    # Truth: explicit composition, point by point.
    truth_q = np.array([(cam_q @ obj_q @ np.append(p, 1))[:3] for p in points_object])
    truth_t = np.array([(cam_t @ obj_t @ np.append(p, 1))[:3] for p in points_object])
    xy, depth = pinhole(truth_q), truth_q[:, 2]
    poses_q = np.repeat(obj_q[None], 50, axis=0)
    recovered = attach(xy, depth, K, cam_q, poses_q)
    np.testing.assert_allclose(recovered, points_object, atol=1e-9)
    moved = carry(recovered, cam_t, obj_t[None], np.zeros(50, np.int64))
    np.testing.assert_allclose(moved, truth_t, atol=1e-9)


def test_carry_by_object_is_each_tracks_own_product_bit_for_bit():
    rng = np.random.default_rng(5)
    cam = np.linalg.inv(pose(rot_z(0.3), [0.2, -0.1, 0.4]))
    for count in (1, 7):
        poses = np.stack([pose(rot_z(a), rng.uniform(-2, 2, 3)) for a in rng.uniform(0, 6, count)])
        which = rng.integers(0, count, 300)
        points = rng.uniform(-0.5, 0.5, (300, 3))
        own = cam[None] @ poses[which]  # one product per track
        expected = np.einsum("nij,nj->ni", own[:, :3, :3], points) + own[:, :3, 3]
        np.testing.assert_array_equal(carry(points, cam, poses, which), expected)


def test_depth_read_at_pixels_is_the_metre_image_there():
    rng = np.random.default_rng(6)
    depth_mm = rng.uniform(0, 5000, (S, S)).astype(np.float32)
    depth_mm[rng.random((S, S)) < 0.1] = 0.0
    frame = Frame(depth_mm, np.zeros((S, S), np.uint64), np.eye(4), {}, 0)
    rows, cols = rng.integers(0, S, 1000), rng.integers(0, S, 1000)
    np.testing.assert_array_equal(DepthMetres(depth_mm)[rows, cols], frame.depth_m()[rows, cols])
    xy = rng.uniform(0, S, (1000, 2))
    np.testing.assert_array_equal(
        sample_depth(DepthMetres(depth_mm), xy, 0.05), sample_depth(frame.depth_m(), xy, 0.05)
    )


def test_sample_depth_is_exact_at_centres_and_bilinear_between():
    cols = np.arange(S, dtype=np.float32)
    depth = np.tile(1.0 + 0.001 * cols, (S, 1)).astype(np.float32)  # depth grows 1 mm per column
    at_centre = sample_depth(depth, np.array([[100.5, 7.5]]))
    assert at_centre[0] == pytest.approx(depth[7, 100])
    between = sample_depth(depth, np.array([[100.75, 7.5]]))  # a quarter of the way to column 101
    assert between[0] == pytest.approx(1.0 + 0.001 * 100.25, abs=1e-6)
    depth[7, 101] = 0.0  # a neighbour without surface: the containing pixel's value
    assert sample_depth(depth, np.array([[100.75, 7.5]]))[0] == pytest.approx(depth[7, 100])
    depth[7, 100] = 0.0
    assert np.isnan(sample_depth(depth, np.array([[100.25, 7.25]]))[0])


def visibility_scene():
    """Wall (id 1) at z = 2; an occluder (id 2) at z = 1 on columns 100-199; the wearer's hand
    (id 9) at z = 0.5 on columns 300-399, rows 0-255."""
    depth = np.full((S, S), 2.0, np.float32)
    ids = np.ones((S, S), np.uint64)
    depth[:, 100:200], ids[:, 100:200] = 1.0, 2
    depth[:256, 300:400], ids[:256, 300:400] = 0.5, 9
    return depth, ids


def on_wall(x, y, z=2.0):
    return np.array([(x - CX) * z / F, (y - CY) * z / F, z])


def test_visibility_depth_test_hand_term_and_frustum():
    depth, ids = visibility_scene()
    delta = 0.02
    points = np.array(
        [
            on_wall(50.5, 50.5),  # open wall: visible
            on_wall(150.5, 50.5),  # wall behind the occluder: hidden by depth
            on_wall(350.5, 100.5),  # wall behind the hand: hidden by depth and hand
            on_wall(350.5, 100.5, 0.5),  # on the hand's surface: depth agrees, hand term hides it
            on_wall(50.5, 50.5, 2.0 + 0.5 * delta),  # within delta of the surface: visible
            on_wall(50.5, 50.5, 2.0 + 1.5 * delta),  # beyond delta: hidden
            on_wall(600.0, 50.5),  # outside the image
            [0.1, 0.1, -2.0],  # behind the camera
            on_wall(150.5, 300.5, 1.0),  # on the occluder, id 2
        ]
    )
    object_ids = np.array([1, 1, 1, 1, 1, 1, 1, 1, 2], np.uint64)
    visible, on_own = frame_visibility(points, object_ids, depth, ids, frozenset({9}), K, delta)
    assert visible.tolist() == [True, False, False, False, True, False, False, False, True]
    assert on_own.tolist() == [True, False, False, False, True, True, False, False, True]


def blocky_ids(rng, shape=(61, 47)):
    """Random rectangles of 5 ids over a [H, W] uint64 image, single pixels included."""
    ids = np.zeros(shape, np.uint64)
    for _ in range(80):
        r, c = rng.integers(0, shape[0]), rng.integers(0, shape[1])
        h, w = rng.integers(1, 12, size=2)
        ids[r : r + h, c : c + w] = rng.integers(0, 5)
    return ids


def test_interior_is_the_one_id_3x3_neighbourhood():
    rng = np.random.default_rng(3)
    for _ in range(5):
        ids = blocky_ids(rng)
        # Definition: every pixel of the 3x3 window (edge-padded) holds the centre's id.
        windows = np.lib.stride_tricks.sliding_window_view(np.pad(ids, 1, mode="edge"), (3, 3))
        expected = (windows == ids[..., None, None]).all(axis=(-1, -2))
        assert 0 < expected.mean() < 1
        np.testing.assert_array_equal(interior(ids), expected)


def test_id_runs_read_like_the_image():
    rng = np.random.default_rng(4)
    ids = blocky_ids(rng)
    runs = IdRuns.of(ids)
    assert len(runs.values) < ids.size / 3
    np.testing.assert_array_equal(runs.unique(), np.unique(ids))
    rows, cols = np.mgrid[0 : ids.shape[0], 0 : ids.shape[1]]
    np.testing.assert_array_equal(runs[rows.ravel(), cols.ravel()], ids.ravel())
    np.testing.assert_array_equal(runs.expand(runs.values), ids)
    for chosen in ({1}, {0, 3, 4}, {7}):
        chosen_runs = np.isin(runs.values, list(chosen))
        np.testing.assert_array_equal(runs.expand(chosen_runs), np.isin(ids, list(chosen)))


def test_query_pixel_pools_are_the_image_rule():
    rng = np.random.default_rng(7)
    cases = ((frozenset({4}), frozenset({2, 3})), (frozenset(), frozenset({1})), (frozenset(), frozenset()))
    for human, dynamic in cases:
        ids = blocky_ids(rng)
        depth_mm = np.where(rng.random(ids.shape) < 0.1, 0.0, 1500.0).astype(np.float32)
        frame = Frame(depth_mm, ids, np.eye(4), {}, 0)
        # The rule on the id image: a surface, an id (not 0, not the human), the id's interior.
        ok = (depth_mm > 0) & (ids != 0) & interior(ids) & ~np.isin(ids, list(human))
        on_dynamic = ok & np.isin(ids, list(dynamic))
        dynamic_pool, static_pool = query_pixel_pools(frame, IdRuns.of(ids), Instances(human, dynamic))
        np.testing.assert_array_equal(dynamic_pool, np.flatnonzero(on_dynamic))
        np.testing.assert_array_equal(static_pool, np.flatnonzero(ok & ~on_dynamic))
        assert len(static_pool)


def test_query_draw_honours_the_dynamic_share():
    rng = np.random.default_rng(0)
    dynamic, static = np.arange(1000), np.arange(1000, 3000)
    chosen = draw_query_pixels(dynamic, static, 100, 0.25, rng)
    assert len(set(chosen.tolist())) == 100
    assert (chosen < 1000).sum() == 25
    few = draw_query_pixels(np.arange(10), static, 100, 0.5, rng)
    assert (few < 10).sum() == 10
    assert len(few) == 100
    none = draw_query_pixels(np.arange(0), static, 100, 0.5, rng)
    assert (none >= 1000).all()
    assert len(none) == 100


class CardWorld:
    """Static camera (world = unrotated camera frame), a wall (id 1, static) at z = 3, a card
    (id 2, dynamic) at z = 1.5 sliding along +x by 4 cm per frame, and the wearer's hand
    (id 9) at z = 0.8 over image rows 400-511 (stored camera). Depth and ids are rendered
    analytically per stored pixel centre."""

    WALL, CARD, HAND = 1, 2, 9
    HALF, STEP = 0.25, 0.04

    def card_pose(self, t):
        return pose(np.eye(3), [self.STEP * t, 0.0, 1.5])

    def frame(self, t):
        cam_from_world = CAM_ROT_FROM_CAM.copy()  # world = unrotated camera
        rows, cols = np.mgrid[0:S, 0:S]
        ray = np.stack([(cols + 0.5 - CX) / F, (rows + 0.5 - CY) / F], -1)  # stored camera
        # stored X' = -Y, Y' = X  =>  world X = Y', world Y = -X'
        world_x_card, world_y_card = ray[..., 1] * 1.5, -ray[..., 0] * 1.5
        on_card = (np.abs(world_x_card - self.STEP * t) < self.HALF) & (np.abs(world_y_card) < self.HALF)
        depth = np.where(on_card, 1.5, 3.0).astype(np.float32)
        ids = np.where(on_card, self.CARD, self.WALL).astype(np.uint64)
        depth[400:], ids[400:] = 0.8, self.HAND
        depth_mm = 1000 * depth
        return Frame(depth_mm, ids, cam_from_world, {self.WALL: np.eye(4), self.CARD: self.card_pose(t)}, t)

    def instances(self, ids):
        present = set(ids.tolist())
        return Instances(frozenset({self.HAND} & present), frozenset({self.CARD} & present))


def test_annotate_chunk_matches_the_card_world():
    world = CardWorld()
    config = with_overrides(RunConfig(), ["adt.tracks_per_clip=100", "adt.oversample=2"])
    reads = []

    def read_frame(t):
        reads.append(t)
        return world.frame(t)

    clip = candidate_clip(
        Chunk("card_0", "card/chunk_0", np.arange(4)),
        read_frame,
        lambda t: b"jpeg",
        world.instances,
        config.section(AdtConfig),
        RunChoices.of(config, "adt"),
    )
    assert reads == [0, 1, 2, 3]  # each frame's depth and ids are read once
    n = clip.num_tracks
    assert n == 200
    assert clip.tracks_xyz.shape == (4, n, 3)
    np.testing.assert_array_equal(clip.fx_fy_cx_cy, [280.0, 280.0, 255.5, 256.5])
    t_q = clip.queries_xyt[:, 2].astype(int)
    object_ids = clip.track_stats.extra["object_id"]
    assert set(object_ids.tolist()) <= {1, 2}  # never the hand
    on_card = object_ids == 2
    assert clip.track_stats.extra["dynamic"].tolist() == on_card.tolist()
    assert 0.3 < on_card.mean() < 0.7  # the dynamic share, 0.5 by default
    # Truth: wall points stay put; card points slide by STEP per frame along world x = stored y.
    for t in range(4):
        shift = np.where(on_card, world.STEP * (t - t_q), 0.0)
        expected = clip.tracks_xyz[t_q, np.arange(n)] + np.stack([0 * shift, shift, 0 * shift], 1)
        np.testing.assert_allclose(clip.tracks_xyz[t], expected, atol=1e-9)
    # Queries are pixel centres whose track projects back onto them at the query frame.
    at_query = clip.tracks_xyz[t_q, np.arange(n)]
    np.testing.assert_allclose(pinhole(at_query), clip.queries_xyt[:, :2], atol=1e-6)
    assert clip.visibility[t_q, np.arange(n)].all()
    # Visibility truth: a wall point is hidden exactly when the card covers it (or off-image).
    for t in range(4):
        points = clip.tracks_xyz[t]
        truth_frame = world.frame(t)
        uv = pinhole(points)
        rows, cols = np.floor(uv[:, 1]).astype(int), np.floor(uv[:, 0]).astype(int)
        inside = (uv >= 0).all(1) & (uv < S).all(1)
        covered = np.zeros(n, bool)
        covered[inside] = truth_frame.ids[rows[inside], cols[inside]] != object_ids[inside]
        assert (clip.visibility[t] == (inside & ~covered)).all()
    agreement = clip.track_stats.mask_agreement
    assert np.allclose(agreement, 1.0)  # visible points always sit on their own id here
    np.testing.assert_allclose(clip.extrinsics_w2c, np.repeat(CAM_ROT_FROM_CAM[None], 4, 0))
