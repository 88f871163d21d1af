"""Panoptic Studio's units: one camera of one sequence (``SequenceCamera``), listed from Dynamic 3D
Gaussians' ``train_meta.json`` files (on a release run, only the pairs the release names)."""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

from pipeline.core.errors import InputError
from pipeline.pstudio.reader import list_sequences, read_views
from pipeline.pstudio.settings import PstudioConfig
from pipeline.sources import UnitPlan

if TYPE_CHECKING:
    from pipeline.settings.run_config import RunConfig

# The camera of the one unit listed for a sequence whose train_meta.json cannot be read: that
# unit fails with the reason, and the other sequences still run.
ALL_CAMERAS = -1
# Cameras annotated together (by camera id: 0-2, 3-5, ...). A group reads params.npz once (1.7 GiB
# for 150 frames of 300,000 Gaussians) and each mask once (a worker's mask cache then serves the
# sequence's other groups); but a group is one worker's, and the release has few sequences: a whole
# sequence per group would put all of a sequence's cameras on one worker and leave the others idle,
# while groups of 3 give each sequence ~9 groups to share out.
CAMERAS_PER_GROUP = 3
# The cameras Dynamic 3D Gaussians holds out for testing (its test_meta.json): no training masks.
HELD_OUT_CAMERAS = (0, 10, 15, 30)


def clip_name(sequence: str, camera: int) -> str:
    """The release's Panoptic Studio clip name."""
    return f"{sequence}_{camera}"


@dataclasses.dataclass(frozen=True, order=True)
class SequenceCamera:
    """A Panoptic Studio unit: one camera of one sequence, one clip (``ALL_CAMERAS``: a sequence whose
    train_meta.json cannot be read, a unit that fails with the reason). A sequence's cameras are
    annotated in groups of ``CAMERAS_PER_GROUP`` (``group``)."""

    sequence: str
    camera: int

    @property
    def name(self) -> str:
        return (
            f"{self.sequence}/all_cameras"
            if self.camera == ALL_CAMERAS
            else f"{self.sequence}/camera_{self.camera}"
        )

    @property
    def group(self) -> str:
        return f"{self.sequence}/cameras_{self.camera // CAMERAS_PER_GROUP}"


def list_units(
    input_root: str, config: RunConfig, release: frozenset[str] | None = None
) -> UnitPlan[SequenceCamera]:
    """Every (sequence, camera) pair: the cameras of train_meta.json, or ``pstudio.cameras``; on a
    release run, only the pairs the release names (``<sequence>_<camera>``)."""
    settings = config.section(PstudioConfig)
    units: list[SequenceCamera] = []
    listed: dict[str, list[int] | None] = {}
    for sequence in list_sequences(input_root):
        try:
            listed[sequence] = [int(c) for c in read_views(input_root, sequence).views.camera_ids]
        except InputError:
            listed[sequence] = None
        cameras = settings.cameras or listed[sequence] or [ALL_CAMERAS]
        units += [SequenceCamera(sequence, camera) for camera in sorted(cameras)]
    if release is None:
        return UnitPlan(units)
    return release_plan(units, listed, release, settings)


def _pair(name: str) -> tuple[str, int] | None:
    """(sequence, camera id) of a Panoptic Studio clip name ``<sequence>_<camera>``, or None."""
    sequence, sep, camera = name.rpartition("_")
    return (sequence, int(camera)) if sep and sequence and camera.isdigit() else None


def clip_scene(name: str) -> str | None:
    """The scene of a Panoptic Studio clip name ``<sequence>_<camera>``: its sequence; None for
    another name."""
    pair = _pair(name)
    return pair[0] if pair else None


def scene_of(unit: SequenceCamera) -> str:
    """A unit's scene: its sequence (every camera of a sequence films one scene)."""
    return unit.sequence


def release_plan(
    units: list[SequenceCamera],
    listed: dict[str, list[int] | None],
    release: frozenset[str],
    settings: PstudioConfig,
) -> UnitPlan[SequenceCamera]:
    """The units of ``units`` whose clip the release names, and why the other names make no clip.

    listed: sequence of --input -> its train_meta.json cameras (None when it cannot be read: then
    each named camera is a unit, which fails with the reason).
    """
    kept: list[SequenceCamera] = []
    absent, not_made = {}, {}
    for name in sorted(release):
        pair = _pair(name)
        if pair is None:
            absent[name] = "not a Panoptic Studio clip name (<sequence>_<camera id>)"
            continue
        sequence, camera = pair
        cameras_of = listed.get(sequence, [])
        if sequence not in listed:
            absent[name] = f"sequence {sequence} is not in --input"
        elif cameras_of is None:
            kept.append(SequenceCamera(sequence, camera))
        elif camera not in cameras_of:
            held_out = " (a held-out test camera: no training masks)" if camera in HELD_OUT_CAMERAS else ""
            absent[name] = (
                f"camera {camera} is not among {sequence}'s train_meta.json cameras "
                f"({_ranges(cameras_of)}){held_out}"
            )
        elif SequenceCamera(sequence, camera) not in units:
            cameras = ",".join(str(c) for c in settings.cameras)
            not_made[name] = f"camera {camera} is not in pstudio.cameras={cameras}"
        else:
            kept.append(SequenceCamera(sequence, camera))
    kept.sort()
    expected = {unit.name: (clip_name(unit.sequence, unit.camera),) for unit in kept}
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
