"""What one DriveTrack unit (segment, camera) reads, as plain typed records (``reader.py`` makes
them; nothing here reads or computes)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable

import numpy as np


@dataclasses.dataclass(frozen=True)
class CameraCalibration:
    """fx_fy_cx_cy [4], distortion [5] (k1, k2, p1, p2, k3), camera_to_vehicle [4, 4];
    rolling_shutter_direction: Waymo's enum (1 top to bottom, 2 left to right, 3 bottom to top,
    4 right to left, 5 global shutter; 0 unknown, also when the file has no such column)."""

    fx_fy_cx_cy: np.ndarray
    distortion: np.ndarray
    camera_to_vehicle: np.ndarray
    width: int
    height: int
    rolling_shutter_direction: int = 0


@dataclasses.dataclass(frozen=True)
class LidarCalibration:
    """lidar_to_vehicle [4, 4]; inclinations [H] in radians as stored (or None), min, max."""

    lidar_to_vehicle: np.ndarray
    inclinations: np.ndarray | None
    inclination_min: float
    inclination_max: float


@dataclasses.dataclass(frozen=True)
class CameraMotion:
    """A camera's rolling-shutter inputs per frame [T] (NaN where a cell is null): pose_timestamp
    (of the frame's vehicle pose), shutter, trigger, readout_done (seconds), and the vehicle's
    linear_velocity [T, 3] (world frame, m/s) and angular_velocity [T, 3] (rad/s) at that pose."""

    pose_timestamp: np.ndarray
    shutter: np.ndarray
    trigger: np.ndarray
    readout_done: np.ndarray
    linear_velocity: np.ndarray
    angular_velocity: np.ndarray


@dataclasses.dataclass(frozen=True)
class CameraFrames:
    """One camera's frames sorted by time: timestamps [T], JPEG bytes, vehicle poses [T, 4, 4], and
    the rolling shutter's inputs (None when the file has not all of their columns)."""

    timestamps: np.ndarray
    jpegs: list[bytes]
    world_from_vehicle_at_exposure: np.ndarray
    motion: CameraMotion | None = None

    def release_jpegs(self) -> None:
        """Let go of the JPEGs (the frames a unit stores are taken first: ``annotate.stored_frames``),
        so that the frames no clip stores, and the originals of undistorted ones, are freed."""
        self.jpegs.clear()


@dataclasses.dataclass(frozen=True)
class BoxLabels:
    """Box rows present in both lidar_box and lidar_camera_synced_box, sorted by (id, time).

    object_ids [R] str, timestamps [R] int64, types [R] int, lidar_boxes [R, 7] and
    synced_boxes [R, 7] as (cx, cy, cz, length, width, height, heading) in the vehicle
    frame of the frame pose, most_visible_camera [R] int.
    """

    object_ids: np.ndarray
    timestamps: np.ndarray
    types: np.ndarray
    lidar_boxes: np.ndarray
    synced_boxes: np.ndarray
    most_visible_camera: np.ndarray


@dataclasses.dataclass(frozen=True)
class LidarFrame:
    """TOP lidar first return: range [H, W], pixel_pose [H, W, 6], camera_projection [H, W, 6]."""

    timestamp: int
    range_image: np.ndarray
    pixel_pose: np.ndarray
    camera_projection: np.ndarray


@dataclasses.dataclass(frozen=True)
class UnitInput:
    """Everything one (segment, camera) unit reads; lidar frames come lazily, in time order.

    world_from_vehicle: frame timestamp -> [4, 4] vehicle pose at frame time (``vehicle_pose``).
    lidar_frames: TOP lidar frames at the given timestamps, read when iterated.
    """

    segment: str
    camera: int
    calibration: CameraCalibration
    lidar_calibration: LidarCalibration
    frames: CameraFrames
    world_from_vehicle: dict[int, np.ndarray]
    boxes: BoxLabels
    lidar_frames: Callable[[list[int]], Iterable[LidarFrame]]
