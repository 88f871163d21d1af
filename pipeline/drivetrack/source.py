"""DriveTrack (Waymo Open v2) as a Source: (segment, camera) units, one clip per vehicle; the
cameras of a segment are annotated together (one read of its lidar)."""

from __future__ import annotations

import operator
import re
from typing import TYPE_CHECKING

from pipeline.core.outcomes import UnitClips
from pipeline.drivetrack.annotate import annotate_cameras, clip_name
from pipeline.drivetrack.reader import SegmentReader, list_segments
from pipeline.drivetrack.settings import DriveTrackConfig
from pipeline.drivetrack.unit_input import UnitInput
from pipeline.sources import Source, UnitPlan, Wanted

if TYPE_CHECKING:
    from pipeline.settings import RunConfig

# A release clip name: tapvid3d_<segment>_<camera>_<object id>, the segment named as Waymo names
# them (<context>_<start>_<ms>_<end>_<ms>); the object id may itself hold '_'.
RELEASE_NAME = re.compile(r"tapvid3d_([^_]+_\d+_\d+_\d+_\d+)_(\d+)_(.+)")


def list_units(input_root: str, config: RunConfig, release: frozenset[str] | None = None) -> UnitPlan:
    """Every (segment, camera) pair of the split folder, sorted; on a release run, the pairs the
    release names a clip of, each to make only those clips."""
    segments = list_segments(input_root)
    units = [(s, c) for s in segments for c in config.drivetrack.cameras]
    if release is None:
        return UnitPlan(units)
    expected = {
        unit_name(unit): names
        for unit in units
        if (names := tuple(sorted(n for n in release if n.startswith(clip_name(*unit, "")))))
    }
    kept = [unit for unit in units if unit_name(unit) in expected]
    made = {name for names in expected.values() for name in names}
    absent, not_made = {}, {}
    cameras = ",".join(str(c) for c in config.drivetrack.cameras)
    for name in sorted(release - made):
        parsed = RELEASE_NAME.fullmatch(name)
        if parsed is None:
            absent[name] = "not a DriveTrack clip name (tapvid3d_<segment>_<camera>_<object id>)"
        elif parsed[1] not in segments:
            absent[name] = f"segment {parsed[1]} is not in --input"
        else:
            not_made[name] = f"camera {parsed[2]} is not in drivetrack.cameras={cameras}"
    return UnitPlan(kept, expected=expected, absent=absent, not_made=not_made)


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


def unit_name(unit: tuple[str, int]) -> str:
    return f"{unit[0]}/camera_{unit[1]}"


def sample_input(folder: str) -> str:
    """Write (once) the embedded sample world, a Waymo v2 split folder; returns its path."""
    from pipeline.samples.waymo_world import write_sample_split

    return write_sample_split(folder)


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


SOURCE = Source(
    name="drivetrack",
    list_units=list_units,
    unit_name=unit_name,
    annotate_group=annotate_segment,
    sample_input=sample_input,
    mask_min_agreement=operator.attrgetter("drivetrack.mask_min_agreement"),
    sweepable=("drivetrack.mask_min_agreement",),
    settings=DriveTrackConfig,
    group_of=operator.itemgetter(0),
)
