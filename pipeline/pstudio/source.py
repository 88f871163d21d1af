"""Panoptic Studio (Dynamic 3D Gaussians) as a Source: (sequence, camera) units, one clip each;
a sequence's cameras are annotated in groups of ``CAMERAS_PER_GROUP`` (one read of its Gaussians
and masks per group)."""

from __future__ import annotations

import dataclasses
import operator
from collections.abc import Iterator

from pipeline.core.clip import ClipRecord
from pipeline.core.config import RunConfig
from pipeline.core.errors import InputError
from pipeline.pstudio.annotate import Gaussians, UnitInput, Views, annotate_unit
from pipeline.pstudio.reader import SequenceFiles, list_sequences, params_path, read_gaussians, read_views
from pipeline.sources import Source

# The camera of the one unit listed for a sequence whose train_meta.json cannot be read: that
# unit fails with the reason, and the other sequences still run.
ALL_CAMERAS = -1
# Cameras annotated together (by camera id: 0-2, 3-5, ...). A group reads params.npz once (1.7 GiB
# for 150 frames of 300,000 Gaussians) and each mask once (a worker's mask cache then serves the
# sequence's other groups); but a group is one worker's, and a benchmark has a handful of
# sequences: a whole sequence per group left one worker of two idle (0.88x from 1 to 2 workers on
# one sequence's units through the DirectRunner), groups of 3 keep ~9 per sequence to share out.
CAMERAS_PER_GROUP = 3


def list_units(input_root: str, config: RunConfig) -> list[tuple[str, int]]:
    """Every (sequence, camera) pair: the cameras of train_meta.json, or ``pstudio.cameras``."""
    units = []
    for sequence in list_sequences(input_root):
        if config.pstudio.cameras:
            cameras = config.pstudio.cameras
        else:
            try:
                cameras = [int(c) for c in read_views(input_root, sequence)[0].camera_ids]
            except InputError:
                cameras = [ALL_CAMERAS]
        units += [(sequence, camera) for camera in sorted(cameras)]
    return units


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


def load_unit(input_root: str, sequence: str, camera: int, config: RunConfig) -> UnitInput:
    """Read the unit's cameras, frames and Gaussians; masks are read when annotate asks."""
    return camera_input(open_sequence(input_root, sequence, config), camera)


def sample_input(folder: str) -> str:
    """Write (once) the embedded sample world in Dynamic 3D Gaussians' layout; returns its path."""
    from pipeline.samples.dynamic3dgs_files import write_sample

    return write_sample(folder)


def annotate(input_root: str, unit: tuple[str, int], config: RunConfig) -> list[ClipRecord]:
    """(sequence, camera) -> one candidate clip ``<sequence>_<camera>``."""
    return annotate_unit(load_unit(input_root, *unit, config), config)


def annotate_sequence(
    input_root: str, units: list[tuple[str, int]], config: RunConfig
) -> Iterator[list[ClipRecord] | Exception]:
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
            result = annotate_unit(camera_input(opened, camera), config)
        except Exception as error:  # noqa: BLE001 - this camera's failure only
            result = error
        yield result


SOURCE = Source(
    name="pstudio",
    list_units=list_units,
    unit_name=unit_name,
    annotate=annotate,
    sample_input=sample_input,
    mask_min_agreement=operator.attrgetter("pstudio.mask_min_agreement"),
    sweepable=("pstudio.mask_min_agreement",),
    group_of=group_of,
    annotate_group=annotate_sequence,
)
