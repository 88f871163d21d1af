"""Waymo range images to 3D points, following the dataset's own convention."""

from __future__ import annotations

import numpy as np

from pipeline.core.errors import InputError
from pipeline.core.geometry import rotation_from_roll_pitch_yaw
from pipeline.drivetrack.reader import LidarCalibration


def beam_inclinations(calibration: LidarCalibration, height: int, what: str = "lidar") -> np.ndarray:
    """Inclination per range-image row [H] in radians, row 0 the highest beam.

    Uses the stored per-beam values when present, else a uniform spread between min and max.
    ``what`` names the range image in errors.
    """
    if calibration.inclinations is not None:
        if calibration.inclinations.shape != (height,):
            raise InputError(
                f"{what}: lidar_calibration holds {calibration.inclinations.size} beam inclinations "
                f"for a range image of {height} rows"
            )
        inclinations = calibration.inclinations
    else:
        rows = np.arange(height)
        span = calibration.inclination_max - calibration.inclination_min
        inclinations = calibration.inclination_min + (rows + 0.5) / height * span
    return inclinations[::-1].astype(np.float64)


def range_image_to_vehicle(
    range_image: np.ndarray, lidar_to_vehicle: np.ndarray, inclinations: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Points of the returns with range > 0 in the vehicle frame at firing time.

    Args:
      range_image: [H, W] ranges in metres (<= 0 means no return).
      lidar_to_vehicle: [4, 4] lidar extrinsic.
      inclinations: [H] per row, row 0 the highest beam (see ``beam_inclinations``).
    Returns:
      points [M, 3] in row-major order of the kept pixels, and kept [H, W] bool.
    """
    height, width = range_image.shape
    az_correction = np.arctan2(lidar_to_vehicle[1, 0], lidar_to_vehicle[0, 0])
    ratio = (width - np.arange(width) - 0.5) / width
    azimuth = (2.0 * ratio - 1.0) * np.pi - az_correction
    kept = range_image > 0
    rows, cols = np.nonzero(kept)
    r = range_image[rows, cols].astype(np.float64)
    incl, az = inclinations[rows], azimuth[cols]
    sensor = np.stack(
        [r * np.cos(az) * np.cos(incl), r * np.sin(az) * np.cos(incl), r * np.sin(incl)], axis=1
    )
    points = sensor @ lidar_to_vehicle[:3, :3].T + lidar_to_vehicle[:3, 3]
    return points, kept


def apply_pixel_poses(points_vehicle: np.ndarray, pixel_poses: np.ndarray) -> np.ndarray:
    """World points [M, 3] from vehicle-frame points [M, 3] and per-pixel poses [M, 6].

    A pose is (roll, pitch, yaw, x, y, z): the vehicle's pose when that pixel was fired
    (TOP lidar rolling-shutter correction), rotation Rz(yaw) Ry(pitch) Rx(roll).
    """
    rotation = rotation_from_roll_pitch_yaw(pixel_poses[:, 0], pixel_poses[:, 1], pixel_poses[:, 2])
    return np.einsum("mij,mj->mi", rotation, points_vehicle) + pixel_poses[:, 3:6]


def top_lidar_world_points(
    range_image: np.ndarray,
    pixel_pose: np.ndarray,
    calibration: LidarCalibration,
    what: str,
) -> tuple[np.ndarray, np.ndarray]:
    """World points [M, 3] of a TOP range image [H, W] with its pixel poses [H, W, 6].

    Returns the points and the kept-pixel mask [H, W] (range > 0).
    """
    if not np.isfinite(range_image).all():
        raise InputError(f"{what}: range image contains NaN or infinity")
    if pixel_pose.shape[:2] != range_image.shape:
        raise InputError(
            f"{what}: lidar_pose shape {pixel_pose.shape[:2]} != range image {range_image.shape}"
        )
    inclinations = beam_inclinations(calibration, range_image.shape[0], what)
    points, kept = range_image_to_vehicle(range_image, calibration.lidar_to_vehicle, inclinations)
    if not kept.any():
        raise InputError(f"{what}: no returns (every range <= 0)")
    poses = pixel_pose[kept].astype(np.float64)
    if not np.isfinite(poses).all():
        raise InputError(f"{what}: per-pixel lidar pose contains NaN or infinity")
    return apply_pixel_poses(points, poses), kept
