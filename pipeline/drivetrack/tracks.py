"""One DriveTrack object's candidate clip: its lidar points chosen and queried (``queries.py``),
carried to every clip frame by the object's camera-synced box, their visibility (``visibility.py``,
or with ``drivetrack.refined_visibility`` ``refined_visibility.py``), mask agreement (``masks.py``
through ``filters.mask.agreement``), the ``ClipRecord``. Pure computation on one camera's evidence
(``lidar.LidarEvidence``); ``annotate.py`` runs it for every object of a camera."""

from __future__ import annotations

import logging

import numpy as np

from pipeline.core.clip import ClipRecord, SparseDepth, TrackStats
from pipeline.core.geometry import transform_directions_batch, transform_points_batch
from pipeline.core.outcomes import NotMade
from pipeline.drivetrack.camera_model import Projection, UnitCamera
from pipeline.drivetrack.lidar import LidarEvidence
from pipeline.drivetrack.masks import object_masks
from pipeline.drivetrack.object_surface import OwnSurface
from pipeline.drivetrack.objects import ObjectRun
from pipeline.drivetrack.queries import (
    PointPool,
    choose_points,
    clip_queries,
    point_keys,
    point_pool,
)
from pipeline.drivetrack.records import UnitInput
from pipeline.drivetrack.refined_visibility import refined_visibility
from pipeline.drivetrack.settings import DriveTrackConfig
from pipeline.drivetrack.surface_normals import fitted_normals
from pipeline.drivetrack.units import SegmentCamera, clip_name
from pipeline.drivetrack.visibility import track_visibility
from pipeline.export.depth_export import sparse_export
from pipeline.filters.mask import agreement, on_mask
from pipeline.sources import RunChoices

log = logging.getLogger(__name__)


def object_visibility(
    unit: UnitInput,
    run: ObjectRun,
    evidence: LidarEvidence,
    camera: UnitCamera,
    seen: list[Projection],
    pool: PointPool,
    chosen: np.ndarray,
    rules: DriveTrackConfig,
) -> np.ndarray:
    """Visibility [T, N] of the pool's points ``chosen`` [N] seen as ``seen`` (one Projection per clip
    frame): in view, facing the camera, not occluded in the lidar's depth; or with
    ``drivetrack.refined_visibility``, ``refined_visibility``'s decisions."""
    frames = range(run.start, run.stop)
    # Normals turn with the frame's pose (the camera turns by under a milliradian during a readout).
    cam_from_box = camera.cam_from_world[run.start : run.stop] @ run.world_from_box
    tracks, pixels = np.stack([s.points for s in seen]), np.stack([s.pixels for s in seen])
    in_view = np.stack([s.in_view for s in seen])
    if rules.refined_visibility:
        refined = evidence.refined
        assert refined is not None, "gather_lidar_cameras(refined=True) gathers the refined evidence"
        surface = refined.surfaces[run.object_id]
        return refined_visibility(
            tracks,
            pixels,
            in_view,
            pool.points[chosen],
            track_normals(pool, chosen),
            cam_from_box,
            OwnSurface([surface[t] for t in frames if t in surface]),
            [refined.frame_occluders(t) for t in frames],
            refined.labels[run.object_id],
            rules.occlusion_margin,
        )
    return track_visibility(
        tracks,
        pixels,
        in_view,
        transform_directions_batch(cam_from_box, pool.normals[chosen]) if rules.facing_test else None,
        [evidence.depth_uv[t] for t in frames],
        [evidence.depth_z[t] for t in frames],
        [evidence.depth_grid(t) for t in frames],
        (unit.calibration.width, unit.calibration.height),
        rules.occlusion_margin,
    )


def track_normals(pool: PointPool, chosen: np.ndarray) -> np.ndarray:
    """Unit normals [N, 3] (box frame) of the pool's points ``chosen`` [N], fitted on all the pool's
    points (``surface_normals``), each facing the lidar of its own sweep."""
    assert pool.views is not None, "the refined evidence holds each point's view"
    return fitted_normals(pool.points, chosen, pool.views[chosen])


def mask_agreement(
    unit: UnitInput,
    run: ObjectRun,
    name: str,
    evidence: LidarEvidence,
    camera: UnitCamera,
    uv: np.ndarray,
    visibility: np.ndarray,
    rules: DriveTrackConfig,
) -> np.ndarray:
    """Per track [N], the share of its visible frames [T, N] on the object's mask (NaN without a
    mask); uv [T, N, 2] the tracks' pixels in the stored frames."""
    masks, has_mask = object_masks(unit, run, name, evidence, camera, rules)
    on_object = np.stack(
        [
            on_mask(mask, uv[i]) if mask is not None else np.zeros(uv.shape[1], bool)
            for i, mask in enumerate(masks)
        ]
    )
    return agreement(on_object, visibility, has_mask)


def candidate_clip(
    unit: UnitInput,
    run: ObjectRun,
    evidence: LidarEvidence,
    camera: UnitCamera,
    stored_jpegs: dict[int, bytes],
    rules: DriveTrackConfig,
    choices: RunChoices,
) -> ClipRecord | NotMade:
    """One vehicle's candidate clip: its candidate tracks with visibility, queries (those of
    ``--queries-from``'s clip of its name, when it holds one) and filter statistics; or why there is
    none: its box holds no lidar point.

    stored_jpegs: the stored frame per unit frame index, for the run's frames.
    """
    name = clip_name(unit.segment, unit.camera, run.object_id)
    unit_name = SegmentCamera(unit.segment, unit.camera).name
    pool = point_pool(evidence, run, unit.frames.timestamps)
    if pool is None:
        log.info("%s: object %s has no lidar points in its box; no clip", unit_name, run.object_id)
        return NotMade(f"object {run.object_id}'s box holds no lidar point on its frames")
    keys = point_keys(choices.seed, name, pool.timestamps, pool.pixels)
    frames = range(run.start, run.stop)
    given = choices.given.of(name)
    count = rules.oversample * rules.tracks_per_clip
    chosen = choose_points(pool.points, keys, given, run, camera, name, count)
    seen = camera.project_frames(frames, transform_points_batch(run.world_from_box, pool.points[chosen]))
    uv = np.stack([s.pixels for s in seen])
    visibility = object_visibility(unit, run, evidence, camera, seen, pool, chosen, rules)
    frame_ids = unit.frames.timestamps[run.start : run.stop]
    return ClipRecord(
        source="drivetrack",
        name=name,
        unit=unit_name,
        images_jpeg=[stored_jpegs[t] for t in frames],
        fx_fy_cx_cy=unit.calibration.fx_fy_cx_cy.copy(),
        image_size=(unit.calibration.width, unit.calibration.height),
        extrinsics_w2c=camera.cam_from_world[run.start : run.stop].copy(),
        tracks_xyz=np.stack([s.points for s in seen]),
        visibility=visibility,
        queries_xyt=clip_queries(uv, visibility, given, keys[chosen], rules.stable_query_frames),
        frame_ids=frame_ids.copy(),
        track_stats=TrackStats(mask_agreement(unit, run, name, evidence, camera, uv, visibility, rules)),
        target_tracks=rules.tracks_per_clip,
        given_queries=given is not None,
        depth_export=depth_export(evidence, frames, frame_ids) if choices.export_depth else None,
        track_keys=keys[chosen],
    )


def depth_export(evidence: LidarEvidence, frames: range, frame_ids: np.ndarray) -> SparseDepth:
    """The clip's depth samples per frame (``export.depth_export.sparse_export``)."""
    uv, z = [evidence.depth_uv[t] for t in frames], [evidence.depth_z[t] for t in frames]
    return sparse_export(uv, z, frame_ids)
