"""Annotate DriveTrack units: the cameras of one segment together (its lidar read once), one clip per
vehicle assigned to each camera; per unit its clips (``UnitClips``) or the exception that failed it.

Pure computation on the reader's records; no Beam. The steps, a module each: ``camera_model.py``
(vehicle and camera poses per frame, where a point appears in a frame, undistorted frames),
``objects.py`` (which vehicles, on which frames), ``lidar.py`` (the TOP lidar: depth samples, each
object's points and normals), ``tracks.py`` (which points, their queries), ``visibility.py`` (in
view, facing, not occluded), or with ``drivetrack.refined_visibility`` ``refined_visibility.py``
(with ``footprints.py``, ``object_surface.py`` and ``surface_normals.py``), ``masks.py`` (object
masks); this module runs them and assembles each clip.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

import cv2
import numpy as np

from pipeline.core.clip import ClipRecord
from pipeline.core.geometry import transform_directions_batch, transform_points_batch
from pipeline.core.images import check_jpeg
from pipeline.core.outcomes import UnitClips
from pipeline.drivetrack.camera_model import (
    UnitCamera,
    camera_from_world,
    frame_poses,
    undistort_image,
    undistortion_maps,
)
from pipeline.drivetrack.lidar import CameraPass, LidarEvidence, gather_lidar_cameras
from pipeline.drivetrack.masks import object_masks
from pipeline.drivetrack.object_surface import OwnSurface
from pipeline.drivetrack.objects import ObjectRun, select_objects
from pipeline.drivetrack.reader import SegmentReader
from pipeline.drivetrack.records import UnitInput, clip_name
from pipeline.drivetrack.refined_visibility import refined_visibility
from pipeline.drivetrack.surface_normals import fitted_normals
from pipeline.drivetrack.tracks import (
    PointPool,
    choose_points,
    clip_queries,
    point_keys,
    point_pool,
    query_draws,
)
from pipeline.drivetrack.visibility import track_visibility
from pipeline.export.depth_export import sparse_record
from pipeline.filters.mask import agreement, on_mask
from pipeline.io.given_queries import given_queries
from pipeline.sources import Wanted

if TYPE_CHECKING:
    from pipeline.settings import RunConfig

log = logging.getLogger(__name__)


def object_visibility(
    unit: UnitInput,
    run: ObjectRun,
    evidence: LidarEvidence,
    camera: UnitCamera,
    seen,
    pool: PointPool,
    chosen: np.ndarray,
    config,
) -> np.ndarray:
    """Visibility [T, N] of the pool's points ``chosen`` [N] seen as ``seen`` (one Projection per clip
    frame): in view, facing the camera, not occluded in the lidar's depth; or with
    ``drivetrack.refined_visibility``, ``refined_visibility``'s decisions."""
    rules = config.drivetrack
    frames = range(run.start, run.stop)
    # Normals turn with the frame's pose (the camera turns by under a milliradian during a readout).
    cam_from_box = camera.cam_from_world[run.start : run.stop] @ run.world_from_box
    tracks, pixels = np.stack([s.points for s in seen]), np.stack([s.pixels for s in seen])
    in_view = np.stack([s.in_view for s in seen])
    if rules.refined_visibility:
        refined = evidence.refined
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
        [evidence.depth_tree(t) for t in frames],
        (unit.calibration.width, unit.calibration.height),
        rules.occlusion_margin,
    )


def track_normals(pool: PointPool, chosen: np.ndarray) -> np.ndarray:
    """Unit normals [N, 3] (box frame) of the pool's points ``chosen`` [N], fitted on all the pool's
    points (``surface_normals``), each facing the lidar of its own sweep."""
    return fitted_normals(pool.points, chosen, pool.views[chosen])


def mask_agreement(
    unit: UnitInput,
    run: ObjectRun,
    name: str,
    evidence,
    camera: UnitCamera,
    uv: np.ndarray,
    visibility,
    config,
) -> np.ndarray:
    """Per track [N], the share of its visible frames on the object's mask (NaN without a mask)."""
    masks, has_mask = object_masks(unit, run, name, evidence, camera, config)
    on_object = np.stack(
        [
            on_mask(mask, uv[i]) if mask is not None else np.zeros(uv.shape[1], bool)
            for i, mask in enumerate(masks)
        ]
    )
    return agreement(on_object, visibility, has_mask)


def track_object(
    unit: UnitInput,
    run: ObjectRun,
    evidence: LidarEvidence,
    camera: UnitCamera,
    stored_jpegs: dict[int, bytes],
    config: RunConfig,
) -> ClipRecord | str:
    """Candidate tracks on one vehicle, with visibility, queries and filter statistics; or why there
    are none: its box holds no lidar point, or ``--queries-from`` holds no clip of its name.

    stored_jpegs: the stored frame per unit frame index, for the run's frames.
    """
    name = clip_name(unit.segment, unit.camera, run.object_id)
    rules = config.drivetrack
    pool = point_pool(evidence, run, unit.frames.timestamps)
    if pool is None:
        log.info("%s: object %s has no lidar points in its box; no clip", unit.name, run.object_id)
        return f"object {run.object_id}'s box holds no lidar point on its frames"
    keys = point_keys(config.seed, name, pool.timestamps, pool.pixels)
    frames = range(run.start, run.stop)
    given = given_queries(config.queries_from, "drivetrack", name) if config.queries_from else None
    if config.queries_from and given is None:
        return "--queries-from holds no clip of this name"  # it re-annotates only the clips it holds
    count = rules.oversample * rules.tracks_per_clip
    chosen = choose_points(pool.points, keys, given, run, camera, name, count)
    seen = camera.project_frames(frames, transform_points_batch(run.world_from_box, pool.points[chosen]))
    uv = np.stack([s.pixels for s in seen])
    visibility = object_visibility(unit, run, evidence, camera, seen, pool, chosen, config)
    frame_ids = unit.frames.timestamps[run.start : run.stop]
    return ClipRecord(
        source="drivetrack",
        name=name,
        unit=unit.name,
        images_jpeg=[stored_jpegs[t] for t in frames],
        fx_fy_cx_cy=unit.calibration.fx_fy_cx_cy.copy(),
        image_size=(unit.calibration.width, unit.calibration.height),
        extrinsics_w2c=camera.cam_from_world[run.start : run.stop].copy(),
        tracks_xyz=np.stack([s.points for s in seen]),
        visibility=visibility,
        queries_xyt=clip_queries(uv, visibility, given, query_draws(keys[chosen])),
        frame_ids=frame_ids.copy(),
        track_stats={
            "visible_frames": visibility.sum(axis=0).astype(np.int64),
            "mask_agreement": mask_agreement(unit, run, name, evidence, camera, uv, visibility, config),
        },
        target_tracks=rules.tracks_per_clip,
        given_queries=given is not None,
        depth_export=depth_export(evidence, frames, frame_ids) if config.export_depth else None,
        track_keys=keys[chosen],
    )


def depth_export(evidence: LidarEvidence, frames: range, frame_ids: np.ndarray):
    """The clip's depth samples per frame (``export.depth_export.sparse_record``)."""
    return sparse_record(
        [evidence.depth_uv[t] for t in frames], [evidence.depth_z[t] for t in frames], frame_ids
    )


def stored_frames(unit: UnitInput, frames: list[int], undistorted: bool) -> dict[int, bytes]:
    """The JPEG written for each of ``frames`` (unit frame indices), checked: Waymo's, or undistorted."""
    calibration = unit.calibration
    maps = undistortion_maps(calibration) if undistorted else None
    stored = {}
    for t in frames:
        what = f"camera_image/{unit.segment} camera {unit.camera} frame {unit.frames.timestamps[t]}"
        jpeg = unit.frames.jpegs[t]
        if undistorted:  # one colour decode both checks the frame and feeds the undistortion
            image = check_jpeg(jpeg, calibration.width, calibration.height, what, cv2.IMREAD_COLOR)
            stored[t] = undistort_image(image, maps)
        else:
            check_jpeg(jpeg, calibration.width, calibration.height, what)
            stored[t] = jpeg
    return stored


def unit_camera(unit: UnitInput, config: RunConfig) -> UnitCamera:
    """The unit's camera model; frames are stored undistorted when ``drivetrack.undistort_frames``
    and the lens has any distortion."""
    calibration = unit.calibration
    return UnitCamera(
        calibration,
        unit.frames,
        camera_from_world(unit.frames, calibration),
        config.drivetrack.undistort_frames and bool(np.any(calibration.distortion != 0)),
        f"camera_image/{unit.segment} camera {unit.camera}",
    )


def annotate_cameras(
    units: list[UnitInput], config: RunConfig, wanted: list[Wanted] | None = None
) -> list[UnitClips | Exception]:
    """The candidate clips of cameras of one segment (in object-id order), or per camera the
    exception that failed it. The TOP lidar is decoded and placed in the world once for all the
    cameras with clips (``gather_lidar_cameras``): a bad lidar frame fails each of them; any other
    bad input only its own camera.

    wanted: per camera, the clip names to make (a release run's; the others' objects are not
      tracked, and each wanted name not made says why), or None for every vehicle.
    """
    rules = config.drivetrack
    wanted = wanted or [None] * len(units)
    results: list[UnitClips | Exception | None] = [None] * len(units)
    passes, stored, index, skipped = [], [], [], []
    for i, unit in enumerate(units):
        try:
            world_from_frame = frame_poses(unit)
            camera = unit_camera(unit, config)
            runs, why = select_objects(unit, camera, world_from_frame, config, object_ids(unit, wanted[i]))
            why = {clip_name(unit.segment, unit.camera, object_id): text for object_id, text in why.items()}
            if not runs:
                results[i] = UnitClips((), why)
                continue
            item = CameraPass(unit, runs, camera, world_from_frame)
            stored.append(stored_frames(unit, item.needed, camera.undistorted))
        except Exception as error:  # noqa: BLE001 - the camera's failure, the others go on
            results[i] = error
            continue
        passes.append(item)
        index.append(i)
        skipped.append(why)
    try:
        depth = config.export_depth or not rules.refined_visibility  # the refined rules read none
        evidence = gather_lidar_cameras(
            passes, rules.box_shrink_m, rules.occlusion_margin, rules.refined_visibility, depth
        )
    except Exception as error:  # noqa: BLE001 - the lidar is shared: every camera reading it fails
        evidence = [error] * len(passes)
    for i, item, frames, found, why in zip(index, passes, stored, evidence, skipped, strict=True):
        if isinstance(found, Exception):
            results[i] = found
            continue
        try:
            results[i] = camera_clips(item, found, frames, config, why)
        except Exception as error:  # noqa: BLE001
            results[i] = error
    return results


def camera_clips(
    item: CameraPass, evidence: LidarEvidence, frames: dict[int, bytes], config: RunConfig, why: dict
) -> UnitClips:
    """One camera's clips, one per object run; ``why`` (clip name -> reason) gains the objects that
    made none."""
    clips, not_made = [], dict(why)
    for run in item.runs:
        made = track_object(item.unit, run, evidence, item.camera, frames, config)
        if isinstance(made, str):
            not_made[clip_name(item.unit.segment, item.unit.camera, run.object_id)] = made
        else:
            clips.append(made)
    return UnitClips(tuple(clips), not_made)


def object_ids(unit: UnitInput, wanted: Wanted) -> frozenset[str] | None:
    """The object ids of the clip names ``wanted`` of this unit (None: every object)."""
    if wanted is None:
        return None
    prefix = clip_name(unit.segment, unit.camera, "")
    return frozenset(name[len(prefix) :] for name in wanted if name.startswith(prefix))


def load_units(input_root: str, segment: str, cameras: list[int]) -> list[UnitInput | Exception]:
    """What each camera's unit of one segment reads, or the exception that failed it: the segment's
    shared files (calibration of the TOP lidar, vehicle poses, boxes) are read once, and a bad one
    fails every camera; ``camera_image`` is read once, each camera failing on its own rows."""
    reader = SegmentReader(input_root, segment)
    try:
        reader.check_components()
        shared = {
            "lidar_calibration": reader.lidar_calibration(),
            "world_from_vehicle": reader.vehicle_poses(),
            "boxes": reader.box_labels(),
        }
    except Exception as error:  # noqa: BLE001 - becomes each unit's failure
        return [error] * len(cameras)
    try:
        every_frames = reader.cameras_frames(cameras)  # camera_image read once
    except Exception as error:  # noqa: BLE001 - each camera's failure, after its calibration's
        every_frames = [error] * len(cameras)
    loaded: list[UnitInput | Exception] = []
    for camera, frames in zip(cameras, every_frames, strict=True):
        try:
            calibration = reader.camera_calibration(camera)
        except Exception as error:  # noqa: BLE001 - this camera's failure only
            loaded.append(error)
            continue
        if isinstance(frames, Exception):
            loaded.append(frames)
            continue
        loaded.append(
            UnitInput(
                segment, camera, calibration, frames=frames, lidar_frames=reader.top_lidar_frames, **shared
            )
        )
    return loaded


def annotate_segment(
    input_root: str, units: list[tuple[str, int]], config: RunConfig, wanted: list[Wanted] | None = None
) -> list[UnitClips | Exception]:
    """The units of one segment annotated together (its lidar decoded once): per unit, its clips
    or the exception that failed it; ``wanted``: per unit, the clips to make (None: every one)."""
    segments = {segment for segment, _ in units}
    if len(segments) != 1:
        raise ValueError(f"annotate_segment takes the units of one segment, got {sorted(segments)}")
    loaded = load_units(input_root, units[0][0], [camera for _, camera in units])
    wanted = wanted or [None] * len(units)
    readable = [item for item in loaded if not isinstance(item, Exception)]
    readable_wanted = [w for item, w in zip(loaded, wanted, strict=True) if not isinstance(item, Exception)]
    annotated = iter(annotate_cameras(readable, config, readable_wanted))
    return [item if isinstance(item, Exception) else next(annotated) for item in loaded]
