"""One unit's input or clips, for tests that look inside a source's stages (a source's own entry is
its group form, ``Source.annotate_group``; these call it for one unit)."""

from __future__ import annotations

import dataclasses

from pipeline.adt.annotate import annotate_group
from pipeline.adt.units import SequenceChunk
from pipeline.core.clip import ClipRecord
from pipeline.drivetrack.annotate import annotate_cameras, load_units
from pipeline.drivetrack.records import UnitInput as DriveTrackInput
from pipeline.drivetrack.settings import DriveTrackConfig
from pipeline.pstudio.annotate import camera_input, load_sequence
from pipeline.pstudio.records import UnitInput as StudioInput
from pipeline.pstudio.settings import PstudioConfig
from pipeline.settings.run_config import RunConfig
from pipeline.sources import RunChoices


def _ok(result):
    if isinstance(result, Exception):
        raise result
    return result


def drivetrack_input(input_root: str, segment: str, camera: int) -> DriveTrackInput:
    """What the (segment, camera) unit reads."""
    return _ok(load_units(input_root, segment, [camera])[0])


def drivetrack_clips(unit: DriveTrackInput, config: RunConfig) -> list[ClipRecord]:
    """The candidate clips of one DriveTrack unit (raises its failure). The annotation takes a
    unit's JPEGs over (``CameraFrames.release_jpegs``): it is given a copy of their list, so that
    ``unit`` can be annotated again."""
    choices = RunChoices.of(config, "drivetrack")
    frames = dataclasses.replace(unit.frames, jpegs=list(unit.frames.jpegs))
    copy = dataclasses.replace(unit, frames=frames)
    return list(_ok(annotate_cameras([copy], config.section(DriveTrackConfig), choices)[0]).clips)


def drivetrack_segment_clips(
    input_root: str, segment: str, cameras: tuple[int, ...], config: RunConfig
) -> dict[int, list[ClipRecord]]:
    """Camera -> the candidate clips of a segment's cameras annotated together, as the run's group
    does (one lidar read for all; raises a camera's failure)."""
    choices = RunChoices.of(config, "drivetrack")
    units = [_ok(unit) for unit in load_units(input_root, segment, list(cameras))]
    made = annotate_cameras(units, config.section(DriveTrackConfig), choices)
    return {camera: list(_ok(result).clips) for camera, result in zip(cameras, made, strict=True)}


def pstudio_input(input_root: str, sequence: str, camera: int, config: RunConfig) -> StudioInput:
    """What the (sequence, camera) unit reads."""
    return camera_input(load_sequence(input_root, sequence, config.section(PstudioConfig)), camera)


def adt_clips(input_root: str, unit: SequenceChunk, config: RunConfig) -> list[ClipRecord]:
    """The candidate clips of one ADT (sequence, chunk) unit (raises its failure)."""
    return list(_ok(next(iter(annotate_group(input_root, [unit], config, [None])))).clips)
