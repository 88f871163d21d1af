"""DriveTrack's shortcuts give bit-identical numbers to the plain computation they replace."""

import numpy as np

from pipeline.core.geometry import invert_se3, rotation_from_roll_pitch_yaw, transform_points
from pipeline.drivetrack.lidar import box_points, kept_poses, posed_points
from pipeline.drivetrack.objects import box_poses, inside_box
from pipeline.drivetrack.visibility import depth_tree, nearest_depth_max4


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
    tree = depth_tree(lidar_uv)
    assert np.array_equal(nearest_depth_max4(lidar_uv, lidar_z, queries, 100, 100, tree), plain)
