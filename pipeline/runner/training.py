"""A training run (``python -m pipeline.run --training``): clips of the scenes the benchmark does not
evaluate on, with the rules, tracks and frames per clip of training data.

Before any work (``prepare_training``): the source must say what a scene is (``Source.scene_of``,
``Source.clip_scene``); the benchmark's splits file is found (``training.splits_file``, else the
official one beside the repository) and read; the source's own ``<source>.tracks_per_clip`` takes
``training.tracks_per_clip``, and its clip-length settings ``training.clip_frames``, unless a
``--set`` gives them. Once the units are listed (``leave_out_benchmark``): every unit whose scene a
benchmark clip comes from is dropped and listed, with those clips, in
``<out>/train/exclusions_<source>.jsonl``. The run's end, shards and card, is
``runner/training_output.py``'s.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shlex
from collections.abc import Mapping, Sequence

from pipeline.core.errors import CannotStart
from pipeline.export.layout import exclusions_path
from pipeline.io.files import is_local, write_atomic
from pipeline.io.http import scrub
from pipeline.runner.splits import read_release
from pipeline.settings.fields import clip_lengths, flat_settings, with_overrides
from pipeline.settings.rule_sets import assigned_keys
from pipeline.settings.run_config import RunConfig
from pipeline.sources import Source, UnitPlan

# The official splits file beside the repository (relative to its root), and the environment
# variable that names another place for it.
OFFICIAL_SPLITS = "../shared/data/tapvid3d_official_splits.json"
SPLITS_ENV = "TAPVID3D_OFFICIAL_SPLITS"
SPLITS_KEY = "training.splits_file"
# This file is pipeline/runner/training.py.
_REPOSITORY = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))


@dataclasses.dataclass(frozen=True)
class Training:
    """What a training run keeps from its start to its end.

    splits_file: the benchmark's splits JSON its scenes were read from.
    scenes: each benchmark scene of the source -> the benchmark's clips of it (sorted).
    command: the command line that made the run, as the dataset card shows it.
    lines: what the run says first of its training settings.
    """

    splits_file: str
    scenes: Mapping[str, tuple[str, ...]]
    command: str
    lines: tuple[str, ...] = ()


@dataclasses.dataclass(frozen=True)
class Exclusion:
    """A unit a training run dropped: its scene, and the benchmark's clips of that scene."""

    unit: str
    scene: str
    clips: tuple[str, ...]

    def to_json(self) -> dict:
        return {"unit": self.unit, "scene": self.scene, "clips": list(self.clips)}


def official_splits() -> str | None:
    """The official splits file: ``$TAPVID3D_OFFICIAL_SPLITS`` when set, else ``OFFICIAL_SPLITS``
    beside the repository; None when that file does not exist."""
    path = os.environ.get(SPLITS_ENV) or os.path.join(_REPOSITORY, OFFICIAL_SPLITS)
    path = os.path.normpath(os.path.abspath(path))
    return path if os.path.isfile(path) else None


def splits_path(config: RunConfig) -> str:
    """The splits file a training run leaves out the scenes of: ``training.splits_file`` (already
    checked to exist), else the official one; CannotStart, saying how to give one, when there is none."""
    given = config.training.splits_file
    if given:
        return os.path.abspath(given) if is_local(given) else given
    found = official_splits()
    if found is None:
        where = f"${SPLITS_ENV}={os.environ[SPLITS_ENV]}" if os.environ.get(SPLITS_ENV) else OFFICIAL_SPLITS
        raise CannotStart(
            f"--training leaves out the scenes of the benchmark's splits file, and there is none at {where}; "
            f"give it with --set {SPLITS_KEY}=FILE (or {SPLITS_ENV}=FILE in the environment)"
        )
    return found


def prepare_training(
    config: RunConfig, source: Source, args: argparse.Namespace, beam_args: Sequence[str]
) -> tuple[RunConfig, Training]:
    """A training run's settings (its tracks and frames per clip, its splits file resolved) and what
    it keeps; CannotStart or InputError saying why it cannot start."""
    if source.scene_of is None or source.clip_scene is None:
        raise CannotStart(
            f"--training: source {source.name} does not say what a scene is (Source.scene_of and "
            "Source.clip_scene), so the benchmark's scenes cannot be left out"
        )
    path = splits_path(config)
    given = f"--set {SPLITS_KEY}={config.training.splits_file}" if config.training.splits_file else path
    scenes, unknown = benchmark_scenes(source, read_release(path, given).clips.get(source.name, {}))
    config, tracks = with_training_tracks(config, source.name, args.overrides)
    config, lengths = with_training_lengths(config, source.name, args.overrides)
    config = dataclasses.replace(config, training=dataclasses.replace(config.training, splits_file=path))
    lines = [f"training: leaving out the {len(scenes)} {source.name} scene(s) of {path}", *tracks, *lengths]
    if unknown:
        lines.append(
            f"training: {unknown} {source.name} clip name(s) of {path} name no scene; none left out for them"
        )
    return config, Training(path, scenes, command_line(args, beam_args), tuple(lines))


def benchmark_scenes(source: Source, clips: Mapping[str, str]) -> tuple[dict[str, tuple[str, ...]], int]:
    """Each scene the benchmark's clips of ``source`` come from -> those clips (sorted), and how many
    clip names name no scene of the source."""
    assert source.clip_scene is not None
    scenes: dict[str, list[str]] = {}
    unknown = 0
    for clip in sorted(clips):
        scene = source.clip_scene(clip)
        if scene is None:
            unknown += 1
        else:
            scenes.setdefault(scene, []).append(clip)
    return {scene: tuple(named) for scene, named in scenes.items()}, unknown


def with_training_tracks(
    config: RunConfig, source: str, assignments: list[str]
) -> tuple[RunConfig, list[str]]:
    """``config`` with ``<source>.tracks_per_clip`` at ``training.tracks_per_clip`` unless a ``--set``
    gave it (or the source has no such setting), and the line that says which."""
    key, tracks = f"{source}.tracks_per_clip", config.training.tracks_per_clip
    values = flat_settings(config)
    if key not in values:
        return config, []
    if key in assigned_keys(assignments):
        return config, [f"training: --set {key}={values[key]} wins over training.tracks_per_clip ({tracks})"]
    line = f"training: {key}={tracks} (training.tracks_per_clip; a plain run's: {values[key]})"
    return with_overrides(config, [f"{key}={tracks}"]), [line]


def with_training_lengths(
    config: RunConfig, source: str, assignments: list[str]
) -> tuple[RunConfig, list[str]]:
    """``config`` with the source's clip-length settings (``clip_lengths``: ``<source>.clip_frames``,
    ADT's ``chunk_frames`` and ``min_frames``) at ``training.clip_frames``, unless a ``--set`` gave one
    of them (then all are as given) or it is 0 (the source's own lengths); and the line that says
    which."""
    frames, lengths = config.training.clip_frames, clip_lengths(config, source)
    if not lengths:
        return config, []
    given = [key for key in lengths if key in assigned_keys(assignments)]
    if given:
        said = ", ".join(f"--set {key}={lengths[key]}" for key in given)
        values = ", ".join(f"{key}={value}" for key, value in lengths.items())
        return config, [f"training: {said} wins over training.clip_frames ({frames}): {values}"]
    plain = ", ".join(str(value) for value in lengths.values())
    if not frames:
        return config, [f"training: {', '.join(lengths)} as a plain run's ({plain}; training.clip_frames=0)"]
    set_to = ", ".join(f"{key}={frames}" for key in lengths)
    line = f"training: {set_to} (training.clip_frames; a plain run's: {plain})"
    return with_overrides(config, [f"{key}={frames}" for key in lengths]), [line]


def command_line(args: argparse.Namespace, beam_args: Sequence[str]) -> str:
    """The run's command line, as the dataset card shows it (every URL without its query string)."""
    words = ["python", "-m", "pipeline.run", "--source", args.source]
    words += ["--input", args.input] if args.input else []
    words += ["--output", args.output, "--training"]
    words += [word for assignment in args.overrides for word in ("--set", assignment)]
    words += ["--queries-from", args.queries_from] if args.queries_from else []
    words += [
        flag for flag, on in (("--export-depth", args.export_depth), ("--overwrite", args.overwrite)) if on
    ]
    return scrub(shlex.join([*words, *beam_args]))


def leave_out_benchmark(
    source: Source, plan: UnitPlan, training: Training, output: str
) -> tuple[UnitPlan, list[Exclusion]]:
    """``plan`` without the units of the benchmark's scenes, and those units (written, one JSON object
    a line, to ``<out>/train/exclusions_<source>.jsonl``)."""
    assert source.scene_of is not None
    kept, dropped = [], []
    for unit in plan.units:
        scene = source.scene_of(unit)
        if scene in training.scenes:
            dropped.append(Exclusion(unit.name, scene, training.scenes[scene]))
        else:
            kept.append(unit)
    lines = "".join(json.dumps(item.to_json(), sort_keys=True) + "\n" for item in dropped)
    write_atomic(exclusions_path(output, source.name), lines.encode())
    return dataclasses.replace(plan, units=kept), dropped


def exclusion_line(source: str, plan: UnitPlan, dropped: list[Exclusion], output: str) -> str:
    """What the run says of the units it dropped."""
    total = len(plan.units) + len(dropped)
    scenes = len({item.scene for item in dropped})
    return (
        f"training: left out {len(dropped)} of {total} unit(s), of {scenes} benchmark scene(s) "
        f"(listed in {exclusions_path(output, source)})"
    )


def all_left_out(source: str, dropped: list[Exclusion], output: str) -> str:
    """Why a training run whose every unit is of a benchmark scene writes nothing, in one line."""
    return (
        f"no clip written: every one of the {len(dropped)} unit(s) is of a scene the benchmark evaluates on "
        f"(listed in {exclusions_path(output, source)})"
    )
