"""What the TOP lidar says about a unit's clips, read in one pass over the frames they need
(shared by the cameras of a segment annotated together): per camera frame, the depth samples the
occlusion test reads and each object's points.

A lidar point is attached to its object through the lidar box (same capture time as the
points); the clip later carries it to each frame with the camera-synced box.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from pipeline.core.geometry import invert_se3, transform_points
from pipeline.drivetrack.boxes import box_poses, inside_box
from pipeline.drivetrack.camera_model import UnitCamera
from pipeline.drivetrack.depth import CellGrid, camera_occluded_lidar, depth_tree
from pipeline.drivetrack.lidar import TopSweep, top_lidar_world_points
from pipeline.drivetrack.objects import ObjectRun
from pipeline.drivetrack.unit_input import UnitInput


@dataclasses.dataclass
class LidarEvidence:
    """Per camera frame: lidar depth samples in the image, and each object's body points.

    depth_uv[t]: [M, 2] pixels; depth_z[t]: [M] camera z; body_points[object][t]: [K, 3];
    body_normals[object][t]: [K, 3] unit normals facing the lidar (box frame);
    body_pixels[object][t]: [K] int64 range-image pixel (row * W + column) of each body point,
    which with the frame's timestamp names the point.
    """

    depth_uv: dict[int, np.ndarray]
    depth_z: dict[int, np.ndarray]
    body_points: dict[str, dict[int, np.ndarray]]
    body_normals: dict[str, dict[int, np.ndarray]]
    body_pixels: dict[str, dict[int, np.ndarray]]
    depth_trees: dict[int, CellGrid | None] = dataclasses.field(default_factory=dict)

    def depth_tree(self, t: int) -> CellGrid | None:
        """The lookup of frame t's depth pixels (``depth.depth_tree``), built at the first clip that
        reads it."""
        if t not in self.depth_trees:
            self.depth_trees[t] = depth_tree(self.depth_uv[t])
        return self.depth_trees[t]


def depth_samples(
    world: np.ndarray, camera: UnitCamera, t: int, occlusion_margin: float
) -> tuple[np.ndarray, np.ndarray]:
    """Pixels [M, 2] in the stored frame t and camera depths [M] of the lidar points [P, 3]
    (world) that the camera sees: in view, and not hidden from it by a nearer lidar point."""
    seen = camera.project(t, world)
    uv, z = seen.pixels[seen.in_view], seen.points[seen.in_view, 2]
    kept = ~camera_occluded_lidar(uv, z, occlusion_margin)
    return uv[kept], z[kept]


def box_points(
    points_vehicle: np.ndarray, box: np.ndarray, shrink: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Which points [P, 3] (vehicle frame) lie inside a lidar box [7] shrunk by ``shrink`` metres:
    their index [K], those points in the box frame [K, 3], and box_from_vehicle [4, 4]."""
    box_from_vehicle = invert_se3(box_poses(box))
    # Only points within ``reach`` (the circumscribed sphere's radius and a metre) of the centre in
    # x and y can be inside: the others are never carried into the box frame (same numbers).
    reach = np.linalg.norm(np.abs(box[3:6] - shrink)) / 2.0 + 1.0
    near = np.flatnonzero(np.abs(points_vehicle[:, 0] - box[0]) <= reach)
    near = near[np.abs(points_vehicle[near, 1] - box[1]) <= reach]
    local = transform_points(box_from_vehicle, points_vehicle[near])
    inside = inside_box(local, box[3:6], shrink)
    return near[inside], local[inside], box_from_vehicle


@dataclasses.dataclass(frozen=True)
class CameraPass:
    """One camera's share of a pass over the lidar: its unit, the object runs it tracks, its
    camera model and the vehicle pose per camera frame [T, 4, 4] (``poses.py``)."""

    unit: UnitInput
    runs: list[ObjectRun]
    camera: UnitCamera
    world_from_frame: np.ndarray

    @property
    def needed(self) -> list[int]:
        """The camera frames its clips span, sorted."""
        return sorted({t for run in self.runs for t in range(run.start, run.stop)})


def gather_lidar_cameras(
    passes: list[CameraPass], shrink: float, occlusion_margin: float
) -> list[LidarEvidence]:
    """One pass over the TOP lidar frames any of one segment's cameras needs, each frame decoded and
    placed in the world once for all of them: each camera's depth samples and in-box points."""
    users: dict[int, list[tuple[int, int]]] = {}  # lidar timestamp -> [(pass index, camera frame)]
    for i, item in enumerate(passes):
        for t in item.needed:
            users.setdefault(int(item.unit.frames.timestamps[t]), []).append((i, t))
    evidence = [
        LidarEvidence({}, {}, *({run.object_id: {} for run in item.runs} for _ in range(3)))
        for item in passes
    ]
    if not passes:
        return evidence
    first = passes[0].unit
    stamps = sorted(users)
    for stamp, lidar in zip(stamps, first.lidar_frames(stamps), strict=True):
        what = f"lidar/{first.segment} TOP frame {lidar.timestamp}"
        sweep = top_lidar_world_points(lidar.range_image, lidar.pixel_pose, first.lidar_calibration, what)
        in_vehicle: dict[bytes, tuple[np.ndarray, np.ndarray]] = {}  # the cameras' poses agree
        for i, t in users[stamp]:
            pose = passes[i].world_from_frame[t]
            key = pose.tobytes()
            if key not in in_vehicle:
                vehicle_from_world = invert_se3(pose)
                in_vehicle[key] = vehicle_from_world, transform_points(vehicle_from_world, sweep.points)
            frame = (t, lidar.camera_projection, sweep, in_vehicle[key])
            _camera_frame(passes[i], evidence[i], *frame, shrink, occlusion_margin)
    return evidence


def _camera_frame(
    item: CameraPass,
    evidence: LidarEvidence,
    t: int,
    projection: np.ndarray,
    sweep: TopSweep,
    in_vehicle: tuple[np.ndarray, np.ndarray],
    shrink: float,
    occlusion_margin: float,
) -> None:
    """Camera frame t's share of a sweep: its depth samples and its objects' points, into ``evidence``.

    projection: [H, W, 6] the sweep's lidar_camera_projection (camera name, u, v, twice);
    in_vehicle: vehicle_from_world [4, 4] at the frame and the sweep's points [M, 3] in that frame."""
    world, camera = sweep.points, item.unit.camera
    in_camera = ((projection[..., 0] == camera) | (projection[..., 3] == camera))[sweep.kept]
    evidence.depth_uv[t], evidence.depth_z[t] = depth_samples(
        world[in_camera], item.camera, t, occlusion_margin
    )
    vehicle_from_world, vehicle = in_vehicle
    pixels = np.flatnonzero(sweep.kept)
    for run in item.runs:
        if run.start <= t < run.stop:
            inside, points, box_from_vehicle = box_points(vehicle, run.lidar_boxes[t - run.start], shrink)
            box_from_world = box_from_vehicle[:3, :3] @ vehicle_from_world[:3, :3]
            evidence.body_points[run.object_id][t] = points
            evidence.body_normals[run.object_id][t] = sweep.normals(inside) @ box_from_world.T
            evidence.body_pixels[run.object_id][t] = pixels[inside]


def gather_lidar(
    unit: UnitInput,
    runs: list[ObjectRun],
    camera: UnitCamera,
    world_from_frame: np.ndarray,
    shrink: float,
    occlusion_margin: float,
) -> LidarEvidence:
    """``gather_lidar_cameras`` for one camera. world_from_frame: [T, 4, 4] (``poses.py``)."""
    (evidence,) = gather_lidar_cameras(
        [CameraPass(unit, runs, camera, world_from_frame)], shrink, occlusion_margin
    )
    return evidence
