"""One DriveTrack object's candidate clip: its lidar points chosen and queried (``queries.py``),
carried to every clip frame by the object's camera-synced box, their visibility (``visibility.py``,
or with ``drivetrack.refined_visibility`` ``refined_visibility.py``), mask agreement (``masks.py``
through ``filters.mask.agreement``), the ``ClipRecord``. Pure computation on one camera's evidence
(``lidar.LidarEvidence``); ``annotate.py`` runs it for every object of a camera."""

from __future__ import annotations

import dataclasses
import logging

import numpy as np

from pipeline.core.clip import ClipRecord, SparseDepth, TrackStats
from pipeline.core.geometry import transform_directions_batch, transform_points_batch
from pipeline.core.outcomes import NotMade
from pipeline.drivetrack.camera_model import Projection, UnitCamera
from pipeline.drivetrack.footprints import FrameOccluders
from pipeline.drivetrack.lidar import LidarEvidence, stream_occluders
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
from pipeline.drivetrack.refined_visibility import RefinedTracks
from pipeline.drivetrack.settings import DriveTrackConfig
from pipeline.drivetrack.surface_normals import fitted_normals
from pipeline.drivetrack.units import SegmentCamera
from pipeline.drivetrack.visibility import track_visibility
from pipeline.export.depth_export import sparse_export
from pipeline.filters.mask import agreement, on_mask
from pipeline.sources import RunChoices

log = logging.getLogger(__name__)


@dataclasses.dataclass
class PreparedClip:
    """One vehicle's candidate clip before its visibility: its name, the object run, the point pool
    and the points chosen [N] with their keys [N], their queries given (or None), how the camera
    sees them per clip frame (one Projection each) and, with ``drivetrack.refined_visibility``, their
    refined visibility, filled frame by frame as the frames' occluders come
    (``lidar.stream_occluders``)."""

    name: str
    run: ObjectRun
    pool: PointPool
    chosen: np.ndarray
    keys: np.ndarray
    given: np.ndarray | None
    seen: list[Projection]
    refined: RefinedTracks | None

    def see(self, t: int, occluders: FrameOccluders) -> None:
        """Camera frame t's occluders, when the clip spans it."""
        if self.refined is not None and self.run.start <= t < self.run.stop:
            self.refined.see(t - self.run.start, occluders)


def prepare_clip(
    unit: UnitInput,
    run: ObjectRun,
    evidence: LidarEvidence,
    camera: UnitCamera,
    rules: DriveTrackConfig,
    choices: RunChoices,
) -> PreparedClip | NotMade:
    """One vehicle's clip up to its visibility: its points chosen and queried (those of
    ``--queries-from``'s clip of its name, when it holds one) and seen in every clip frame; or why
    there is none: its box holds no lidar point."""
    name = run.name
    pool = point_pool(evidence, run, unit.frames.timestamps)
    if pool is None:
        log.info("%s: object %s has no lidar points in its box; no clip", unit_name(unit), run.object_id)
        return NotMade(f"object {run.object_id}'s box holds no lidar point on its frames")
    keys = point_keys(choices.seed, name, pool.timestamps, pool.pixels)
    frames = range(run.start, run.stop)
    given = choices.given.of(name)
    count = rules.oversample * rules.tracks_per_clip
    chosen = choose_points(pool.points, keys, given, run, camera, name, count)
    seen = camera.project_frames(frames, transform_points_batch(run.world_from_box, pool.points[chosen]))
    refined = None
    if rules.refined_visibility:
        found = evidence.refined
        assert found is not None, "gather_lidar_cameras(refined=True) gathers the refined evidence"
        surface = found.surfaces[run.object_id]
        refined = RefinedTracks(
            np.stack([s.points for s in seen]),
            np.stack([s.pixels for s in seen]),
            np.stack([s.in_view for s in seen]),
            pool.points[chosen],
            track_normals(pool, chosen),
            camera.cam_from_world[run.start : run.stop] @ run.world_from_box,
            OwnSurface([surface[t] for t in frames if t in surface]),
            found.labels[run.object_id],
            rules.occlusion_margin,
        )
    return PreparedClip(name, run, pool, chosen, keys[chosen], given, seen, refined)


def object_visibility(
    unit: UnitInput,
    prepared: PreparedClip,
    evidence: LidarEvidence,
    camera: UnitCamera,
    rules: DriveTrackConfig,
) -> np.ndarray:
    """Visibility [T, N] of the prepared clip's points: in view, facing the camera, not occluded in
    the lidar's depth; or with ``drivetrack.refined_visibility``, ``refined_visibility``'s
    decisions, every frame's occluders seen."""
    if prepared.refined is not None:
        return prepared.refined.visibility()
    run, seen = prepared.run, prepared.seen
    frames = range(run.start, run.stop)
    # Normals turn with the frame's pose (the camera turns by under a milliradian during a readout).
    cam_from_box = camera.cam_from_world[run.start : run.stop] @ run.world_from_box
    return track_visibility(
        np.stack([s.points for s in seen]),
        np.stack([s.pixels for s in seen]),
        np.stack([s.in_view for s in seen]),
        transform_directions_batch(cam_from_box, prepared.pool.normals[prepared.chosen])
        if rules.facing_test
        else None,
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
    evidence: LidarEvidence,
    camera: UnitCamera,
    uv: np.ndarray,
    visibility: np.ndarray,
    rules: DriveTrackConfig,
) -> np.ndarray:
    """Per track [N], the share of its visible frames [T, N] on the object's mask (NaN without a
    mask); uv [T, N, 2] the tracks' pixels in the stored frames."""
    masks, has_mask = object_masks(unit, run, evidence, camera, rules)
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
    """One vehicle's candidate clip (``prepare_clip``, its occluders streamed with the refined
    visibility, ``finish_clip``): the camera's only clip, as a test makes it."""
    prepared = prepare_clip(unit, run, evidence, camera, rules, choices)
    if isinstance(prepared, NotMade):
        return prepared
    if prepared.refined is not None:
        stream_occluders([evidence], [prepared.see])
    return finish_clip(unit, prepared, evidence, camera, stored_jpegs, rules, choices)


def finish_clip(
    unit: UnitInput,
    prepared: PreparedClip,
    evidence: LidarEvidence,
    camera: UnitCamera,
    stored_jpegs: dict[int, bytes],
    rules: DriveTrackConfig,
    choices: RunChoices,
) -> ClipRecord:
    """The prepared clip's candidate tracks with visibility, queries and filter statistics.

    stored_jpegs: the stored frame per unit frame index, for the run's frames.
    """
    run, seen, name = prepared.run, prepared.seen, prepared.name
    frames = range(run.start, run.stop)
    uv = np.stack([s.pixels for s in seen])
    visibility = object_visibility(unit, prepared, evidence, camera, rules)
    frame_ids = unit.frames.timestamps[run.start : run.stop]
    return ClipRecord(
        source="drivetrack",
        name=name,
        unit=unit_name(unit),
        images_jpeg=[stored_jpegs[t] for t in frames],
        fx_fy_cx_cy=unit.calibration.fx_fy_cx_cy.copy(),
        image_size=(unit.calibration.width, unit.calibration.height),
        extrinsics_w2c=camera.cam_from_world[run.start : run.stop].copy(),
        tracks_xyz=np.stack([s.points for s in seen]),
        visibility=visibility,
        queries_xyt=clip_queries(uv, visibility, prepared.given, prepared.keys, rules.stable_query_frames),
        frame_ids=frame_ids.copy(),
        track_stats=TrackStats(mask_agreement(unit, run, evidence, camera, uv, visibility, rules)),
        target_tracks=rules.tracks_per_clip,
        given_queries=prepared.given is not None,
        depth_export=depth_export(evidence, frames, frame_ids) if choices.export_depth else None,
        track_keys=prepared.keys,
    )


def unit_name(unit: UnitInput) -> str:
    """The name of the unit (segment, camera)."""
    return SegmentCamera(unit.segment, unit.camera).name


def depth_export(evidence: LidarEvidence, frames: range, frame_ids: np.ndarray) -> SparseDepth:
    """The clip's depth samples per frame (``export.depth_export.sparse_export``)."""
    uv, z = [evidence.depth_uv[t] for t in frames], [evidence.depth_z[t] for t in frames]
    return sparse_export(uv, z, frame_ids)
