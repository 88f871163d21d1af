"""DriveTrack's shortcuts give bit-identical numbers to the plain computation they replace."""

from types import SimpleNamespace

import numpy as np

from pipeline.core.geometry import invert_se3, rotation_from_roll_pitch_yaw, transform_points
from pipeline.drivetrack.footprints import (
    MIN_BEAM_COSINE,
    MIN_LIMIT,
    BoxCells,
    BoxMotions,
    SweepFootprints,
    moved,
    row_spacings,
    sweep_footprints,
)
from pipeline.drivetrack.lidar import (
    MAX_RANGE_JUMP,
    TopSweep,
    box_points,
    kept_poses,
    posed_points,
    range_image_normals,
    sensor_points,
)
from pipeline.drivetrack.object_surface import (
    MAX_STEP_SPACINGS,
    MIN_NORMAL_COSINE,
    consistent_triangles,
    surface_triangles,
)
from pipeline.drivetrack.objects import SURFACE_GROW_M, box_poses, inside_box, on_surface_box
from pipeline.drivetrack.records import BoxLabels
from pipeline.drivetrack.visibility import depth_grid, nearest_depth_max4


def _plain_poses(pixel_pose, kept):
    poses = pixel_pose[kept].astype(np.float64)
    return rotation_from_roll_pitch_yaw(poses[:, 0], poses[:, 1], poses[:, 2]), poses[:, 3:6]


def test_kept_poses_per_column_and_per_pixel_match_the_plain_computation():
    rng = np.random.default_rng(0)
    kept = rng.random((8, 50)) > 0.3
    kept[:, 7] = False  # a column without returns
    columns = rng.normal(size=(50, 6)).astype(np.float32)
    per_pixel = rng.normal(size=(8, 50, 6)).astype(np.float32)
    for pixel_pose in (np.broadcast_to(columns, (8, 50, 6)).copy(), per_pixel):
        rotations, translations, pose_of_point = kept_poses(pixel_pose, kept, "test")
        expected_rotation, expected_translation = _plain_poses(pixel_pose, kept)
        assert np.array_equal(rotations[pose_of_point], expected_rotation)
        assert np.array_equal(translations[pose_of_point], expected_translation)


def test_posed_points_match_einsum_over_a_rotation_per_point():
    """Lidar points placed in the world by their column's pose without a rotation gathered per
    point: the bits of einsum over the gathered rotations (a sum in another order differs in about
    0.3% of the coordinates here)."""
    rng = np.random.default_rng(3)
    angles = rng.uniform(-np.pi, np.pi, size=(300, 3)) * rng.choice([1e-3, 1.0], size=(300, 1))
    rotations = rotation_from_roll_pitch_yaw(angles[:, 0], angles[:, 1], angles[:, 2])
    translations = rng.normal(0.0, 1e4, size=(300, 3))  # a vehicle kilometres from the origin
    pose_of_point = rng.integers(0, 300, size=100_000)
    points = rng.normal(0.0, 30.0, size=(100_000, 3))
    expected = np.einsum("mij,mj->mi", rotations[pose_of_point], points) + translations[pose_of_point]
    assert np.array_equal(posed_points(points, rotations, translations, pose_of_point), expected)


def test_box_points_match_testing_every_point():
    rng = np.random.default_rng(1)
    points = rng.uniform(-30, 30, size=(20000, 3))
    boxes = np.array([[5.0, -2.0, 0.5, 4.5, 1.9, 1.6, 0.7], [-20.0, 9.0, 1.0, 12.0, 2.5, 3.0, -2.0]])
    for box in boxes:
        local = transform_points(invert_se3(box_poses(box)), points)
        expected = np.flatnonzero(inside_box(local, box[3:6], 0.1))
        index, inside, _ = box_points(points, box, 0.1)
        assert len(expected) > 0
        assert np.array_equal(index, expected)
        assert np.array_equal(inside, local[expected])


def test_nearest_depth_with_a_prebuilt_tree():
    rng = np.random.default_rng(2)
    lidar_uv, lidar_z = rng.uniform(0, 100, size=(500, 2)), rng.uniform(1, 50, size=500)
    queries = rng.uniform(0, 100, size=(200, 2))
    plain = nearest_depth_max4(lidar_uv, lidar_z, queries, 100, 100)
    grid = depth_grid(lidar_uv)
    assert np.array_equal(nearest_depth_max4(lidar_uv, lidar_z, queries, 100, 100, grid), plain)


# The refined visibility's kernels against the array expressions they replace.


def _rotations(rng, count: int) -> np.ndarray:
    angles = rng.uniform(-np.pi, np.pi, size=(count, 3))
    return rotation_from_roll_pitch_yaw(angles[:, 0], angles[:, 1], angles[:, 2])


def _range_image(rng, height: int = 12, width: int = 80) -> tuple[np.ndarray, np.ndarray]:
    """Ranges [H, W] of a few surfaces with depth steps and holes, and their lidar-frame grid."""
    ranges = 10.0 + np.cumsum(rng.normal(0.0, 0.05, size=(height, width)), axis=1)
    ranges[:, width // 2 :] *= 0.6  # a step no neighbour crosses
    ranges[rng.random((height, width)) < 0.15] = 0.0
    inclinations = np.linspace(0.2, -0.3, height)
    return ranges, sensor_points(ranges, np.eye(4), inclinations)


def _plain_normals(points, ranges, pixels):
    rows, cols = np.unravel_index(pixels, ranges.shape)
    tangents = []
    for axis in (0, 1):
        here = ranges[rows, cols]
        best, best_jump = np.zeros((len(rows), 3)), np.full(len(rows), np.inf)
        for step in (-1, 1):
            r, c = (rows + step, cols) if axis == 0 else (rows, cols + step)
            on_image = (r >= 0) & (r < ranges.shape[0]) & (c >= 0) & (c < ranges.shape[1])
            r, c = np.where(on_image, r, 0), np.where(on_image, c, 0)
            there = np.where(on_image, ranges[r, c], 0.0)
            jump = np.abs(there - here)
            same = (there > 0) & (here > 0) & (jump <= MAX_RANGE_JUMP * here) & (jump < best_jump)
            best[same] = points[r[same], c[same]] - points[rows[same], cols[same]]
            best_jump[same] = jump[same]
        tangents.append((best, np.isfinite(best_jump)))
    (along_rows, has_row), (along_columns, has_column) = tangents
    normals = np.cross(along_rows, along_columns)
    length = np.linalg.norm(normals, axis=-1, keepdims=True)
    here = points[rows, cols]
    towards_lidar = -here / np.maximum(np.linalg.norm(here, axis=-1, keepdims=True), 1e-12)
    defined = (has_row & has_column)[:, None] & (length > 0)
    normals = np.where(defined, normals / np.where(length > 0, length, 1.0), towards_lidar)
    facing = np.einsum("ki,ki->k", normals, towards_lidar) >= 0
    return np.where(facing[:, None], normals, -normals)


def _sweep(rng) -> TopSweep:
    ranges, grid = _range_image(rng)
    kept = ranges > 0
    pose_of_point = np.flatnonzero(kept) % ranges.shape[1]
    world_from_lidar = _rotations(rng, ranges.shape[1]) @ _rotations(rng, 1)[0]
    points = rng.normal(0.0, 20.0, size=(int(kept.sum()), 3))
    return TopSweep(points, kept, np.flatnonzero(kept), grid, ranges, world_from_lidar, pose_of_point)


def test_range_image_normals_and_footprints_match_the_array_expressions():
    rng = np.random.default_rng(4)
    sweep = _sweep(rng)
    pixels = np.flatnonzero(sweep.kept)
    local = _plain_normals(sweep.grid, sweep.ranges, pixels)
    assert np.array_equal(range_image_normals(sweep.grid, sweep.ranges, pixels), local)
    index = np.sort(rng.choice(len(pixels), size=len(pixels) // 2, replace=False))
    to_world = sweep.world_from_lidar[sweep.pose_of_point[index]]
    normals = np.einsum("kij,kj->ki", to_world, local[index])
    assert np.array_equal(sweep.normals(index), normals)
    spacing = row_spacings(np.linspace(0.2, -0.3, sweep.ranges.shape[0]))
    rows, width = pixels[index] // sweep.ranges.shape[1], sweep.ranges.shape[1]
    ranges = sweep.ranges.ravel()[pixels[index]]
    beam = sweep.grid.reshape(-1, 3)[pixels[index]] / ranges[:, None]
    level = np.hypot(beam[:, 0], beam[:, 1])
    d_azimuth = np.stack([-beam[:, 1], beam[:, 0], np.zeros_like(level)], 1)
    d_inclination = np.stack([-beam[:, 0] * beam[:, 2] / level, -beam[:, 1] * beam[:, 2] / level, level], 1)
    beam, d_azimuth, d_inclination = (
        np.einsum("kij,kj->ki", to_world, v) for v in (beam, d_azimuth, d_inclination)
    )
    facing = np.einsum("ki,ki->k", normals, beam)
    facing = np.where(np.abs(facing) < MIN_BEAM_COSINE, np.copysign(MIN_BEAM_COSINE, facing), facing)
    footprints = sweep_footprints(sweep, index, spacing)
    for direction, half_angle, along in (
        (d_azimuth, np.full(len(index), np.pi / width), footprints.along_azimuth),
        (d_inclination, spacing[rows] / 2.0, footprints.along_inclination),
    ):
        slide = direction - beam * (np.einsum("ki,ki->k", normals, direction) / facing)[:, None]
        assert np.array_equal(along, slide * (ranges * half_angle)[:, None])


def test_object_surface_matches_the_array_expressions():
    rng = np.random.default_rng(5)
    ranges, _ = _range_image(rng)
    height, width = ranges.shape
    pixels = np.flatnonzero(ranges > 0)
    spacing = row_spacings(np.linspace(0.2, -0.3, height))
    rows, cols = pixels // width, pixels % width
    here = np.flatnonzero((rows + 1 < height) & (cols + 1 < width))

    def position(wanted):
        at = np.minimum(np.searchsorted(pixels, wanted), len(pixels) - 1)
        return np.where(pixels[at] == wanted, at, -1)

    right, down, diagonal = (position(pixels[here] + step) for step in (1, width, width + 1))
    has_right, has_down, has_diagonal = right >= 0, down >= 0, diagonal >= 0
    candidates = [
        (np.stack([here, right, down], 1), has_right & has_down),
        (np.stack([right, diagonal, down], 1), has_right & has_down & has_diagonal),
        (np.stack([here, diagonal, down], 1), ~has_right & has_down & has_diagonal),
        (np.stack([here, right, diagonal], 1), has_right & ~has_down & has_diagonal),
    ]
    triangles = np.concatenate([corners[keep] for corners, keep in candidates])
    corner_ranges = ranges.ravel()[pixels[triangles]]
    beam = np.maximum(2.0 * np.pi / width, spacing[rows[triangles]].max(axis=1))
    steps = np.ptp(corner_ranges, axis=1) <= MAX_STEP_SPACINGS * corner_ranges.min(axis=1) * beam
    expected = triangles[steps]
    assert 0 < len(expected) < len(triangles)
    assert np.array_equal(surface_triangles(pixels, ranges, spacing), expected)
    points = rng.normal(0.0, 1.0, size=(len(pixels), 3))
    points[: len(pixels) // 3, 2] = 0.0  # a flat part, where the normals below agree
    normals = np.where(
        rng.random((len(pixels), 1)) < 0.5, [[0.0, 0.0, 1.0]], rng.normal(size=(len(pixels), 3))
    )
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    corners = points[expected]
    own = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    length = np.linalg.norm(own, axis=1)
    own = own / np.where(length > 0, length, 1.0)[:, None]
    agreement = np.abs(np.einsum("mi,mci->mc", own, normals[expected])).min(axis=1)
    consistent = expected[(length > 0) & (agreement >= MIN_NORMAL_COSINE)]
    assert 0 < len(consistent) < len(expected)
    assert np.array_equal(consistent_triangles(points, normals, expected), consistent)


def _motions(rng, frames: int = 3, objects: int = 6) -> BoxMotions:
    """Box motions of objects crowded around the vehicle (overlapping boxes) over a few frames."""
    rows = frames * objects
    boxes = np.concatenate(
        [
            rng.uniform(-6.0, 6.0, (rows, 2)),
            rng.uniform(0.5, 1.0, (rows, 1)),
            rng.uniform(1.5, 5.0, (rows, 3)),
        ],
        axis=1,
    )
    boxes = np.concatenate([boxes, rng.uniform(-np.pi, np.pi, (rows, 1))], axis=1)
    labels = BoxLabels(  # sorted by (id, time), as the reader's
        np.repeat([f"object{k}" for k in range(objects)], frames),
        np.tile(np.arange(frames) * 100, objects),
        np.ones(rows, np.int64),
        boxes,
        boxes + rng.normal(0.0, 0.1, boxes.shape),
        np.ones(rows, np.int64),
    )
    unit = SimpleNamespace(boxes=labels, frames=SimpleNamespace(timestamps=np.arange(frames) * 100))
    poses = np.tile(np.eye(4), (frames, 1, 1))
    poses[:, :3, :3] = _rotations(rng, frames)
    poses[:, :3, 3] = rng.normal(0.0, 100.0, (frames, 3))
    return BoxMotions(unit, poses)


def test_labels_box_limits_and_moves_match_the_array_expressions():
    rng = np.random.default_rng(6)
    motions = _motions(rng)
    points = rng.uniform([-9.0, -9.0, -1.0], [9.0, 9.0, 3.0], size=(20000, 3))
    rows = motions._rows[1]
    expected = np.full(len(points), -1)
    for row in rows[::-1]:
        local = transform_points(motions._box_from_vehicle[row], points)
        expected[on_surface_box(local, motions._lidar[row, 3:6])] = motions._labels[row]
    labels = motions.labels_at(1, points)
    assert np.array_equal(labels, expected) and len(np.unique(labels)) > 3
    vehicle_from_world = invert_se3(box_poses(rng.normal(0.0, 5.0, 7)))
    footprints = SweepFootprints(
        *(rng.normal(0.0, 0.2, (len(points), 3)) for _ in range(4)), np.arange(len(points))
    )
    limits = np.ones((len(points), 4))
    for row in rows:
        members = np.flatnonzero(labels == motions._labels[row])
        box_from_world = motions._box_from_vehicle[row] @ vehicle_from_world
        local = transform_points(box_from_world, footprints.points[members])
        upper = motions._lidar[row, 3:6] / 2.0 + SURFACE_GROW_M
        lower = -upper
        lower[2] = SURFACE_GROW_M - motions._lidar[row, 5] / 2.0
        for axis, vectors in enumerate((footprints.along_azimuth, footprints.along_inclination)):
            for sign in (-1.0, 1.0):
                steps = sign * (vectors[members] @ box_from_world[:3, :3].T)
                with np.errstate(divide="ignore", invalid="ignore"):
                    room = np.where(
                        steps > 0,
                        (upper - local) / steps,
                        np.where(steps < 0, (lower - local) / steps, np.inf),
                    )
                limits[members, 2 * axis + (sign > 0)] = np.maximum(room.min(axis=1), 0.0)
    edge_rows = rng.choice([-1, 0, 0, 1], len(points))
    got, along_inclination = motions.box_limits(1, footprints, labels, vehicle_from_world, edge_rows)
    beyond = (edge_rows != 0) & (labels >= 0)
    assert np.array_equal(got[~beyond], np.clip(limits[~beyond], MIN_LIMIT, 1.0))
    assert np.array_equal(along_inclination[~beyond], footprints.along_inclination[~beyond])
    # Past the field of view's edge a footprint reaches its box's border (or its own half-vector, if
    # that is further), the other way as far as before.
    side = np.where(edge_rows > 0, 3, 2)[beyond]
    reach = got[beyond, side, None] * along_inclination[beyond]
    wanted = np.maximum(limits[beyond, side], 1.0)[:, None] * footprints.along_inclination[beyond]
    assert np.allclose(reach, wanted, rtol=1e-12, atol=1e-12) and beyond.sum() > 1000
    back = got[beyond, 5 - side, None] * along_inclination[beyond]
    before = np.clip(limits[beyond, 5 - side], MIN_LIMIT, 1.0)[:, None] * footprints.along_inclination[beyond]
    assert np.allclose(back, before, rtol=1e-12, atol=1e-12)
    assert np.array_equal(got[beyond][:, :2], np.clip(limits[beyond][:, :2], MIN_LIMIT, 1.0))
    moves = motions.moves(1, 2)
    movable = np.flatnonzero(moves.row_of_label >= 0)
    index = np.flatnonzero((labels < 0) | np.isin(labels, movable))
    transforms = np.tile(np.eye(4), (len(index), 1, 1))
    on_object = labels[index] >= 0
    row = moves.row_of_label[labels[index][on_object]]
    transforms[on_object, :3, :3], transforms[on_object, :3, 3] = (
        moves.rotations[row],
        moves.translations[row],
    )
    placed = np.einsum("kij,kj->ki", transforms[:, :3, :3], footprints.points[index]) + transforms[:, :3, 3]
    turned = np.einsum("kij,kj->ki", transforms[:, :3, :3], footprints.normals[index])
    still = ~on_object
    placed[still], turned[still] = footprints.points[index][still], footprints.normals[index][still]
    got = moved(index, labels, moves, footprints.points, footprints.normals)
    assert np.array_equal(got[0], placed) and np.array_equal(got[1], turned)


def test_box_cells_match_a_stable_sort_of_cell_keys():
    rng = np.random.default_rng(7)
    low = rng.uniform(0.0, 500.0, size=(3000, 2))
    high = low + rng.exponential(4.0, size=(3000, 2))
    origin, side, columns, rows, starts, members = BoxCells(low, high).arrays
    first, last = np.floor((low - origin) / side).astype(int), np.floor((high - origin) / side).astype(int)
    keys = [
        (row * columns + column, j)
        for j in range(len(low))
        for row in range(first[j, 1], last[j, 1] + 1)
        for column in range(first[j, 0], last[j, 0] + 1)
    ]
    order = sorted(keys)
    assert np.array_equal(members, [j for _, j in order])
    assert np.array_equal(np.diff(starts), np.bincount([key for key, _ in keys], minlength=rows * columns))
