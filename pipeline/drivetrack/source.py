"""DriveTrack (Waymo Open v2) as a Source: (segment, camera) units, one clip per vehicle; the
cameras of a segment are annotated together (one read of its lidar)."""

from __future__ import annotations

import operator

from pipeline.core.clip import ClipRecord
from pipeline.core.config import RunConfig
from pipeline.drivetrack.annotate import annotate_cameras, annotate_unit
from pipeline.drivetrack.reader import SegmentReader, list_segments
from pipeline.drivetrack.unit_input import UnitInput
from pipeline.sources import Source


def list_units(input_root: str, config: RunConfig) -> list[tuple[str, int]]:
    """Every (segment, camera) pair of the split folder, sorted."""
    return [(s, c) for s in list_segments(input_root) for c in config.drivetrack.cameras]


def load_unit(input_root: str, segment: str, camera: int) -> UnitInput:
    """Read what one unit needs; the TOP lidar is read once, when annotate asks for it."""
    (loaded,) = load_units(input_root, segment, [camera])
    if isinstance(loaded, Exception):
        raise loaded
    return loaded


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


def annotate(input_root: str, unit: tuple[str, int], config: RunConfig) -> list[ClipRecord]:
    """(segment, camera) -> one candidate clip per vehicle assigned to that camera."""
    return annotate_unit(load_unit(input_root, *unit), config)


def annotate_segment(
    input_root: str, units: list[tuple[str, int]], config: RunConfig
) -> list[list[ClipRecord] | Exception]:
    """The units of one segment annotated together (its lidar decoded once): per unit, its clips
    or the exception that failed it."""
    segments = {segment for segment, _ in units}
    if len(segments) != 1:
        raise ValueError(f"annotate_segment takes the units of one segment, got {sorted(segments)}")
    loaded = load_units(input_root, units[0][0], [camera for _, camera in units])
    readable = [item for item in loaded if not isinstance(item, Exception)]
    annotated = iter(annotate_cameras(readable, config))
    return [item if isinstance(item, Exception) else next(annotated) for item in loaded]


SOURCE = Source(
    name="drivetrack",
    list_units=list_units,
    unit_name=unit_name,
    annotate=annotate,
    sample_input=sample_input,
    mask_min_agreement=operator.attrgetter("drivetrack.mask_min_agreement"),
    sweepable=("drivetrack.mask_min_agreement",),
    group_of=operator.itemgetter(0),
    annotate_group=annotate_segment,
)
