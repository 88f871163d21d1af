"""What one DriveTrack unit (segment, camera) reads, as the reader's records."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable

import numpy as np

from pipeline.drivetrack.reader import (
    BoxLabels,
    CameraCalibration,
    CameraFrames,
    LidarCalibration,
    LidarFrame,
)


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

    @property
    def name(self) -> str:
        return f"{self.segment}/camera_{self.camera}"


def clip_name(segment: str, camera: int, object_id: str) -> str:
    """The release's DriveTrack clip name."""
    return f"tapvid3d_{segment}_{camera}_{object_id}"
