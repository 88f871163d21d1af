"""Annotate DriveTrack units: the cameras of one segment together (its lidar read once), one clip per
vehicle assigned to each camera; per unit its clips (``UnitClips``) or the exception that failed it.

Pure computation on the reader's records; no Beam. The steps, a module each: ``camera_model.py``
(vehicle and camera poses per frame, where a point appears in a frame, undistorted frames),
``objects.py`` (which vehicles, on which frames), ``lidar.py`` (the TOP lidar: depth samples, each
object's points and normals), ``tracks.py`` (one object's candidate clip: ``queries.py`` which
points and their queries, ``visibility.py`` in view, facing, not occluded, or with
``drivetrack.refined_visibility`` ``refined_visibility.py`` with ``footprints.py``,
``object_surface.py`` and ``surface_normals.py``, ``masks.py`` object masks); this module reads a
segment's units, selects their objects, gathers the lidar once and runs ``tracks.py`` per object:
each clip prepared (its points chosen and seen), then with the refined visibility the sweeps kept
are placed again and each frame's footprints streamed to the clips, then each clip finished.

What scales with the frames is let go of once used: the JPEGs read once the frames stored are
made, each frame's footprints once the clips have read them, a camera's evidence once its clips
are made (tests/drivetrack/test_unit_memory.py).
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING

import numpy as np

from pipeline.core.images import check_jpeg
from pipeline.core.outcomes import NotMade, UnitClips
from pipeline.drivetrack.camera_model import (
    Undistortion,
    UnitCamera,
    camera_from_world,
    frame_poses,
)
from pipeline.drivetrack.footprints import FrameOccluders
from pipeline.drivetrack.lidar import CameraPass, LidarEvidence, gather_lidar_cameras, stream_occluders
from pipeline.drivetrack.objects import select_objects
from pipeline.drivetrack.reader import SegmentReader
from pipeline.drivetrack.records import CameraFrames, UnitInput
from pipeline.drivetrack.settings import DriveTrackConfig
from pipeline.drivetrack.tracks import PreparedClip, finish_clip, prepare_clip
from pipeline.drivetrack.units import SegmentCamera, clip_name
from pipeline.sources import RunChoices, Wanted

if TYPE_CHECKING:
    from pipeline.settings.run_config import RunConfig

log = logging.getLogger(__name__)


def stored_frames(unit: UnitInput, frames: list[int], undistorted: bool) -> dict[int, bytes]:
    """The JPEG written for each of ``frames`` (unit frame indices), checked: Waymo's, or undistorted
    (``undistorts``)."""
    calibration = unit.calibration
    undistortion = Undistortion(calibration) if undistorted else None
    stored: dict[int, bytes] = {}
    for t in frames:
        what = f"camera_image/{unit.segment} camera {unit.camera} frame {unit.frames.timestamps[t]}"
        jpeg = unit.frames.jpegs[t]
        if undistortion is not None:  # one colour decode both checks the frame and feeds the undistortion
            stored[t] = undistortion.jpeg(jpeg, what)
        else:
            check_jpeg(jpeg, calibration.width, calibration.height, what)
            stored[t] = jpeg
    return stored


def unit_camera(unit: UnitInput) -> UnitCamera:
    """The unit's camera model."""
    calibration = unit.calibration
    what = f"camera_image/{unit.segment} camera {unit.camera}"
    return UnitCamera(calibration, unit.frames, camera_from_world(unit.frames, calibration), what)


def undistorts(unit: UnitInput, undistort_frames: bool) -> bool:
    """Whether the unit's frames are stored undistorted: ``drivetrack.undistort_frames``, when the
    lens has any distortion."""
    return undistort_frames and bool(np.any(unit.calibration.distortion != 0))


def annotate_cameras(
    units: list[UnitInput], rules: DriveTrackConfig, choices: RunChoices, wanted: list[Wanted] | None = None
) -> list[UnitClips | Exception]:
    """The candidate clips of cameras of one segment (in object-id order), or per camera the
    exception that failed it. The TOP lidar is decoded and placed in the world once for all the
    cameras with clips (``gather_lidar_cameras``): a bad lidar frame fails each of them; any other
    bad input only its own camera. The units' JPEGs are taken over: once a camera's stored frames
    are made (``stored_frames``), its unit holds none (``CameraFrames.release_jpegs``).

    wanted: per camera, the clip names to make (a release run's; the others' objects are not
      tracked, and each wanted name not made says why), or None for every vehicle.
    """
    wanted = wanted or [None] * len(units)
    results: dict[int, UnitClips | Exception] = {}
    passes, stored, index, skipped = [], [], [], []
    for i, unit in enumerate(units):
        try:
            world_from_frame = frame_poses(unit)
            camera = unit_camera(unit)
            runs, why = select_objects(unit, camera, world_from_frame, rules, object_ids(unit, wanted[i]))
            if not runs:
                results[i] = UnitClips((), why)
                continue
            item = CameraPass(unit, runs, camera, world_from_frame)
            stored.append(stored_frames(unit, item.needed, undistorts(unit, rules.undistort_frames)))
        except Exception as error:  # noqa: BLE001 - the camera's failure, the others go on
            results[i] = error
            continue
        finally:
            unit.frames.release_jpegs()  # the stored frames are the unit's JPEGs from here on
        passes.append(item)
        index.append(i)
        skipped.append(why)
    depth = choices.export_depth or not rules.refined_visibility  # the refined rules read none
    evidence: list[LidarEvidence | Exception]
    try:
        evidence = list(
            gather_lidar_cameras(
                passes,
                rules.box_shrink_m,
                rules.occlusion_margin,
                parallax_cleanup=rules.parallax_cleanup,
                refined=rules.refined_visibility,
                depth=depth,
            )
        )
    except Exception as error:  # noqa: BLE001 - the lidar is shared: every camera reading it fails
        evidence = [error for _ in passes]
    prepared = [_prepared(item, found, rules, choices) for item, found in zip(passes, evidence, strict=True)]
    if rules.refined_visibility:
        _see_occluders(evidence, prepared)
    pending = list(zip(index, passes, stored, evidence, prepared, skipped, strict=True))
    del passes, stored, evidence, prepared
    while pending:  # each camera's evidence and frames let go of once its clips are made
        i, item, frames, found, clips, why = pending.pop(0)
        if isinstance(found, Exception) or isinstance(clips, Exception):
            results[i] = found if isinstance(found, Exception) else clips
            continue
        try:
            results[i] = camera_clips(item, found, clips, frames, rules, choices, why)
        except Exception as error:  # noqa: BLE001
            results[i] = error
    return [results[i] for i in range(len(units))]


def _prepared(
    item: CameraPass, evidence: LidarEvidence | Exception, rules: DriveTrackConfig, choices: RunChoices
) -> dict[str, PreparedClip | NotMade] | Exception:
    """A camera's clips up to their visibility (``prepare_clip``), by name: those of its object runs
    that the run wants; or the exception that failed the camera."""
    if isinstance(evidence, Exception):
        return evidence
    try:
        clips: dict[str, PreparedClip | NotMade] = {}
        for run in item.runs:
            if choices.wants(run.name, None):  # the wanted objects alone were selected
                clips[run.name] = prepare_clip(item.unit, run, evidence, item.camera, rules, choices)
        return clips
    except Exception as error:  # noqa: BLE001 - the camera's failure, the others go on
        return error


def _see_occluders(
    evidence: list[LidarEvidence | Exception], prepared: list[dict[str, PreparedClip | NotMade] | Exception]
) -> None:
    """The refined visibility's second pass over the lidar (``stream_occluders``) for the cameras
    whose clips are prepared: each frame's occluders to the camera's clips; a failure fails them
    all (in ``prepared``)."""
    ready: list[int] = []
    found: list[LidarEvidence] = []
    consumers: list[Callable[[int, FrameOccluders], None]] = []
    for k, (camera_evidence, clips) in enumerate(zip(evidence, prepared, strict=True)):
        if isinstance(camera_evidence, Exception) or isinstance(clips, Exception):
            continue
        ready.append(k)
        found.append(camera_evidence)
        consumers.append(
            functools.partial(_see_all, [c for c in clips.values() if isinstance(c, PreparedClip)])
        )
    try:
        stream_occluders(found, consumers)
    except Exception as error:  # noqa: BLE001 - the lidar is shared: every camera reading it fails
        for k in ready:
            prepared[k] = error


def _see_all(clips: list[PreparedClip], t: int, occluders: FrameOccluders) -> None:
    """Camera frame t's occluders to each clip (``PreparedClip.see``)."""
    for clip in clips:
        clip.see(t, occluders)


def camera_clips(
    item: CameraPass,
    evidence: LidarEvidence,
    prepared: dict[str, PreparedClip | NotMade],
    frames: dict[int, bytes],
    rules: DriveTrackConfig,
    choices: RunChoices,
    why: dict[str, str],
) -> UnitClips:
    """One camera's clips, one per prepared clip (``finish_clip``); ``why`` (clip name -> reason)
    gains the objects that made none (the run's objects ``--queries-from`` holds no clip of are
    not prepared: the run says why)."""
    clips, not_made = [], dict(why)
    for name, clip in prepared.items():
        if isinstance(clip, NotMade):
            not_made[name] = clip.reason
        else:
            clips.append(finish_clip(item.unit, clip, evidence, item.camera, frames, rules, choices))
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
        lidar_calibration = reader.lidar_calibration()
        poses, boxes = reader.vehicle_poses(), reader.box_labels()
    except Exception as error:  # noqa: BLE001 - becomes each unit's failure
        return [error for _ in cameras]
    every_frames: list[CameraFrames | Exception]
    try:
        every_frames = list(reader.cameras_frames(cameras))  # camera_image read once
    except Exception as error:  # noqa: BLE001 - each camera's failure, after its calibration's
        every_frames = [error for _ in cameras]
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
                segment, camera, calibration, lidar_calibration, frames, poses, boxes, reader.top_lidar_frames
            )
        )
    return loaded


def annotate_group(
    input_root: str, units: list[SegmentCamera], config: RunConfig, wanted: list[Wanted]
) -> Iterator[UnitClips | Exception]:
    """The units of one segment annotated together (its lidar decoded once): per unit, its clips
    or the exception that failed it; ``wanted``: per unit, the clips to make (None: every one)."""
    segments = {unit.segment for unit in units}
    if len(segments) != 1:
        raise ValueError(f"annotate_group takes the units of one segment, got {sorted(segments)}")
    loaded = load_units(input_root, units[0].segment, [unit.camera for unit in units])
    readable = [item for item in loaded if not isinstance(item, Exception)]
    readable_wanted = [w for item, w in zip(loaded, wanted, strict=True) if not isinstance(item, Exception)]
    rules, choices = config.section(DriveTrackConfig), RunChoices.of(config, "drivetrack")
    annotated = iter(annotate_cameras(readable, rules, choices, readable_wanted))
    for item in loaded:
        yield item if isinstance(item, Exception) else next(annotated)
