"""DriveTrack (Waymo Open v2) as a Source: (segment, camera) units, one clip per vehicle."""

from __future__ import annotations

import operator

from pipeline.core.clip import ClipRecord
from pipeline.core.config import RunConfig
from pipeline.drivetrack.annotate import annotate_unit
from pipeline.drivetrack.reader import SegmentReader, list_segments
from pipeline.drivetrack.unit_input import UnitInput
from pipeline.sources import Source


def list_units(input_root: str, config: RunConfig) -> list[tuple[str, int]]:
    """Every (segment, camera) pair of the split folder, sorted."""
    return [(s, c) for s in list_segments(input_root) for c in config.drivetrack.cameras]


def load_unit(input_root: str, segment: str, camera: int) -> UnitInput:
    """Read what one unit needs; the TOP lidar is read once, when annotate asks for it."""
    reader = SegmentReader(input_root, segment)
    reader.check_components()
    return UnitInput(
        segment=segment,
        camera=camera,
        calibration=reader.camera_calibration(camera),
        lidar_calibration=reader.lidar_calibration(),
        frames=reader.camera_frames(camera),
        world_from_vehicle=reader.vehicle_poses(),
        boxes=reader.box_labels(),
        lidar_frames=reader.top_lidar_frames,
    )


def unit_name(unit: tuple[str, int]) -> str:
    return f"{unit[0]}/camera_{unit[1]}"


def sample_input(folder: str) -> str:
    """Write (once) the embedded sample world, a Waymo v2 split folder; returns its path."""
    from pipeline.samples.waymo_world import write_sample_split

    return write_sample_split(folder)


def annotate(input_root: str, unit: tuple[str, int], config: RunConfig) -> list[ClipRecord]:
    """(segment, camera) -> one candidate clip per vehicle assigned to that camera."""
    return annotate_unit(load_unit(input_root, *unit), config)


SOURCE = Source(
    name="drivetrack",
    list_units=list_units,
    unit_name=unit_name,
    annotate=annotate,
    sample_input=sample_input,
    mask_min_agreement=operator.attrgetter("drivetrack.mask_min_agreement"),
    sweepable=("drivetrack.mask_min_agreement",),
)
