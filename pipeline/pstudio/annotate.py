"""Annotate Panoptic Studio units: the cameras of one sequence together, its Gaussians read once and
each mask decoded once (the multi-view mask statistic reads every camera's); per unit, as soon as it is
made, its clip (``UnitClips``) or the exception that failed it (a bad train_meta.json or params.npz
fails them all)."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from typing import TYPE_CHECKING

from pipeline.core.errors import InputError
from pipeline.core.outcomes import UnitClips
from pipeline.core.windows import cut
from pipeline.pstudio.reader import SequenceFiles, params_path, read_gaussians, read_views
from pipeline.pstudio.records import GaussianConstants, Gaussians, UnitInput, Views
from pipeline.pstudio.settings import PstudioConfig
from pipeline.pstudio.splats import gaussian_constants
from pipeline.pstudio.tracks import candidate_clip
from pipeline.pstudio.units import SequenceCamera, clip_name
from pipeline.sources import RunChoices, Wanted

if TYPE_CHECKING:
    from pipeline.settings.run_config import RunConfig


@dataclasses.dataclass(frozen=True)
class LoadedSequence:
    """What every camera's unit of a sequence shares: its views, its files (images, and masks
    through the process's mask cache), its Gaussians and their constants."""

    name: str
    views: Views
    files: SequenceFiles
    frames: int
    gaussians: Gaussians
    constants: GaussianConstants


def load_sequence(input_root: str, sequence: str, settings: PstudioConfig) -> LoadedSequence:
    """Read a sequence's train_meta.json and Gaussians (params.npz); masks are read when asked."""
    meta = read_views(input_root, sequence)
    files = SequenceFiles(input_root, sequence, meta)
    gaussians = read_gaussians(params_path(input_root, sequence, settings), meta.num_frames)
    constants = gaussian_constants(gaussians.scales, gaussians.opacities)
    return LoadedSequence(sequence, meta.views, files, meta.num_frames, gaussians, constants)


def camera_input(opened: LoadedSequence, camera: int) -> UnitInput:
    """One camera's unit of an opened sequence (its frames read now)."""
    views = opened.views
    if camera not in views.camera_ids:
        raise InputError(
            f"{opened.name}: camera {camera} is not in train_meta.json (cameras "
            f"{views.camera_ids.tolist()}); held-out test cameras have no training masks"
        )
    view = views.index(camera)
    frames = [opened.files.image(view, t) for t in range(opened.frames)]
    masks = opened.files.packed_mask
    return UnitInput(opened.name, camera, views, opened.gaussians, opened.constants, frames, masks)


def annotate_group(
    input_root: str, units: list[SequenceCamera], config: RunConfig, wanted: list[Wanted]
) -> Iterator[UnitClips | Exception]:
    """The cameras of one sequence annotated together (``Source.annotate_group``): its Gaussians
    read once, each mask decoded once (the multi-view mask statistic reads every camera's); per
    unit, as soon as it is made, its clip or the exception that failed it (a bad train_meta.json or
    params.npz fails them all). A camera's sequence longer than ``pstudio.clip_frames`` makes one
    clip per window (``core.windows.cut``). A clip not wanted (``wanted``: a release run's, or not
    in ``--queries-from``) is not made; the run says why."""
    sequences = {unit.sequence for unit in units}
    if len(sequences) != 1:
        raise ValueError(f"annotate_group takes the units of one sequence, got {sorted(sequences)}")
    settings, choices = config.section(PstudioConfig), RunChoices.of(config, "pstudio")
    try:
        opened = load_sequence(input_root, units[0].sequence, settings)
    except Exception as error:  # noqa: BLE001 - becomes each unit's failure
        yield from [error] * len(units)
        return
    for unit, keep in zip(units, wanted, strict=True):
        result: UnitClips | Exception
        try:
            whole = clip_name(unit.sequence, unit.camera)
            windows = cut(whole, opened.frames, settings.clip_frames, settings.min_frames)
            windows = [window for window in windows if choices.wants(window.name, keep)]
            clips = []
            if windows:
                camera = camera_input(opened, unit.camera)
                clips = [candidate_clip(camera.in_window(window), settings, choices) for window in windows]
            result = UnitClips(tuple(clips))
        except Exception as error:  # noqa: BLE001 - this camera's failure only (a bad --queries-from file too)
            result = error
        yield result
