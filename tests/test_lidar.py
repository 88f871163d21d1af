"""Range image to points: the dataset's convention, checked by hand and against the generator."""

import numpy as np

from pipeline.drivetrack.lidar import beam_inclinations, range_image_to_vehicle, top_lidar_world_points
from pipeline.drivetrack.reader import LidarCalibration, SegmentReader
from pipeline.samples.waymo_world import SEGMENT, timestamp


def test_uniform_inclinations_are_reversed():
    calibration = LidarCalibration(np.eye(4), None, -0.2, 0.2)
    # rows i: min + (i + 0.5) / H * span -> [-0.1, 0.1]; reversed so row 0 is highest.
    np.testing.assert_allclose(beam_inclinations(calibration, 2), [0.1, -0.1])


def test_range_image_hand_case():
    # 2 x 4 image, identity extrinsic: column j has azimuth (2 (W - j - 0.5) / W - 1) pi,
    # so column 1 looks at +pi/4 (front-left) and column 2 at -pi/4.
    ranges = np.zeros((2, 4))
    ranges[0, 1] = 2.0  # highest row, inclination 0.1
    ranges[1, 2] = 3.0  # lowest row, inclination -0.1
    points, kept = range_image_to_vehicle(ranges, np.eye(4), np.array([0.1, -0.1]))
    assert kept.sum() == 2
    c, s = np.cos(0.1), np.sin(0.1)
    r2 = np.sqrt(0.5)
    np.testing.assert_allclose(points[0], [2 * c * r2, 2 * c * r2, 2 * s], atol=1e-12)
    np.testing.assert_allclose(points[1], [3 * c * r2, -3 * c * r2, -3 * s], atol=1e-12)


def test_azimuth_correction_cancels_the_extrinsic_yaw():
    yaw = 0.3
    extrinsic = np.eye(4)
    extrinsic[:3, :3] = [[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]]
    extrinsic[:3, 3] = [1.0, 0.0, 2.0]
    ranges = np.zeros((1, 4))
    ranges[0, 1] = 5.0
    points, _ = range_image_to_vehicle(ranges, extrinsic, np.array([0.0]))
    # In the vehicle frame the column keeps its nominal azimuth +pi/4, from the lidar's origin.
    np.testing.assert_allclose(
        points[0] - [1, 0, 2], 5 * np.array([np.sqrt(0.5), np.sqrt(0.5), 0]), atol=1e-12
    )


def test_sample_world_points_match_the_generator_within_1mm(sample_split):
    folder, generated = sample_split
    reader = SegmentReader(folder, SEGMENT)
    calibration = reader.lidar_calibration()
    worst = 0.0
    frames = [0, 17, 39]
    for frame, lidar in zip(frames, reader.top_lidar_frames([timestamp(f) for f in frames]), strict=True):
        world, kept = top_lidar_world_points(lidar.range_image, lidar.pixel_pose, calibration, "test")
        truth = generated["points"][frame]
        assert kept.sum() == np.isfinite(truth[..., 0]).sum() > 10_000
        worst = max(worst, np.linalg.norm(world - truth[kept], axis=1).max())
    assert worst < 1e-3, f"worst point error {worst * 1000:.3f} mm"
