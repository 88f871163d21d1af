"""Preparing a run, before any work: every option, setting and path checked (``CannotStart`` says
what is wrong, in one line), the sample world or the input, the units to annotate and what the run
says of them."""

from __future__ import annotations

import argparse
import dataclasses
import os
from collections.abc import Mapping

from apache_beam.options.pipeline_options import DirectOptions, PipelineOptions, StandardOptions

from pipeline import sources
from pipeline.core.errors import CannotStart, InputError
from pipeline.core.sizes import format_bytes
from pipeline.export.layout import sample_folder
from pipeline.io import storage
from pipeline.io.files import is_local, remove_quietly, write_atomic
from pipeline.io.http import is_http
from pipeline.runner.splits import Release, read_release
from pipeline.runner.training import Training, prepare_training
from pipeline.settings.fields import path_settings, release_fixed_changes
from pipeline.settings.rule_sets import RuleSet, assigned_keys, configured, rule_set
from pipeline.settings.run_config import RunConfig
from pipeline.sources import Source, UnitPlan

DASK_RUNNER = "apache_beam.runners.dask.dask_runner.DaskRunner"
SAMPLE_WORLD = "the sample world"
PROBE_BYTES = 4 << 20


@dataclasses.dataclass(frozen=True)
class PreparedRun:
    """Everything checked before any work: the source, settings, paths, release and Beam options."""

    source: Source
    config: RunConfig
    rules: RuleSet
    input_root: str | None
    output: str
    release: Release | None
    overwrite: bool
    beam_args: list[str]
    options: PipelineOptions
    training: Training | None = None

    @property
    def restricted_to(self) -> Release | None:
        """The release the run is restricted to (``--release``), or None."""
        return self.release if self.release is not None and self.release.restricts_run else None


def runner_args(beam_args: list[str]) -> list[str]:
    """Beam options with our defaults: the DirectRunner when none is named; ``DaskRunner`` as a
    short name for Beam's Dask runner, whose units go one per partition unless told otherwise (its
    default packs 128 elements in a partition, i.e. the whole run on one worker)."""
    args = [a.replace("DaskRunner", DASK_RUNNER) if a.endswith("DaskRunner") else a for a in beam_args]
    if not any(a.startswith("--runner") for a in args):
        args = ["--runner", "DirectRunner", *args]
    on_dask = DASK_RUNNER in args or f"--runner={DASK_RUNNER}" in args
    if on_dask and not any(a.startswith(("--dask_npartitions", "--dask_partition_size")) for a in args):
        args.append("--dask_partition_size=1")
    return args


def prepare_run(args: argparse.Namespace, beam_args: list[str]) -> PreparedRun:
    """Check everything before any work; CannotStart (or SettingsError, InputError) says what is
    wrong. The rule set's account (``rule_set``) is of the settings before the command's flags,
    which set none that a rule set governs; a training run's (``--training``: ``runner/training.py``)
    are checked and set here too."""
    source = sources.get(args.source)
    options = PipelineOptions(beam_args)
    storage.use_options(options)
    output = absolute(args.output)
    storage.check_scheme(output)
    config = configured(args.overrides, bool(args.release))
    if args.release:
        check_release_lengths(config, source.name)
    rules = rule_set(config, source.name, assigned_keys(args.overrides))
    config, release = command_settings(config, args)
    training = None
    if args.training:
        config, training = prepare_training(config, source, args, beam_args)
    if args.input is None and not source.has_sample:
        source.sample_input(sample_folder(output, source.name))  # NoSample: how to get the source's data
    check_writable(output)
    if args.input is None and not is_local(output):
        raise CannotStart(
            f"the embedded sample world is written under a local --output; with {output} pass --input "
            "(a copy of the sample uploaded there works)"
        )
    input_root = args.input if args.input is None or "://" in args.input else os.path.abspath(args.input)
    return PreparedRun(
        source, config, rules, input_root, output, release, args.overwrite, beam_args, options, training
    )


def check_release_lengths(config: RunConfig, source: str) -> None:
    """CannotStart, on a ``--release`` run, when a clip length of the source is set that cuts the
    release's clips into windows it does not name (``release_fixed``: ``<source>.clip_frames``)."""
    changed = release_fixed_changes(config, source)
    if changed:
        given = ", ".join(f"--set {key}={value}" for key, value in changed.items())
        raise CannotStart(
            f"--release makes the release's clips, whole: {given} cuts them into clips it does not "
            "name; drop it"
        )


def command_settings(config: RunConfig, args: argparse.Namespace) -> tuple[RunConfig, Release | None]:
    """``config`` with the command's own flags (``--export-depth``, ``--queries-from``, ``--release``),
    every path the run reads checked (``check_inputs``), and the release it follows: ``--release``,
    else ``splits_file``'s (the manifests' membership alone), else None."""
    given_splits = config.splits_file
    splits = absolute(args.release or "") or absolute(config.splits_file)
    if args.release and config.splits_file and absolute(config.splits_file) != splits:
        raise CannotStart("--release and --set splits_file name different files; give one")
    config = dataclasses.replace(
        config,
        export_depth=config.export_depth or args.export_depth,
        queries_from=absolute(args.queries_from or config.queries_from),
        splits_file=splits,
    )
    check_inputs(args.input, config, args.release)
    label = f"--release {args.release}" if args.release else f"--set splits_file={given_splits}"
    if not splits:
        return config, None
    return config, dataclasses.replace(read_release(splits, label), restricts_run=bool(args.release))


def check_inputs(input_root: str | None, config: RunConfig, release: str | None = None) -> None:
    """CannotStart unless every local path the run will read exists: ``--input``, ``--release`` and
    every setting declared a path (``core.config.path_setting``) that is set, each named as the user
    gave it (``--set drivetrack.masks_dir=DIR``). ``--queries-from`` may also be an ``http(s)://``
    base (``pipeline.io.given_queries``)."""
    paths = {"--input": input_root, "--release": release, **path_settings(config)}
    for what, path in paths.items():
        if path and not (what == "--queries-from" and is_http(path)):
            storage.check_scheme(path, ("http", "https") if what == "--queries-from" else ())
        if path and is_local(path) and not os.path.exists(path):
            given = f"{what} {path}" if what.startswith("--") else f"--set {what}={path}"
            raise CannotStart(f"{given} does not exist")


def absolute(path: str) -> str:
    """A local path made absolute (workers may run elsewhere); remote URLs unchanged."""
    return os.path.abspath(path) if path and is_local(path) else path


def check_writable(output: str) -> None:
    """CannotStart unless ``output`` takes a real write of PROBE_BYTES (a full disk fails here, not
    after hours of work), which is then removed."""
    if is_local(output) and os.path.isfile(output):
        raise CannotStart(f"--output {output} is a file, not a folder")
    probe = f"{output}/.write_probe-{os.getpid()}"
    try:
        write_atomic(probe, os.urandom(PROBE_BYTES))
    except OSError as error:
        raise CannotStart(f"output folder {output} is not writable ({error.strerror or error})") from None
    remove_quietly([probe])


def sample_input(prepared: PreparedRun) -> str:
    """The run's input root: ``--input``, or the embedded sample world (written once, announced)."""
    if prepared.input_root is not None:
        return prepared.input_root
    folder = sample_folder(prepared.output, prepared.source.name)
    print(f"no --input given: using the embedded sample world in {folder} (written once)", flush=True)
    return prepared.source.sample_input(folder)


def plan_units(prepared: PreparedRun, input_root: str) -> UnitPlan:
    """The source's units (on a release run, those its clips need); CannotStart when unlistable. A
    run on the sample world was given no ``--input``: its reasons say ``the sample world`` where a
    source's listing says ``--input``."""
    release = prepared.restricted_to
    names = release.names(prepared.source.name) if release is not None else None
    try:
        plan = prepared.source.list_units(input_root, prepared.config, names)
    except (InputError, OSError) as error:
        raise CannotStart(str(error)) from None
    if prepared.input_root is not None:
        return plan

    def in_sample(reasons: Mapping[str, str]) -> dict[str, str]:
        return {clip: reason.replace("--input", SAMPLE_WORLD) for clip, reason in reasons.items()}

    return dataclasses.replace(plan, absent=in_sample(plan.absent), not_made=in_sample(plan.not_made))


def plan_lines(prepared: PreparedRun, input_root: str, plan: UnitPlan) -> list[str]:
    """What the run says of its plan before any work: how many units, from where, the source's notes,
    and the most scratch disk the run takes at once (when its units take any)."""
    lines = [f"{prepared.source.name}: {len(plan.units)} unit(s) to annotate from {input_root}", *plan.notes]
    if plan.scratch_per_worker:
        lines.append(scratch_line(plan.scratch_per_worker, prepared.options))
    return lines


def scratch_line(per_worker: int, options: PipelineOptions) -> str:
    """The most scratch disk the run takes at once: concurrent workers x one worker's most."""
    workers = concurrent_workers(options)
    if workers is None:
        return f"peak scratch: {format_bytes(per_worker)} per concurrent worker"
    total = format_bytes(workers * per_worker)
    return f"peak scratch: {workers} worker(s) x {format_bytes(per_worker)} = {total}"


def concurrent_workers(options: PipelineOptions) -> int | None:
    """How many units run at once on the DirectRunner (its worker count in a multi-process or
    multi-thread mode, else one); None for other runners (their cluster decides)."""
    direct = options.view_as(DirectOptions)
    if options.view_as(StandardOptions).runner not in (None, "DirectRunner"):
        return None
    if direct.direct_running_mode in ("multi_processing", "multi_threading"):
        return direct.direct_num_workers or os.cpu_count() or 1
    return 1
