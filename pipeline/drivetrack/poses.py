"""A unit's poses per camera frame, checked: the vehicle in the world, the camera from the world.

Frames of the world: the vehicle frame at frame time (boxes and lidar points live there), and
the camera frame at exposure (OpenCV axes, via the camera image's own vehicle pose).
"""

from __future__ import annotations

import numpy as np

from pipeline.core.errors import InputError
from pipeline.core.geometry import CV_FROM_FLU, invert_se3, rigid_transform_problem
from pipeline.drivetrack.reader import CameraCalibration, CameraFrames
from pipeline.drivetrack.unit_input import UnitInput


def require_rigid(what: str, matrix: np.ndarray) -> None:
    """InputError naming ``what`` unless ``matrix`` [4, 4] is a rigid transform."""
    problem = rigid_transform_problem(matrix)
    if problem:
        raise InputError(f"{what} {problem}")


def frame_poses(unit: UnitInput) -> np.ndarray:
    """world_from_vehicle at each camera frame's frame time [T, 4, 4], checked; the camera must
    have an image at every frame of the segment (every vehicle_pose timestamp)."""
    segment, camera = unit.segment, unit.camera
    poses = []
    for index, timestamp in enumerate(unit.frames.timestamps.tolist()):
        pose = unit.world_from_vehicle.get(timestamp)
        if pose is None:
            raise InputError(
                f"camera_image/{segment} camera {camera} frame {timestamp}: "
                "no vehicle_pose row at this timestamp"
            )
        require_rigid(f"vehicle_pose/{segment} frame {timestamp}: world_from_vehicle", pose)
        require_rigid(
            f"camera_image/{segment} camera {camera} frame {timestamp}: pose.transform",
            unit.frames.world_from_vehicle_at_exposure[index],
        )
        poses.append(pose)
    missing = sorted(set(unit.world_from_vehicle) - set(unit.frames.timestamps.tolist()))
    if missing:
        raise InputError(
            f"camera_image/{segment} camera {camera}: no image for frame {missing[0]} "
            f"({len(missing)} of {len(unit.world_from_vehicle)} frames)"
        )
    require_rigid(
        f"camera_calibration/{segment} camera {camera}: extrinsic", unit.calibration.camera_to_vehicle
    )
    require_rigid(f"lidar_calibration/{segment} TOP: extrinsic", unit.lidar_calibration.lidar_to_vehicle)
    return np.stack(poses)


def camera_from_world(frames: CameraFrames, calibration: CameraCalibration) -> np.ndarray:
    """OpenCV camera-from-world per frame [T, 4, 4] from the exposure-time vehicle poses."""
    world_from_camera = frames.world_from_vehicle_at_exposure @ calibration.camera_to_vehicle
    return CV_FROM_FLU @ invert_se3(world_from_camera)
