"""Beam edge of the DriveTrack source: list (segment, camera) units and annotate them."""

from __future__ import annotations

from pipeline.core.clip import ClipRecord
from pipeline.core.config import RunConfig
from pipeline.drivetrack.annotate import UnitInput, annotate_unit
from pipeline.drivetrack.reader import SegmentReader, list_segments
from pipeline.graph import Annotator


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


class AnnotateDriveTrack(Annotator):
    """(segment, camera) -> one candidate clip per vehicle assigned to that camera."""

    unit_name = staticmethod(unit_name)

    def annotate(self, unit: tuple[str, int]) -> list[ClipRecord]:
        return annotate_unit(load_unit(self.input_root, *unit), self.config)


def sample_input(folder: str) -> str:
    """Write (once) the embedded sample world, a Waymo v2 split folder; returns its path."""
    from pipeline.samples import load_fixture_module

    return load_fixture_module("waymo_world").write_sample_split(folder)


ANNOTATOR = AnnotateDriveTrack
