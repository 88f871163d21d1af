"""Annotate one DriveTrack unit (segment, camera): one clip per vehicle assigned to the camera.

Pure computation on the reader's records; no Beam. Frames of the world:
- vehicle frame at frame time t_f: where lidar boxes, camera-synced boxes and lidar points live;
- camera frame at exposure: OpenCV axes, via the camera image's own vehicle pose.
A lidar point is attached to its object through the lidar box (same capture time), then
carried to each frame with the camera-synced box (the object at camera capture time).
"""

from __future__ import annotations

import dataclasses
import logging
from collections import Counter
from collections.abc import Callable, Iterable

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from pipeline.core.clip import ClipRecord
from pipeline.core.config import RunConfig
from pipeline.core.errors import InputError
from pipeline.core.geometry import (
    CV_FROM_FLU,
    invert_se3,
    project,
    rigid_transform_problem,
    transform_points,
)
from pipeline.core.given_queries import given_queries
from pipeline.core.images import check_jpeg
from pipeline.core.sampling import queries_from_tracks, rng_for, sample_query_frames
from pipeline.core.visibility import in_view, passes_relative_depth_test
from pipeline.drivetrack.boxes import box_corners_local, box_poses, inside_box, longest_run
from pipeline.drivetrack.depth import camera_occluded_lidar, nearest_depth_max4
from pipeline.drivetrack.lidar import top_lidar_world_points
from pipeline.drivetrack.reader import (
    BoxLabels,
    CameraCalibration,
    CameraFrames,
    LidarCalibration,
    LidarFrame,
)
from pipeline.export.depth_export import sparse_record
from pipeline.filters.mask import agreement, on_mask, read_mask_png, silhouette_mask

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class UnitInput:
    """Everything one (segment, camera) unit reads; lidar frames come lazily, in time order."""

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


@dataclasses.dataclass(frozen=True)
class ObjectRun:
    """A vehicle's clip: frames [start, stop) of the camera, its boxes on those frames.

    world_from_box: [T, 4, 4] camera-synced box poses in the world.
    lidar_boxes: [T, 7] lidar boxes (vehicle frame at frame time).
    """

    object_id: str
    start: int
    stop: int
    world_from_box: np.ndarray
    lidar_boxes: np.ndarray


def camera_from_world(frames: CameraFrames, calibration: CameraCalibration) -> np.ndarray:
    """OpenCV camera-from-world per frame [T, 4, 4] from the exposure-time vehicle poses."""
    vehicle_from_camera = calibration.camera_to_vehicle
    world_from_camera = frames.world_from_vehicle_at_exposure @ vehicle_from_camera
    return CV_FROM_FLU @ invert_se3(world_from_camera)


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
        for what, matrix in (
            (f"vehicle_pose/{segment} frame {timestamp}: world_from_vehicle", pose),
            (
                f"camera_image/{segment} camera {camera} frame {timestamp}: pose.transform",
                unit.frames.world_from_vehicle_at_exposure[index],
            ),
        ):
            problem = rigid_transform_problem(matrix)
            if problem:
                raise InputError(f"{what} {problem}")
        poses.append(pose)
    missing = sorted(set(unit.world_from_vehicle) - set(unit.frames.timestamps.tolist()))
    if missing:
        raise InputError(
            f"camera_image/{segment} camera {camera}: no image for frame {missing[0]} "
            f"({len(missing)} of {len(unit.world_from_vehicle)} frames)"
        )
    for what, matrix in (
        (f"camera_calibration/{segment} camera {camera}: extrinsic", unit.calibration.camera_to_vehicle),
        (f"lidar_calibration/{segment} TOP: extrinsic", unit.lidar_calibration.lidar_to_vehicle),
    ):
        problem = rigid_transform_problem(matrix)
        if problem:
            raise InputError(f"{what} {problem}")
    return np.stack(poses)


def box_in_view(corners_cam: np.ndarray, calibration: CameraCalibration) -> bool:
    """True when a box's corners [8, 3] (camera frame) project onto the image."""
    front = corners_cam[:, 2] > 0
    if not front.any():
        return False
    uv = project(corners_cam[front], calibration.fx_fy_cx_cy)
    return bool(
        uv[:, 0].max() >= 0
        and uv[:, 0].min() < calibration.width
        and uv[:, 1].max() >= 0
        and uv[:, 1].min() < calibration.height
    )


def select_objects(
    unit: UnitInput, cam_from_world: np.ndarray, world_from_frame: np.ndarray, config: RunConfig
) -> list[ObjectRun]:
    """Vehicles assigned to this camera whose box projects on enough contiguous frames."""
    rules = config.drivetrack
    boxes = unit.boxes
    frame_index = {ts: i for i, ts in enumerate(unit.frames.timestamps.tolist())}
    runs = []
    for object_id in sorted(set(boxes.object_ids.tolist())):
        rows = np.nonzero(boxes.object_ids == object_id)[0]
        if boxes.types[rows[0]] not in rules.object_types:
            continue
        votes = Counter(boxes.most_visible_camera[rows].tolist())
        assigned = min(votes, key=lambda cam: (-votes[cam], cam))
        if assigned != unit.camera:
            continue
        for component, values in (
            ("lidar_box", boxes.lidar_boxes),
            ("lidar_camera_synced_box", boxes.synced_boxes),
        ):
            bad = ~np.isfinite(values[rows]).all(axis=1)
            if bad.any():
                raise InputError(
                    f"{component}/{unit.segment} object {object_id} frame {boxes.timestamps[rows][bad][0]}: "
                    "NaN or infinity in the box"
                )
        num_frames = len(unit.frames.timestamps)
        synced = np.full((num_frames, 7), np.nan)
        lidar = np.full((num_frames, 7), np.nan)
        for row in rows:
            index = frame_index.get(int(boxes.timestamps[row]))
            if index is not None:
                synced[index] = boxes.synced_boxes[row]
                lidar[index] = boxes.lidar_boxes[row]
        labelled = np.isfinite(synced[:, 0])
        world_from_box = np.full((num_frames, 4, 4), np.nan)
        world_from_box[labelled] = world_from_frame[labelled] @ box_poses(synced[labelled])
        in_view_flags = np.zeros(num_frames, bool)
        nearest = np.full(num_frames, np.inf)
        for t in np.nonzero(labelled)[0]:
            corners = transform_points(cam_from_world[t] @ world_from_box[t], box_corners_local(synced[t]))
            in_view_flags[t] = box_in_view(corners, unit.calibration)
            nearest[t] = np.linalg.norm(corners, axis=1).min()
        start, stop = longest_run(in_view_flags)
        if stop - start < rules.min_contiguous_frames:
            continue
        if nearest[start:stop].min() > rules.max_corner_distance_m:
            continue
        runs.append(ObjectRun(object_id, start, stop, world_from_box[start:stop], lidar[start:stop]))
    return runs


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


def gather_lidar(
    unit: UnitInput,
    runs: list[ObjectRun],
    cam_from_world: np.ndarray,
    world_from_frame: np.ndarray,
    shrink: float,
    occlusion_margin: float,
) -> LidarEvidence:
    """One pass over the TOP lidar frames the clips need: depth samples and in-box points."""
    needed = sorted({t for run in runs for t in range(run.start, run.stop)})
    timestamps = unit.frames.timestamps
    evidence = LidarEvidence({}, {}, {run.object_id: {} for run in runs}, {run.object_id: {} for run in runs})
    lidar_origin = unit.lidar_calibration.lidar_to_vehicle[:3, 3]
    frames = unit.lidar_frames([int(timestamps[t]) for t in needed])
    calibration = unit.calibration
    for t, lidar in zip(needed, frames, strict=True):
        what = f"lidar/{unit.segment} TOP frame {lidar.timestamp}"
        world, kept = top_lidar_world_points(
            lidar.range_image, lidar.pixel_pose, unit.lidar_calibration, what
        )
        projection = lidar.camera_projection[kept]
        in_camera = (projection[:, 0] == unit.camera) | (projection[:, 3] == unit.camera)
        points_cam = transform_points(cam_from_world[t], world[in_camera])
        visible = in_view(points_cam, calibration.fx_fy_cx_cy, calibration.width, calibration.height)
        uv = project(points_cam[visible], calibration.fx_fy_cx_cy)
        z = points_cam[visible, 2]
        seen = ~camera_occluded_lidar(uv, z, occlusion_margin)
        evidence.depth_uv[t], evidence.depth_z[t] = uv[seen], z[seen]
        vehicle = transform_points(invert_se3(world_from_frame[t]), world)
        for run in runs:
            if run.start <= t < run.stop:
                box = run.lidar_boxes[t - run.start]
                box_from_vehicle = invert_se3(box_poses(box))
                local = transform_points(box_from_vehicle, vehicle)
                local = local[inside_box(local, box[3:6], shrink)]
                evidence.body_points[run.object_id][t] = local
                evidence.body_normals[run.object_id][t] = surface_normals(
                    local, transform_points(box_from_vehicle, lidar_origin)
                )
    return evidence


def object_masks(
    unit: UnitInput,
    run: ObjectRun,
    clip_name: str,
    evidence: LidarEvidence,
    cam_from_world: np.ndarray,
    config: RunConfig,
) -> tuple[list[np.ndarray | None], np.ndarray]:
    """Object mask per clip frame ([H, W] bool or None) and [T] has-mask flags."""
    calibration = unit.calibration
    masks = []
    for t in range(run.start, run.stop):
        if config.drivetrack.masks_dir:
            path = f"{config.drivetrack.masks_dir.rstrip('/')}/{clip_name}/{unit.frames.timestamps[t]}.png"
            masks.append(read_mask_png(path, calibration.width, calibration.height))
            continue
        body = evidence.body_points[run.object_id].get(t, np.zeros((0, 3)))
        points_cam = transform_points(cam_from_world[t] @ run.world_from_box[t - run.start], body)
        points_cam = points_cam[points_cam[:, 2] > 0]
        uv = project(points_cam, calibration.fx_fy_cx_cy)
        masks.append(
            silhouette_mask(uv, calibration.width, calibration.height, config.drivetrack.mask_closing_px)
            if len(uv)
            else None
        )
    return masks, np.array([mask is not None for mask in masks])


def surface_normals(points: np.ndarray, sensor: np.ndarray, radius: float = 0.3) -> np.ndarray:
    """Unit normals [K, 3] of one sweep's points [K, 3] on an object (open3d's local PCA over
    neighbours within ``radius`` metres), turned to face the lidar at ``sensor`` [3], which
    saw those surfaces from its side."""
    if len(points) < 3:
        normals = sensor - points
        return normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=radius, max_nn=16))
    normals = np.asarray(cloud.normals)
    flip = np.einsum("ki,ki->k", normals, sensor - points) < 0
    normals[flip] *= -1.0
    return normals


def clip_name(segment: str, camera: int, object_id: str) -> str:
    """The release's DriveTrack clip name."""
    return f"tapvid3d_{segment}_{camera}_{object_id}"


def match_given_queries(
    pool: np.ndarray, queries: np.ndarray, cam_from_box: np.ndarray, fx_fy_cx_cy: np.ndarray, clip: str
) -> np.ndarray:
    """Index into the object's lidar points [P, 3] (box frame) of each given query [N, 3]: the
    point whose projection at the query's frame (camera poses [T, 4, 4]) is nearest (x, y);
    it must lie within half a pixel, as the release's queries are such projections."""
    frames = queries[:, 2].astype(np.int64)
    if (frames < 0).any() or (frames >= len(cam_from_box)).any():
        raise InputError(f"{clip}: a given query frame lies outside 0..{len(cam_from_box) - 1}")
    chosen = np.empty(len(queries), np.int64)
    for t in np.unique(frames):
        rows = np.nonzero(frames == t)[0]
        points = transform_points(cam_from_box[t], pool)
        front = np.nonzero(points[:, 2] > 0)[0]
        if not len(front):
            raise InputError(f"{clip}: no lidar point of the object is in front of the camera at frame {t}")
        distance, nearest = cKDTree(project(points[front], fx_fy_cx_cy)).query(queries[rows, :2])
        if distance.max() > 0.5:
            k = int(np.argmax(distance))
            x, y = queries[rows[k], :2]
            raise InputError(
                f"{clip}: given query {int(rows[k])} at ({x:.1f}, {y:.1f}, t={t}) is {distance[k]:.2f} px "
                "from the nearest lidar point of the object"
            )
        chosen[rows] = front[nearest]
    return chosen


def track_object(
    unit: UnitInput,
    run: ObjectRun,
    evidence: LidarEvidence,
    cam_from_world: np.ndarray,
    config: RunConfig,
) -> ClipRecord | None:
    """Candidate tracks on one vehicle, with visibility, queries and filter statistics."""
    name = clip_name(unit.segment, unit.camera, run.object_id)
    calibration = unit.calibration
    rules = config.drivetrack
    frames_with_points = [
        t for t in range(run.start, run.stop) if len(evidence.body_points[run.object_id].get(t, ()))
    ]
    if not frames_with_points:
        log.info("%s: object %s has no lidar points in its box; no clip", unit.name, run.object_id)
        return None
    pool = np.concatenate([evidence.body_points[run.object_id][t] for t in frames_with_points])
    normals = np.concatenate([evidence.body_normals[run.object_id][t] for t in frames_with_points])
    rng = rng_for(config.seed, name)
    frames = range(run.start, run.stop)
    cam_from_box = cam_from_world[run.start : run.stop] @ run.world_from_box
    given = given_queries(config.queries_from, "drivetrack", name) if config.queries_from else None
    if config.queries_from and given is None:
        return None  # --queries-from re-annotates only the clips it holds
    if given is not None:
        chosen = match_given_queries(pool, given, cam_from_box, calibration.fx_fy_cx_cy, name)
    else:
        count = min(len(pool), rules.oversample * rules.tracks_per_clip)
        chosen = np.sort(rng.choice(len(pool), size=count, replace=False))
    body, body_normals = pool[chosen], normals[chosen]
    count = len(chosen)
    tracks = np.einsum("tij,nj->tni", cam_from_box[:, :3, :3], body) + cam_from_box[:, None, :3, 3]
    visibility = in_view(tracks, calibration.fx_fy_cx_cy, calibration.width, calibration.height)
    if rules.facing_test:
        normals_cam = np.einsum("tij,nj->tni", cam_from_box[:, :3, :3], body_normals)
        cosine = np.einsum("tni,tni->tn", normals_cam, -tracks) / np.linalg.norm(tracks, axis=2)
        visibility &= cosine > 0
    uv = project(tracks, calibration.fx_fy_cx_cy)
    for i, t in enumerate(frames):
        candidates = np.nonzero(visibility[i])[0]
        depth = nearest_depth_max4(
            evidence.depth_uv[t],
            evidence.depth_z[t],
            uv[i, candidates],
            calibration.width,
            calibration.height,
        )
        visibility[i, candidates] = passes_relative_depth_test(
            tracks[i, candidates, 2], depth, rules.occlusion_margin
        )

    masks, has_mask = object_masks(unit, run, name, evidence, cam_from_world, config)
    on_object = np.stack(
        [on_mask(mask, uv[i]) if mask is not None else np.zeros(count, bool) for i, mask in enumerate(masks)]
    )
    query_frames = sample_query_frames(visibility, rng) if given is None else given[:, 2].astype(np.int64)
    queries = queries_from_tracks(tracks, np.maximum(query_frames, 0), calibration.fx_fy_cx_cy)
    queries[query_frames < 0] = np.nan
    return ClipRecord(
        source="drivetrack",
        name=name,
        unit=unit.name,
        images_jpeg=[unit.frames.jpegs[t] for t in frames],
        fx_fy_cx_cy=calibration.fx_fy_cx_cy.copy(),
        image_size=(calibration.width, calibration.height),
        extrinsics_w2c=cam_from_world[run.start : run.stop].copy(),
        tracks_xyz=tracks,
        visibility=visibility,
        queries_xyt=queries,
        frame_ids=unit.frames.timestamps[run.start : run.stop].copy(),
        track_stats={
            "visible_frames": visibility.sum(axis=0).astype(np.int64),
            "mask_agreement": agreement(on_object, visibility, has_mask),
        },
        target_tracks=rules.tracks_per_clip,
        given_queries=given is not None,
        depth_export=(
            sparse_record(
                [evidence.depth_uv[t] for t in frames],
                [evidence.depth_z[t] for t in frames],
                unit.frames.timestamps[run.start : run.stop],
            )
            if config.export_depth
            else None
        ),
    )


def annotate_unit(unit: UnitInput, config: RunConfig) -> list[ClipRecord]:
    """All candidate clips of one (segment, camera) unit, in object-id order."""
    world_from_frame = frame_poses(unit)
    cam_from_world = camera_from_world(unit.frames, unit.calibration)
    runs = select_objects(unit, cam_from_world, world_from_frame, config)
    if not runs:
        return []
    calibration = unit.calibration
    for t in sorted({t for run in runs for t in range(run.start, run.stop)}):
        check_jpeg(
            unit.frames.jpegs[t],
            calibration.width,
            calibration.height,
            f"camera_image/{unit.segment} camera {unit.camera} frame {unit.frames.timestamps[t]}",
        )
    rules = config.drivetrack
    evidence = gather_lidar(
        unit, runs, cam_from_world, world_from_frame, rules.box_shrink_m, rules.occlusion_margin
    )
    clips = [track_object(unit, run, evidence, cam_from_world, config) for run in runs]
    return [clip for clip in clips if clip is not None]
