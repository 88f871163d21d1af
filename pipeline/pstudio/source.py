"""Panoptic Studio (Dynamic 3D Gaussians) as a Source: (sequence, camera) units, one clip each."""

from __future__ import annotations

import operator

from pipeline.core.clip import ClipRecord
from pipeline.core.config import RunConfig
from pipeline.core.errors import InputError
from pipeline.pstudio.annotate import UnitInput, annotate_unit
from pipeline.pstudio.reader import SequenceFiles, list_sequences, params_path, read_gaussians, read_views
from pipeline.sources import Source

# The camera of the one unit listed for a sequence whose train_meta.json cannot be read: that
# unit fails with the reason, and the other sequences still run.
ALL_CAMERAS = -1


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


def unit_name(unit: tuple[str, int]) -> str:
    return f"{unit[0]}/all_cameras" if unit[1] == ALL_CAMERAS else f"{unit[0]}/camera_{unit[1]}"


def load_unit(input_root: str, sequence: str, camera: int, config: RunConfig) -> UnitInput:
    """Read the unit's cameras, frames and Gaussians; masks are read when annotate asks."""
    views, meta = read_views(input_root, sequence)
    if camera not in views.camera_ids:
        raise InputError(
            f"{sequence}: camera {camera} is not in train_meta.json (cameras {views.camera_ids.tolist()}); "
            "held-out test cameras have no training masks"
        )
    files = SequenceFiles(input_root, sequence, meta, views)
    view = views.index(camera)
    frames = [files.image(view, t) for t in range(len(meta["fn"]))]
    gaussians = read_gaussians(params_path(input_root, sequence, config.pstudio), len(meta["fn"]))
    return UnitInput(sequence, camera, views, gaussians, frames, files.mask)


def sample_input(folder: str) -> str:
    """Write (once) the embedded sample world in Dynamic 3D Gaussians' layout; returns its path."""
    from pipeline.samples.dynamic3dgs_files import write_sample

    return write_sample(folder)


def annotate(input_root: str, unit: tuple[str, int], config: RunConfig) -> list[ClipRecord]:
    """(sequence, camera) -> one candidate clip ``<sequence>_<camera>``."""
    return annotate_unit(load_unit(input_root, *unit, config), config)


SOURCE = Source(
    name="pstudio",
    list_units=list_units,
    unit_name=unit_name,
    annotate=annotate,
    sample_input=sample_input,
    mask_min_agreement=operator.attrgetter("pstudio.mask_min_agreement"),
    sweepable=("pstudio.mask_min_agreement",),
)
