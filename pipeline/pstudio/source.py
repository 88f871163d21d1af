"""Panoptic Studio (Dynamic 3D Gaussians) as a Source: (sequence, camera) units, one clip each;
a sequence's cameras are annotated in groups of ``CAMERAS_PER_GROUP`` (one read of its Gaussians
and masks per group)."""

from __future__ import annotations

import dataclasses
import operator
from collections.abc import Iterator
from typing import TYPE_CHECKING

from pipeline.core.errors import InputError
from pipeline.core.outcomes import UnitClips
from pipeline.pstudio.annotate import Gaussians, UnitInput, Views, annotate_unit, clip_name
from pipeline.pstudio.reader import SequenceFiles, list_sequences, params_path, read_gaussians, read_views
from pipeline.pstudio.settings import PstudioConfig
from pipeline.sources import Source, UnitPlan, Wanted

if TYPE_CHECKING:
    from pipeline.settings import RunConfig

# The camera of the one unit listed for a sequence whose train_meta.json cannot be read: that
# unit fails with the reason, and the other sequences still run.
ALL_CAMERAS = -1
# Cameras annotated together (by camera id: 0-2, 3-5, ...). A group reads params.npz once (1.7 GiB
# for 150 frames of 300,000 Gaussians) and each mask once (a worker's mask cache then serves the
# sequence's other groups); but a group is one worker's, and a benchmark has a handful of
# sequences: a whole sequence per group left one worker of two idle (0.88x from 1 to 2 workers on
# one sequence's units through the DirectRunner), groups of 3 keep ~9 per sequence to share out.
CAMERAS_PER_GROUP = 3
# The cameras Dynamic 3D Gaussians holds out for testing (its test_meta.json): no training masks.
HELD_OUT_CAMERAS = (0, 10, 15, 30)


def list_units(input_root: str, config: RunConfig, release: frozenset[str] | None = None) -> UnitPlan:
    """Every (sequence, camera) pair: the cameras of train_meta.json, or ``pstudio.cameras``; on a
    release run, only the pairs the release names (``<sequence>_<camera>``)."""
    units, listed = [], {}
    for sequence in list_sequences(input_root):
        try:
            listed[sequence] = [int(c) for c in read_views(input_root, sequence)[0].camera_ids]
        except InputError:
            listed[sequence] = None
        cameras = config.pstudio.cameras or listed[sequence] or [ALL_CAMERAS]
        units += [(sequence, camera) for camera in sorted(cameras)]
    if release is None:
        return UnitPlan(units)
    return release_plan(units, listed, release, config)


def _pair(name: str) -> tuple[str, int] | None:
    """(sequence, camera id) of a Panoptic Studio clip name ``<sequence>_<camera>``, or None."""
    sequence, sep, camera = name.rpartition("_")
    return (sequence, int(camera)) if sep and sequence and camera.isdigit() else None


def release_plan(
    units: list[tuple[str, int]], listed: dict[str, list[int] | None], release: frozenset[str], config
) -> UnitPlan:
    """The units of ``units`` whose clip the release names, and why the other names make no clip.

    listed: sequence of --input -> its train_meta.json cameras (None when it cannot be read: then
    each named camera is a unit, which fails with the reason).
    """
    kept, absent, not_made = [], {}, {}
    for name in sorted(release):
        pair = _pair(name)
        if pair is None:
            absent[name] = "not a Panoptic Studio clip name (<sequence>_<camera id>)"
            continue
        sequence, camera = pair
        if sequence not in listed:
            absent[name] = f"sequence {sequence} is not in --input"
        elif listed[sequence] is None:
            kept.append((sequence, camera))
        elif camera not in listed[sequence]:
            held_out = " (a held-out test camera: no training masks)" if camera in HELD_OUT_CAMERAS else ""
            absent[name] = (
                f"camera {camera} is not among {sequence}'s train_meta.json cameras "
                f"({_ranges(listed[sequence])}){held_out}"
            )
        elif (sequence, camera) not in units:
            cameras = ",".join(str(c) for c in config.pstudio.cameras)
            not_made[name] = f"camera {camera} is not in pstudio.cameras={cameras}"
        else:
            kept.append((sequence, camera))
    kept.sort()
    expected = {unit_name(unit): (clip_name(*unit),) for unit in kept}
    return UnitPlan(kept, expected=expected, absent=absent, not_made=not_made)


def _ranges(values: list[int]) -> str:
    """``[0, 1, 2, 5]`` as ``0-2, 5``."""
    parts, ordered = [], sorted(values)
    start = previous = ordered[0]
    for value in [*ordered[1:], None]:
        if value is not None and value == previous + 1:
            previous = value
            continue
        parts.append(f"{start}-{previous}" if previous > start else f"{start}")
        if value is not None:
            start = previous = value
    return ", ".join(parts)


def group_of(unit: tuple[str, int]) -> str:
    """The group of a (sequence, camera) unit: its sequence and camera id // CAMERAS_PER_GROUP."""
    sequence, camera = unit
    return f"{sequence}/cameras_{camera // CAMERAS_PER_GROUP}"


def unit_name(unit: tuple[str, int]) -> str:
    return f"{unit[0]}/all_cameras" if unit[1] == ALL_CAMERAS else f"{unit[0]}/camera_{unit[1]}"


@dataclasses.dataclass(frozen=True)
class OpenedSequence:
    """What every camera's unit of a sequence shares: its views, its files (images, and masks
    through the process's mask cache) and its Gaussians."""

    name: str
    views: Views
    files: SequenceFiles
    frames: int
    gaussians: Gaussians


def open_sequence(input_root: str, sequence: str, config: RunConfig) -> OpenedSequence:
    """Read a sequence's train_meta.json and Gaussians (params.npz); masks are read when asked."""
    views, meta = read_views(input_root, sequence)
    files = SequenceFiles(input_root, sequence, meta, views)
    gaussians = read_gaussians(params_path(input_root, sequence, config.pstudio), len(meta["fn"]))
    return OpenedSequence(sequence, views, files, len(meta["fn"]), gaussians)


def camera_input(opened: OpenedSequence, camera: int) -> UnitInput:
    """One camera's unit of an opened sequence (its frames read now)."""
    views = opened.views
    if camera not in views.camera_ids:
        raise InputError(
            f"{opened.name}: camera {camera} is not in train_meta.json (cameras "
            f"{views.camera_ids.tolist()}); held-out test cameras have no training masks"
        )
    view = views.index(camera)
    frames = [opened.files.image(view, t) for t in range(opened.frames)]
    return UnitInput(opened.name, camera, views, opened.gaussians, frames, opened.files.mask)


def sample_input(folder: str) -> str:
    """Write (once) the embedded sample world in Dynamic 3D Gaussians' layout; returns its path."""
    from pipeline.samples.dynamic3dgs_files import write_sample

    return write_sample(folder)


def annotate_sequence(
    input_root: str, units: list[tuple[str, int]], config: RunConfig, wanted: list[Wanted] | None = None
) -> Iterator[UnitClips | Exception]:
    """The cameras of one sequence annotated together: its Gaussians read once, each mask decoded
    once (the multi-view mask statistic reads every camera's); per unit, as soon as it is made, its
    clip or the exception that failed it (a bad train_meta.json or params.npz fails them all)."""
    sequences = {sequence for sequence, _ in units}
    if len(sequences) != 1:
        raise ValueError(f"annotate_sequence takes the units of one sequence, got {sorted(sequences)}")
    try:
        opened = open_sequence(input_root, units[0][0], config)
    except Exception as error:  # noqa: BLE001 - becomes each unit's failure
        yield from [error] * len(units)
        return
    for _, camera in units:
        try:
            result = UnitClips(tuple(annotate_unit(camera_input(opened, camera), config)))
        except Exception as error:  # noqa: BLE001 - this camera's failure only
            result = error
        yield result


SOURCE = Source(
    name="pstudio",
    list_units=list_units,
    unit_name=unit_name,
    annotate_group=annotate_sequence,
    sample_input=sample_input,
    mask_min_agreement=operator.attrgetter("pstudio.mask_min_agreement"),
    sweepable=("pstudio.mask_min_agreement",),
    settings=PstudioConfig,
    group_of=group_of,
)
