"""Camera and SE(3) maths against hand-worked cases."""

import numpy as np
import pytest

from pipeline.core.geometry import (
    CV_FROM_FLU,
    in_image,
    invert_se3,
    project,
    rigid_transform_problem,
    rotation_from_roll_pitch_yaw,
    rotation_z,
    transform_points,
    unproject,
)


def test_project_and_unproject_hand_values():
    intrinsics = np.array([100.0, 200.0, 50.0, 40.0])
    point = np.array([1.0, -2.0, 4.0])
    # u = 100 * 1/4 + 50 = 75; v = 200 * -2/4 + 40 = -60
    np.testing.assert_allclose(project(point, intrinsics), [75.0, -60.0])
    np.testing.assert_allclose(unproject(np.array([75.0, -60.0]), np.array(4.0), intrinsics), point)


def test_in_image_is_half_open():
    pixels = np.array([[0.0, 0.0], [9.999, 4.999], [10.0, 1.0], [-0.001, 1.0]])
    assert in_image(pixels, 10, 5).tolist() == [True, True, False, False]


def test_rotation_conventions():
    # yaw 90 degrees takes x to y.
    np.testing.assert_allclose(rotation_z(np.pi / 2) @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    # roll 90 degrees takes y to z; pitch 90 degrees takes z to x.
    np.testing.assert_allclose(
        rotation_from_roll_pitch_yaw(np.pi / 2, 0, 0) @ [0, 1, 0], [0, 0, 1], atol=1e-12
    )
    np.testing.assert_allclose(
        rotation_from_roll_pitch_yaw(0, np.pi / 2, 0) @ [0, 0, 1], [1, 0, 0], atol=1e-12
    )
    # Order: R = Rz(yaw) Ry(pitch) Rx(roll): roll first. x stays x under roll, then pitch
    # 90 degrees sends x to -z, then yaw leaves -z alone.
    np.testing.assert_allclose(
        rotation_from_roll_pitch_yaw(0.3, np.pi / 2, 0.7) @ [1, 0, 0], [0, 0, -1], atol=1e-12
    )


def test_invert_and_apply_rigid_transform():
    transform = np.eye(4)
    transform[:3, :3] = rotation_z(0.4)
    transform[:3, 3] = [1.0, 2.0, 3.0]
    points = np.array([[0.5, -1.0, 2.0], [3.0, 0.0, -1.0]])
    back = transform_points(invert_se3(transform), transform_points(transform, points))
    np.testing.assert_allclose(back, points, atol=1e-12)


def test_waymo_camera_axes_to_opencv():
    # Waymo camera: x forward, y left, z up. A point 10 m ahead, 1 m left, 2 m up is, in
    # OpenCV axes, x = -1 (left is negative x), y = -2 (up is negative y), z = 10.
    np.testing.assert_allclose(transform_points(CV_FROM_FLU, np.array([10.0, 1.0, 2.0])), [-1, -2, 10])


@pytest.mark.parametrize(
    "matrix, words",
    [
        (np.full((4, 4), np.nan), "NaN"),
        (np.diag([1.0, 1.0, 0.0, 1.0]), "orthonormal"),
        (np.diag([1.0, 1.0, -1.0, 1.0]), "orthonormal"),
        (np.eye(3), "shape"),
    ],
)
def test_rigid_transform_problems_are_named(matrix, words):
    assert words in rigid_transform_problem(matrix)


def test_rigid_transform_accepts_rotation():
    transform = np.eye(4)
    transform[:3, :3] = rotation_from_roll_pitch_yaw(0.1, 0.2, 0.3)
    assert rigid_transform_problem(transform) is None
