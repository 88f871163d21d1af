"""The selected-pixel path culls splats before projecting them in full (a bound of each footprint,
then its exact box against the requested pixels' blocks): on a scene where most splats lie off
the requested blocks, it keeps exactly the splats that reach them and renders the full frame's
depth bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pipeline.pstudio.render import render_depth_at, render_depth_image
from pipeline.pstudio.splats import (
    BLOCK,
    FEW_BLOCKS,
    LIMIT_BOX_BLOCKS,
    _boxes_meet_blocks,
    _boxes_reach,
    few_blocks,
    gaussian_constants,
    inside_image,
    project_splats,
    wanted_blocks,
)

WIDTH, HEIGHT = 200, 120
INTRINSICS = np.array([180.0, 170.0, 100.3, 59.7])


def crowded_scene(count: int = 20_000, seed: int = 0):
    """Gaussians [count] filling the left of the view and beyond its edges: random rotations, scales from 1 mm
    to 5 cm (some needles and discs), opacities around the 1/255 cut-off and up to 1, some behind
    the camera or at the near plane; means as float32, as params.npz stores them."""
    rng = np.random.default_rng(seed)
    depth = np.where(rng.random(count) < 0.03, rng.uniform(-0.5, 0.3, count), rng.uniform(1.0, 6.0, count))
    means = (
        np.stack([rng.uniform(-0.7, 0.2, count), rng.uniform(-0.45, 0.45, count), np.ones(count)], 1)
        * depth[:, None]
    )
    scales = np.exp(rng.uniform(np.log(1e-3), np.log(0.05), (count, 3)))
    scales[: count // 10, 0] *= 0.01  # needles and discs
    opacities = rng.uniform(0.5 / 255, 1.0, count)
    quaternions = Rotation.random(count, random_state=seed).as_quat(scalar_first=True)
    quaternions *= rng.uniform(0.5, 2.0, (count, 1))  # unnormalised, as stored
    w2c = np.eye(4)
    w2c[:3, :3] = Rotation.from_euler("xyz", [3, -4, 2], degrees=True).as_matrix()
    w2c[:3, 3] = [0.05, -0.02, 0.1]
    return (
        means.astype(np.float32),
        quaternions.astype(np.float32),
        gaussian_constants(scales, opacities),
        w2c,
    )


def clustered_points(rng: np.random.Generator) -> np.ndarray:
    """Points [P, 2] in three small clusters, at pixel centres, block edges and anywhere in a
    pixel, plus two outside the image."""
    centres = np.array([[20.5, 30.5], [137.5, 90.5], [199.5, 0.5]])
    cluster = np.concatenate([c + rng.integers(-3, 4, (12, 2)) for c in centres])
    edges = np.array([[4.0 * 9, 31.0], [4.0 * 9 - 1e-9, 31.0], [140.0, 4.0 * 22], [140.0, 4.0 * 22 - 1e-9]])
    anywhere = centres[:2] + rng.uniform(-2, 2, (6, 2)).reshape(3, 2, 2)
    outside = np.array([[-0.5, 10.0], [WIDTH + 0.5, 10.0]])
    return np.concatenate([cluster, edges, anywhere.reshape(-1, 2), outside])


def test_selected_points_render_the_full_frame_bit_for_bit_with_most_splats_culled():
    means, quaternions, constants, w2c = crowded_scene()
    full = project_splats(means, quaternions, constants, w2c, INTRINSICS, WIDTH, HEIGHT)
    points = clustered_points(np.random.default_rng(1))
    selected = project_splats(means, quaternions, constants, w2c, INTRINSICS, WIDTH, HEIGHT, points)
    depth, surface = render_depth_at(selected, points)
    # The full frame's splat lists, evaluated at the same points (pixel centres and the rest).
    full_depth, full_surface = render_depth_at(full, points)
    np.testing.assert_array_equal(depth, full_depth)
    np.testing.assert_array_equal(surface, full_surface)
    image_depth, image_surface = render_depth_image(full)
    inside = inside_image(points, WIDTH, HEIGHT)
    centres = inside & np.all(points % 1 == 0.5, axis=1)
    rows, cols = points[centres, 1].astype(int), points[centres, 0].astype(int)
    np.testing.assert_array_equal(depth[centres], image_depth[rows, cols])
    np.testing.assert_array_equal(surface[centres], image_surface[rows, cols])
    assert np.isnan(depth[~inside]).all()
    assert surface.sum() > 20
    assert (~surface[inside]).sum() > 3
    # The culling is exact: kept are precisely the full frame's splats whose footprint box meets
    # a requested block, in the same (depth) order, and that is a small part of the scene.
    blocks = {(int(x // BLOCK), int(y // BLOCK)) for x, y in points[inside]}
    low, high = full.xy - full.extent, full.xy + full.extent
    reaching = np.zeros(len(full), bool)
    for bx, by in blocks:
        reaching |= (
            (low[:, 0] < (bx + 1) * BLOCK)
            & (high[:, 0] >= bx * BLOCK)
            & (low[:, 1] < (by + 1) * BLOCK)
            & (high[:, 1] >= by * BLOCK)
        )
    np.testing.assert_array_equal(selected.index, full.index[reaching])
    assert len(selected) < 0.15 * len(full)
    assert len(full) > 10_000


def test_splats_at_equal_depth_keep_their_index_order():
    """Front to back, and Gaussians at exactly the same depth in index order (a stable sort)."""
    rng = np.random.default_rng(2)
    count = 3_000
    depth = rng.choice([1.0, 1.5, 2.25, 3.0], count)
    means = np.stack([rng.uniform(-0.3, 0.3, count) * depth, rng.uniform(-0.2, 0.2, count) * depth, depth], 1)
    constants = gaussian_constants(np.full((count, 3), 0.01), np.full(count, 0.8))
    quaternions = np.tile([1.0, 0.0, 0.0, 0.0], (count, 1))
    splats = project_splats(means, quaternions, constants, np.eye(4), INTRINSICS, WIDTH, HEIGHT)
    np.testing.assert_array_equal(splats.index, np.argsort(depth, kind="stable"))


def test_depth_limits_keep_every_depth_within_them_and_every_depth_test():
    """With a depth limit per point, splats deeper than the limit of every point of a tile are
    left out: a depth within the limit is the unlimited one bit for bit, one beyond it may become
    "no surface"; so a depth test that any surface beyond the limit fails (|z - D| < delta, limit
    z + delta) decides the same, here on 6,000 points across a crowded scene."""
    means, quaternions, constants, w2c = crowded_scene()
    rng = np.random.default_rng(4)
    points = np.concatenate([clustered_points(rng), rng.uniform([0, 0], [WIDTH, HEIGHT], (6_000, 2))])
    splats = project_splats(means, quaternions, constants, w2c, INTRINSICS, WIDTH, HEIGHT, points)
    depth, surface = render_depth_at(splats, points)
    # Depths that change slowly across the image (as a surface's do), so a tile's limit is low
    # where its points are near.
    z, delta = 0.5 + 6.0 * np.clip(points[:, 0], 0, WIDTH) / WIDTH + rng.uniform(0, 0.2, len(points)), 0.05
    limited_depth, limited_surface = render_depth_at(splats, points, limits=z + delta)
    within = surface & (depth <= z + delta)
    np.testing.assert_array_equal(limited_surface[within], True)
    np.testing.assert_array_equal(limited_depth[within], depth[within])
    kept = limited_surface & ~within
    np.testing.assert_array_equal(limited_depth[kept], depth[kept])  # beyond, yet found: the same
    np.testing.assert_array_equal(
        limited_surface & (np.abs(z - limited_depth) < delta), surface & (np.abs(z - depth) < delta)
    )
    # The limits did leave splats out: some depths beyond them became "no surface".
    assert (surface & ~limited_surface).sum() > 100
    assert within.sum() > 100
    np.testing.assert_array_equal(np.isnan(limited_depth), np.isnan(depth))
    # Projecting only the splats no deeper than the largest limit of a block they reach decides
    # the same (here the left half's points, whose limits keep out the scene's far part).
    left = points[:, 0] < WIDTH / 2
    near = project_splats(
        means, quaternions, constants, w2c, INTRINSICS, WIDTH, HEIGHT, points[left], (z + delta)[left]
    )
    near_depth, near_surface = render_depth_at(near, points[left], limits=(z + delta)[left])
    np.testing.assert_array_equal(near_surface[within[left]], True)
    np.testing.assert_array_equal(near_depth[within[left]], depth[left][within[left]])
    np.testing.assert_array_equal(
        near_surface & (np.abs(z[left] - near_depth) < delta),
        (surface & (np.abs(z - depth) < delta))[left],
    )
    assert len(near) < 0.8 * len(splats)
    # Exactly those: of the splats reaching the points' blocks, the ones with a block in their box
    # whose points' largest limit is no shallower than their depth (boxes wider than
    # LIMIT_BOX_BLOCKS blocks either way are kept untested).
    reaching = project_splats(means, quaternions, constants, w2c, INTRINSICS, WIDTH, HEIGHT, points[left])
    limit_of = {}
    for (x, y), limit in zip(points[left], (z + delta)[left], strict=True):
        if 0 <= x < WIDTH and 0 <= y < HEIGHT:
            block = (int(x // BLOCK), int(y // BLOCK))
            limit_of[block] = max(limit_of.get(block, -np.inf), limit)
    low, high = reaching.xy - reaching.extent, reaching.xy + reaching.extent
    last = np.array([WIDTH // BLOCK - 1, HEIGHT // BLOCK - 1])
    first_block = np.clip(np.floor(low / BLOCK), 0, last).astype(int)
    last_block = np.clip(np.floor(high / BLOCK), 0, last).astype(int)
    expected, unscanned = [], 0
    for k, ((x0, y0), (x1, y1)) in enumerate(zip(first_block, last_block, strict=True)):
        covered = [(x, y) for x in range(x0, x1 + 1) for y in range(y0, y1 + 1)]
        scanned = max(x1 - x0, y1 - y0) < LIMIT_BOX_BLOCKS
        unscanned += not scanned
        expected.append(not scanned or any(limit_of.get(b, -np.inf) >= reaching.depth[k] for b in covered))
    np.testing.assert_array_equal(near.index, reaching.index[np.array(expected)])
    assert unscanned > 10
    assert 0 < np.sum(expected) < 0.5 * len(reaching)


def box_meets_a_block(u, v, ext_x, ext_y, blocks) -> bool:
    """Whether [u +- ext_x] x [v +- ext_y] meets the image and one of ``blocks`` [by, bx] (bool)."""
    if u + ext_x < 0 or u - ext_x >= WIDTH or v + ext_y < 0 or v - ext_y >= HEIGHT:
        return False
    columns = slice(max(0, int(np.floor((u - ext_x) / BLOCK))), int(np.floor((u + ext_x) / BLOCK)) + 1)
    rows = slice(max(0, int(np.floor((v - ext_y) / BLOCK))), int(np.floor((v + ext_y) / BLOCK)) + 1)
    return bool(blocks[rows, columns].any())


def test_depth_limits_without_their_points_are_refused():
    """Limits [P] are the depths of points_uv [P, 2]: without the points they bound nothing."""
    means = np.array([[0.0, 0.0, 2.0]])
    constants = gaussian_constants(np.full((1, 3), 0.01), np.full(1, 0.8))
    quaternions = np.array([[1.0, 0.0, 0.0, 0.0]])
    with pytest.raises(ValueError, match="limits .* points_uv"):
        project_splats(means, quaternions, constants, np.eye(4), INTRINSICS, WIDTH, HEIGHT, limits=np.ones(1))


def test_the_culls_branchless_box_test_is_the_box_test():
    """The cull tests its boxes without branches (``_boxes_reach``, on a summed-area table): the
    answer of looking at every block the box covers, for 40,000 boxes on and off the image, on
    block and image edges, tiny and huge, against sparse and full block tables."""
    rng = np.random.default_rng(6)
    count = 40_000
    u = np.concatenate(
        [rng.uniform(-50, WIDTH + 50, count // 2), rng.integers(-2, WIDTH // BLOCK + 2, count // 2) * 4.0]
    )
    v = np.concatenate(
        [rng.uniform(-50, HEIGHT + 50, count // 2), rng.integers(-2, HEIGHT // BLOCK + 2, count // 2) * 4.0]
    )
    ext = np.exp(rng.uniform(np.log(1e-6), np.log(300), (2, count)))
    ext[:, ::7] = rng.integers(0, 9, (2, len(ext[0, ::7]))) * 2.0  # box edges on block edges
    u[::11] = -1e30  # culled splats' boxes
    for points in (clustered_points(rng), rng.uniform([0, 0], [WIDTH, HEIGHT], (5, 2)), None):
        wanted = wanted_blocks(points, WIDTH, HEIGHT)
        flags = np.empty(count, bool)
        _boxes_reach(u, v, ext[0], ext[1], WIDTH, HEIGHT, wanted, flags)
        blocks = np.diff(np.diff(wanted, axis=0), axis=1) > 0  # [blocks_y, blocks_x] holding a point
        expected = [box_meets_a_block(*box, blocks) for box in zip(u, v, ext[0], ext[1], strict=True)]
        np.testing.assert_array_equal(flags, expected)
        assert 0.01 < flags.mean() < 0.99
        if points is not None:  # few blocks: also against their list, as the cull tests them
            listed = few_blocks(wanted)
            rows, columns = np.nonzero(blocks)
            np.testing.assert_array_equal(listed, np.stack([columns, rows]))
            by_list = np.empty(count, bool)
            last_x, last_y = wanted.shape[1] - 2, wanted.shape[0] - 2
            corners = np.empty((5, count), np.int16)
            _boxes_meet_blocks(u, v, ext[0], ext[1], WIDTH, HEIGHT, last_x, last_y, listed, corners, by_list)
            np.testing.assert_array_equal(by_list, expected)


def test_only_a_few_blocks_are_listed():
    """The cull tests boxes against the wanted blocks' list up to FEW_BLOCKS of them, against the
    table beyond (and with none)."""
    rows, columns = np.divmod(np.arange(FEW_BLOCKS + 1), WIDTH // BLOCK)
    points = np.stack([columns * BLOCK + 1.5, rows * BLOCK + 0.5], axis=1)  # one in each block
    assert few_blocks(wanted_blocks(points[:FEW_BLOCKS], WIDTH, HEIGHT)).shape == (2, FEW_BLOCKS)
    assert few_blocks(wanted_blocks(points, WIDTH, HEIGHT)).shape == (2, 0)
    assert few_blocks(wanted_blocks(np.array([[-5.0, 3.0]]), WIDTH, HEIGHT)).shape == (2, 0)
    assert few_blocks(wanted_blocks(None, WIDTH, HEIGHT)).shape == (2, 0)


def test_projected_splats_are_contiguous_arrays_of_their_own():
    """The render kernels read each field contiguous: project_splats hands them so (no copy there)."""
    means, quaternions, constants, w2c = crowded_scene(2_000)
    splats = project_splats(means, quaternions, constants, w2c, INTRINSICS, WIDTH, HEIGHT)
    assert len(splats) > 100
    for field in (splats.xy, splats.conic, splats.opacity, splats.cutoff, splats.depth, splats.extent):
        assert field.flags.c_contiguous and field.flags.owndata
