"""Waymo range images to 3D points and surface normals, following the dataset's own convention."""

from __future__ import annotations

import dataclasses

import numba
import numpy as np

from pipeline.core.errors import InputError
from pipeline.core.geometry import rotation_from_roll_pitch_yaw
from pipeline.drivetrack.normals import range_image_normals
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


def sensor_points(
    range_image: np.ndarray, lidar_to_vehicle: np.ndarray, inclinations: np.ndarray
) -> np.ndarray:
    """Every pixel of a range image [H, W] as a point [H, W, 3] in the lidar frame (whatever its
    range); column j looks along azimuth ``(2 (W - j - 0.5) / W - 1) pi - atan2(E[1,0], E[0,0])``."""
    width = range_image.shape[1]
    az_correction = np.arctan2(lidar_to_vehicle[1, 0], lidar_to_vehicle[0, 0])
    ratio = (width - np.arange(width) - 0.5) / width
    azimuth = (2.0 * ratio - 1.0) * np.pi - az_correction
    incl, az = inclinations[:, None], azimuth[None, :]
    r = range_image.astype(np.float64)
    return np.stack([r * np.cos(az) * np.cos(incl), r * np.sin(az) * np.cos(incl), r * np.sin(incl)], -1)


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
    kept = range_image > 0
    sensor = sensor_points(range_image, lidar_to_vehicle, inclinations)[kept]
    return sensor @ lidar_to_vehicle[:3, :3].T + lidar_to_vehicle[:3, 3], kept


@dataclasses.dataclass(frozen=True)
class TopSweep:
    """A TOP sweep in the world: points [M, 3] of the kept pixels (range > 0, row-major), kept
    [H, W], and what their normals need: the lidar-frame grid [H, W, 3] of every pixel, the ranges
    [H, W], the world-from-vehicle rotations [P, 3, 3] of the sweep's poses with the pose of each
    kept point [M] (``kept_poses``), and the vehicle-from-lidar rotation [3, 3]."""

    points: np.ndarray
    kept: np.ndarray
    grid: np.ndarray
    ranges: np.ndarray
    pose_rotations: np.ndarray
    pose_of_point: np.ndarray
    lidar_rotation: np.ndarray

    def normals(self, index: np.ndarray) -> np.ndarray:
        """Unit world-frame normals [K, 3], facing the lidar, of the kept points ``index`` [K]."""
        local = range_image_normals(self.grid, self.ranges, np.flatnonzero(self.kept)[index])
        rotations = self.pose_rotations[self.pose_of_point[index]]
        return np.einsum("kij,kj->ki", rotations @ self.lidar_rotation, local)


def kept_poses(
    pixel_pose: np.ndarray, kept: np.ndarray, what: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World-from-vehicle rotations [P, 3, 3] and translations [P, 3] of the poses the kept pixels
    [H, W] were fired at, and the pose of each kept pixel [M] (row-major), from the pixel poses
    [H, W, 6]. Where each column holds one pose (the TOP lidar fires a column at once), P is the
    number of columns with a kept pixel: the same numbers as per pixel, H times fewer; else P = M."""
    if np.all(pixel_pose == pixel_pose[:1]):
        used = kept.any(axis=0)
        poses = pixel_pose[0, used].astype(np.float64)  # [C, 6], the columns with a kept pixel
        pose_of_point = (np.cumsum(used) - 1)[np.flatnonzero(kept) % kept.shape[1]]
    else:
        poses = pixel_pose[kept].astype(np.float64)
        pose_of_point = np.arange(len(poses))
    if not np.isfinite(poses).all():
        raise InputError(f"{what}: per-pixel lidar pose contains NaN or infinity")
    rotation = rotation_from_roll_pitch_yaw(poses[:, 0], poses[:, 1], poses[:, 2])
    return rotation, np.ascontiguousarray(poses[:, 3:6]), pose_of_point


@numba.njit(cache=True, nogil=True)
def posed_points(points, rotations, translations, pose_of_point):
    """Points [M, 3] moved by their poses: rotations[k] @ p + translations[k], k = pose_of_point[m]
    ([P, 3, 3], [P, 3], [M]), without gathering a rotation per point. Each row's products are
    summed as NumPy's einsum("mij,mj->mi") sums them, (x + z) + y: the same bits (NumPy 2.4's
    order; tests/test_drivetrack_shortcuts.py compares with einsum itself)."""
    out = np.empty_like(points)
    for m in range(points.shape[0]):
        k = pose_of_point[m]
        x, y, z = points[m, 0], points[m, 1], points[m, 2]
        for i in range(3):
            rotated = (rotations[k, i, 0] * x + rotations[k, i, 2] * z) + rotations[k, i, 1] * y
            out[m, i] = rotated + translations[k, i]
    return out


def top_lidar_world_points(
    range_image: np.ndarray,
    pixel_pose: np.ndarray,
    calibration: LidarCalibration,
    what: str,
) -> TopSweep:
    """The world points of a TOP range image [H, W] with its pixel poses [H, W, 6].

    A pixel pose is (roll, pitch, yaw, x, y, z): the vehicle's pose in the world when that pixel
    was fired (the TOP lidar's rolling-shutter correction), rotation Rz(yaw) Ry(pitch) Rx(roll).
    """
    if not np.isfinite(range_image).all():
        raise InputError(f"{what}: range image contains NaN or infinity")
    if pixel_pose.shape[:2] != range_image.shape:
        raise InputError(
            f"{what}: lidar_pose shape {pixel_pose.shape[:2]} != range image {range_image.shape}"
        )
    extrinsic = calibration.lidar_to_vehicle
    inclinations = beam_inclinations(calibration, range_image.shape[0], what)
    kept = range_image > 0
    if not kept.any():
        raise InputError(f"{what}: no returns (every range <= 0)")
    grid = sensor_points(range_image, extrinsic, inclinations)
    points = grid[kept] @ extrinsic[:3, :3].T + extrinsic[:3, 3]
    rotations, translations, pose_of_point = kept_poses(pixel_pose, kept, what)
    world = posed_points(points, rotations, translations, pose_of_point)
    return TopSweep(
        world, kept, grid, range_image.astype(np.float64), rotations, pose_of_point, extrinsic[:3, :3]
    )
