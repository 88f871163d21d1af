"""What the TOP lidar says about a unit's clips, read in one pass over the frames they need:
per camera frame, the depth samples the occlusion test reads and each object's points.

A lidar point is attached to its object through the lidar box (same capture time as the
points); the clip later carries it to each frame with the camera-synced box.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from pipeline.core.geometry import invert_se3, project, transform_points
from pipeline.core.visibility import in_view
from pipeline.drivetrack.boxes import box_poses, inside_box
from pipeline.drivetrack.depth import camera_occluded_lidar
from pipeline.drivetrack.lidar import top_lidar_world_points
from pipeline.drivetrack.normals import surface_normals
from pipeline.drivetrack.objects import ObjectRun
from pipeline.drivetrack.reader import CameraCalibration
from pipeline.drivetrack.unit_input import UnitInput


@dataclasses.dataclass
class LidarEvidence:
    """Per camera frame: lidar depth samples in the image, and each object's body points.

    depth_uv[t]: [M, 2] pixels; depth_z[t]: [M] camera z; body_points[object][t]: [K, 3];
    body_normals[object][t]: [K, 3] unit normals facing the lidar (box frame).
    """

    depth_uv: dict[int, np.ndarray]
    depth_z: dict[int, np.ndarray]
    body_points: dict[str, dict[int, np.ndarray]]
    body_normals: dict[str, dict[int, np.ndarray]]


def depth_samples(
    points_cam: np.ndarray, calibration: CameraCalibration, occlusion_margin: float
) -> tuple[np.ndarray, np.ndarray]:
    """Pixels [M, 2] and depths [M] of the lidar points [P, 3] (camera frame) that the camera
    sees: in view, and not hidden from it by a nearer lidar point."""
    visible = in_view(points_cam, calibration.fx_fy_cx_cy, calibration.width, calibration.height)
    uv = project(points_cam[visible], calibration.fx_fy_cx_cy)
    z = points_cam[visible, 2]
    seen = ~camera_occluded_lidar(uv, z, occlusion_margin)
    return uv[seen], z[seen]


def box_points(
    points_vehicle: np.ndarray, box: np.ndarray, lidar_origin: np.ndarray, shrink: float
) -> tuple[np.ndarray, np.ndarray]:
    """The points [P, 3] (vehicle frame) inside a lidar box [7] shrunk by ``shrink`` metres, in
    the box frame [K, 3], with their normals [K, 3] facing the lidar at ``lidar_origin`` [3]."""
    box_from_vehicle = invert_se3(box_poses(box))
    local = transform_points(box_from_vehicle, points_vehicle)
    local = local[inside_box(local, box[3:6], shrink)]
    return local, surface_normals(local, transform_points(box_from_vehicle, lidar_origin))


def gather_lidar(
    unit: UnitInput,
    runs: list[ObjectRun],
    cam_from_world: np.ndarray,
    world_from_frame: np.ndarray,
    shrink: float,
    occlusion_margin: float,
) -> LidarEvidence:
    """One pass over the TOP lidar frames the clips need: depth samples and in-box points.

    cam_from_world, world_from_frame: [T, 4, 4] per camera frame (``poses.py``).
    """
    needed = sorted({t for run in runs for t in range(run.start, run.stop)})
    timestamps = unit.frames.timestamps
    evidence = LidarEvidence({}, {}, {run.object_id: {} for run in runs}, {run.object_id: {} for run in runs})
    lidar_origin = unit.lidar_calibration.lidar_to_vehicle[:3, 3]
    frames = unit.lidar_frames([int(timestamps[t]) for t in needed])
    for t, lidar in zip(needed, frames, strict=True):
        what = f"lidar/{unit.segment} TOP frame {lidar.timestamp}"
        world, kept = top_lidar_world_points(
            lidar.range_image, lidar.pixel_pose, unit.lidar_calibration, what
        )
        projection = lidar.camera_projection[kept]
        in_camera = (projection[:, 0] == unit.camera) | (projection[:, 3] == unit.camera)
        evidence.depth_uv[t], evidence.depth_z[t] = depth_samples(
            transform_points(cam_from_world[t], world[in_camera]), unit.calibration, occlusion_margin
        )
        vehicle = transform_points(invert_se3(world_from_frame[t]), world)
        for run in runs:
            if run.start <= t < run.stop:
                points, normals = box_points(vehicle, run.lidar_boxes[t - run.start], lidar_origin, shrink)
                evidence.body_points[run.object_id][t] = points
                evidence.body_normals[run.object_id][t] = normals
    return evidence
