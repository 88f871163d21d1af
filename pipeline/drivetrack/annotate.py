"""Annotate one DriveTrack unit (segment, camera): one clip per vehicle assigned to the camera.

Pure computation on the reader's records; no Beam. The steps, a module each: ``poses.py``
(vehicle and camera per frame), ``objects.py`` (which vehicles, on which frames), ``evidence.py``
(the TOP lidar: depth samples, each object's points), ``tracks.py`` (which points),
``visibility.py`` (in view, facing, not occluded), ``silhouette.py`` (object masks) and
``queries.py``; this module runs them and assembles each clip.
"""

from __future__ import annotations

import logging

import numpy as np

from pipeline.core.clip import ClipRecord
from pipeline.core.config import RunConfig
from pipeline.core.geometry import project, transform_directions_batch, transform_points_batch
from pipeline.core.images import check_jpeg
from pipeline.core.sampling import rng_for
from pipeline.drivetrack.evidence import LidarEvidence, gather_lidar
from pipeline.drivetrack.objects import ObjectRun, select_objects
from pipeline.drivetrack.poses import camera_from_world, frame_poses
from pipeline.drivetrack.queries import clip_queries
from pipeline.drivetrack.silhouette import object_masks
from pipeline.drivetrack.tracks import choose_points, point_pool
from pipeline.drivetrack.unit_input import UnitInput
from pipeline.drivetrack.visibility import track_visibility
from pipeline.export.depth_export import sparse_record
from pipeline.export.given_queries import given_queries
from pipeline.filters.mask import agreement, on_mask

log = logging.getLogger(__name__)


def clip_name(segment: str, camera: int, object_id: str) -> str:
    """The release's DriveTrack clip name."""
    return f"tapvid3d_{segment}_{camera}_{object_id}"


def track_object(
    unit: UnitInput,
    run: ObjectRun,
    evidence: LidarEvidence,
    cam_from_world: np.ndarray,
    config: RunConfig,
) -> ClipRecord | None:
    """Candidate tracks on one vehicle, with visibility, queries and filter statistics; None when
    its box holds no lidar point, or when ``--queries-from`` holds no clip of its name.

    cam_from_world: [T, 4, 4] per camera frame of the unit.
    """
    name = clip_name(unit.segment, unit.camera, run.object_id)
    calibration = unit.calibration
    rules = config.drivetrack
    pool = point_pool(evidence, run)
    if pool is None:
        log.info("%s: object %s has no lidar points in its box; no clip", unit.name, run.object_id)
        return None
    points, normals = pool
    rng = rng_for(config.seed, name)
    frames = range(run.start, run.stop)
    cam_from_box = cam_from_world[run.start : run.stop] @ run.world_from_box
    given = given_queries(config.queries_from, "drivetrack", name) if config.queries_from else None
    if config.queries_from and given is None:
        return None  # --queries-from re-annotates only the clips it holds
    chosen = choose_points(
        points,
        given,
        cam_from_box,
        calibration.fx_fy_cx_cy,
        name,
        rules.oversample * rules.tracks_per_clip,
        rng,
    )
    tracks = transform_points_batch(cam_from_box, points[chosen])
    uv = project(tracks, calibration.fx_fy_cx_cy)
    depth_uv, depth_z = [evidence.depth_uv[t] for t in frames], [evidence.depth_z[t] for t in frames]
    visibility = track_visibility(
        tracks,
        uv,
        transform_directions_batch(cam_from_box, normals[chosen]) if rules.facing_test else None,
        depth_uv,
        depth_z,
        calibration,
        rules.occlusion_margin,
    )
    masks, has_mask = object_masks(unit, run, name, evidence, cam_from_box, config)
    on_object = np.stack(
        [
            on_mask(mask, uv[i]) if mask is not None else np.zeros(len(chosen), bool)
            for i, mask in enumerate(masks)
        ]
    )
    frame_ids = unit.frames.timestamps[run.start : run.stop]
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
        queries_xyt=clip_queries(tracks, visibility, given, rng, calibration.fx_fy_cx_cy),
        frame_ids=frame_ids.copy(),
        track_stats={
            "visible_frames": visibility.sum(axis=0).astype(np.int64),
            "mask_agreement": agreement(on_object, visibility, has_mask),
        },
        target_tracks=rules.tracks_per_clip,
        given_queries=given is not None,
        depth_export=sparse_record(depth_uv, depth_z, frame_ids) if config.export_depth else None,
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
