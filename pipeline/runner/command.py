"""The ``python -m pipeline.run --source {adt,drivetrack,pstudio} --runner DirectRunner ...`` command.

Regenerates TAPVid-3D clips from a source dataset. Any option not listed here is passed to
Beam (``--runner``, ``--direct_num_workers``, ``--direct_running_mode``, Dataflow/Flink/Spark
options, ...) and checked against the options Beam and the runner define. Without ``--input`` it
runs on the embedded sample world. With ``--release`` it regenerates the release's own clips and
writes a verdict for each (``<out>/release_<source>.jsonl``). With ``--training`` it leaves out
every scene the benchmark evaluates on and writes its clips as Parquet shards too
(``<out>/train/<source>/``, docs/training.md).

Exit status: 0 done (clips written, or every unit finished by an earlier run); 1 some unit failed;
2 the run could not start (a bad option or setting, a missing input, an output that cannot be
written) or finish; 3 nothing was produced and nothing resumed (the last line says why: a training
run whose every unit is of a benchmark scene is one); 4 the run stopped itself:
``max_failures_in_a_row`` units in a row failed alike (the last line says why); 130 interrupted by
Ctrl-C; 141 the output was closed (``| head``): the run stopped.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import sys
import time
import uuid
from collections.abc import Mapping

from apache_beam.metrics.metric import MetricsFilter

from pipeline import sources
from pipeline.commandline import StrictParser, UsageError, check_beam_args
from pipeline.core.errors import CannotStart, InputError, OutputError, interruption, root_cause
from pipeline.core.outcomes import FILTER_ORDER
from pipeline.core.progress import quiet_worker_logs, set_verbose, workers_silenced
from pipeline.core.sizes import format_bytes
from pipeline.export.layout import failures_path, provenance_path, release_verdicts_path, temporary_patterns
from pipeline.io.beam_pipeline import pipeline_for, run_to_end
from pipeline.io.file_set import complete_commits
from pipeline.io.files import PARTIAL, remove_abandoned
from pipeline.io.http import one_line, shown
from pipeline.pipes import OUTPUT_CLOSED, READER_GONE, STOPPED, interrupted_status, silence_output
from pipeline.runner import graph
from pipeline.runner.finish import RunSummary, finish_run
from pipeline.runner.monitor import RunMonitor
from pipeline.runner.prepare import (
    PreparedRun,
    plan_lines,
    plan_units,
    prepare_run,
    runner_args,
    sample_input,
)
from pipeline.runner.stages import UnitJob
from pipeline.runner.training import Exclusion, all_left_out, exclusion_line, leave_out_benchmark
from pipeline.runner.training_output import finish_training, withdraw_training_output
from pipeline.runner.verdicts import summary_line
from pipeline.settings.fields import SettingsError, add_set_argument
from pipeline.settings.run_config import RunConfig
from pipeline.sources import NoSample, UnitPlan

NOTHING_PRODUCED = 3


def command_parser() -> StrictParser:
    parser = StrictParser(
        prog="python -m pipeline.run",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--source", choices=sources.names(), help="the dataset to regenerate (required)")
    parser.add_argument("--input", help="source data (DriveTrack: a Waymo Open v2 split folder)")
    parser.add_argument("--output", default="tapvid3d_out", help="output folder (default %(default)s)")
    parser.add_argument(
        "--release",
        metavar="SPLITS_JSON",
        help="the release's splits JSON: annotate only the units its clips need, write only its clips "
        "(under their release names), manifests exactly its splits, and a verdict for every clip it "
        "names in <out>/release_<source>.jsonl",
    )
    parser.add_argument(
        "--training",
        action="store_true",
        help="make training data: leave out every unit of a scene the benchmark evaluates on (training."
        "splits_file), list them in <out>/train/exclusions_<source>.jsonl, write the clips as Parquet "
        "shards in <out>/train/<source>/ and the dataset card <out>/train/DATASET_CARD.md",
    )
    parser.add_argument(
        "--queries-from",
        metavar="DIR",
        help="re-annotate exactly the queries of the clips in DIR (<DIR>/<source>/<clip>.npz, matched "
        "by name, e.g. the released files): tracks correspond one to one, filters report but drop none",
    )
    parser.add_argument(
        "--export-depth",
        action="store_true",
        help="also write the depth each visibility test read to <out>/depth/<source>/<clip>.npz "
        "(dense uint16 mm for adt and pstudio, sparse lidar points for drivetrack)",
    )
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="re-annotate every unit; by default a unit an earlier run finished with the same settings "
        "(its clips on disk, intact and valid) is skipped",
    )
    add_set_argument(
        parser,
        "override a config field, e.g. flicker.max_fraction=0.2 (repeatable)",
    )
    parser.add_argument("--verbose", action="store_true", help="also print the workers' and Beam's log lines")
    return parser


def parse_args(argv: list[str]) -> tuple[argparse.Namespace, list[str]]:
    """The command's own options, and the Beam options (checked, with our defaults); UsageError
    names an unknown option (with the nearest valid name) or a bad value."""
    parser = command_parser()
    args, rest = parser.parse_known_args(argv)
    beam_args = runner_args(rest)
    check_beam_args(beam_args, parser.option_names())
    if args.source is None:
        parser.error("the following arguments are required: --source")
    if args.training and args.release:
        parser.error("--training leaves out the benchmark's scenes, --release makes its clips: give one")
    return args, beam_args


def configure_logging(verbose: bool) -> None:
    logging.basicConfig(
        level=logging.INFO, force=True, format="%(asctime)s %(levelname)s %(message)s", datefmt="%H:%M:%S"
    )
    set_verbose(verbose)
    quiet_worker_logs()


def main(argv: list[str] | None = None, started: float | None = None) -> int:
    """The command; its exit status (the module's docstring lists them). ``started``: the
    ``time.monotonic()`` its "finished in" counts from (default: now)."""
    started = time.monotonic() if started is None else started
    try:
        args, beam_args = parse_args(sys.argv[1:] if argv is None else argv)
    except UsageError as problem:
        print(f"python -m pipeline.run: {problem}", file=sys.stderr)
        return 2
    configure_logging(args.verbose)
    try:
        prepared = prepare_run(args, beam_args)
    except (SettingsError, CannotStart, ValueError, InputError, NoSample) as problem:
        return cannot_start(problem)
    try:
        return run(prepared, started)
    except GaveUp as reason:
        return stopped(prepared, reason)
    except KeyboardInterrupt:
        return stopped(prepared)
    except BrokenPipeError:
        READER_GONE.set()
        return stopped(prepared)


def cannot_start(problem: Exception) -> int:
    """Say why the run cannot start (each problem with the settings on a line of its own); 2."""
    if isinstance(problem, SettingsError):
        print(f"cannot start: {len(problem.problems)} problem(s) with the settings:", file=sys.stderr)
        for line in problem.problems:
            print(f"  {line}", file=sys.stderr)
    elif isinstance(problem, NoSample):
        print(problem, file=sys.stderr)
    else:
        print(f"cannot start: {problem}", file=sys.stderr)
    return 2


def run(prepared: PreparedRun, started: float) -> int:
    """``main`` after the checks, without the stop handling: the plan, the output tidied, the Beam
    graph over the plan's units, the run's files, the closing lines."""
    for line in opening_lines(prepared):
        print(line, flush=True)
    try:
        input_root = sample_input(prepared)
        plan = plan_units(prepared, input_root)
    except (NoSample, CannotStart) as problem:
        return cannot_start(problem)
    plan, dropped = leave_out_benchmark_scenes(prepared, plan)
    if dropped and not plan.units:
        return only_benchmark_scenes(prepared, dropped)
    for line in plan_lines(prepared, input_root, plan):
        print(line, flush=True)
    tidy_output(prepared)
    job = UnitJob(
        prepared.source,
        input_root,
        prepared.config,
        prepared.output,
        resume=not prepared.overwrite,
        run_id=uuid.uuid4().hex,
        expected=plan.expected if prepared.restricted_to is not None else None,
    )
    finished = run_and_finish(prepared, job, plan)
    if finished is None:
        return 2
    summary, metrics = finished
    print_summary(summary, metrics, prepared.output, prepared.source.name)
    if not training_output(prepared, job, plan, summary, dropped):
        return 2
    print(f"finished in {time.monotonic() - started:.1f} s")
    if summary.clips_written == 0:
        print(why_nothing(summary, prepared.config))
    return exit_status(summary)


def opening_lines(prepared: PreparedRun) -> list[str]:
    """What the run says first: what its rule set decides, the release's other names for clips, what
    a training run leaves out and its tracks per clip."""
    alias = prepared.release.alias_line() if prepared.release is not None else None
    training = prepared.training.lines if prepared.training is not None else ()
    return [*prepared.rules.lines(), *([alias] if alias else []), *training]


def leave_out_benchmark_scenes(prepared: PreparedRun, plan: UnitPlan) -> tuple[UnitPlan, list[Exclusion]]:
    """On a training run, ``plan`` without the units of the benchmark's scenes, and those units
    (listed in ``<out>/train/exclusions_<source>.jsonl``, and said); on any other, ``plan``."""
    if prepared.training is None:
        return plan, []
    kept, dropped = leave_out_benchmark(prepared.source, plan, prepared.training, prepared.output)
    print(exclusion_line(prepared.source.name, kept, dropped, prepared.output), flush=True)
    return kept, dropped


def only_benchmark_scenes(prepared: PreparedRun, dropped: list[Exclusion]) -> int:
    """A training run whose every unit is of a benchmark scene: its source's earlier shards removed,
    the last line saying why nothing is written; NOTHING_PRODUCED."""
    for line in withdraw_training_output(prepared):
        print(line)
    print(all_left_out(prepared.source.name, dropped, prepared.output))
    return NOTHING_PRODUCED


def training_output(
    prepared: PreparedRun, job: UnitJob, plan: UnitPlan, summary: RunSummary, dropped: list[Exclusion]
) -> bool:
    """A training run's shards and dataset card written, and said (a run that wrote no clip: its
    source's earlier ones removed); False when they could not be (said in one line). Nothing on any
    other run."""
    if prepared.training is None:
        return True
    try:
        if summary.clips_written:
            lines = finish_training(prepared, job, plan, summary, dropped)
        else:
            lines = withdraw_training_output(prepared)
    except Exception as error:  # noqa: BLE001 - Beam wraps a step's error; say the cause in one line
        interrupted = interruption(error)
        if interrupted is not None:
            raise interrupted from None
        print(
            f"cannot finish: the shards or the dataset card: {one_line(root_cause(error))}", file=sys.stderr
        )
        return False
    for line in lines:
        print(line)
    return True


def partial_files(prepared: PreparedRun) -> list[str]:
    """Globs of the partial files (``pipeline/io/files.py``'s hidden temporaries) that runs of the
    source leave in its folders of the output and the shared manifests folder."""
    return temporary_patterns(prepared.output, prepared.source.name, PARTIAL)


def tidy_output(prepared: PreparedRun) -> None:
    """Before any unit, what killed runs left in the output set right: a finish or compare killed
    mid-commit gets its new set whole, then the partial files of runs that are gone are removed (and
    said); a concurrent run's live ones stay."""
    partial = partial_files(prepared)
    complete_commits(prepared.output)
    removed = remove_abandoned(partial)
    if removed:
        print(f"removed {removed} partial file(s) an interrupted run left in {prepared.output}")


def run_and_finish(
    prepared: PreparedRun, job: UnitJob, plan: UnitPlan
) -> tuple[RunSummary, dict[str, int] | None] | None:
    """The Beam graph run over the plan's units, then the run finished (``finish_run``): its summary
    and Beam counters; None when its output could not be written (said in one line). GaveUp, and a
    Ctrl-C or a closed output however Beam wrapped it, go on to ``main``."""
    quiet = _ReportedByUs()
    logging.getLogger("apache_beam").addFilter(quiet)
    logging.getLogger("apache_beam.runners.common").addFilter(quiet)
    try:
        metrics = beam_counters(run_pipeline(prepared, job, plan))
        return finish_run(prepared, job, plan, metrics), metrics
    except GaveUp:
        raise
    except Exception as error:  # noqa: BLE001 - Beam wraps a step's error; say the cause in one line
        interrupted = interruption(error)
        if interrupted is not None:
            raise interrupted from None
        cause = root_cause(error)
        if not isinstance(cause, (OSError, OutputError)):
            raise
        print(f"cannot finish: {cause}", file=sys.stderr)
        return None


class GaveUp(Exception):
    """The run stopped itself: units failed alike, ``max_failures_in_a_row`` in a row (the message
    says which cause)."""


def run_pipeline(prepared: PreparedRun, job: UnitJob, plan: UnitPlan):
    """Run the Beam graph over the plan's units, reporting each unit as it finishes (worker processes
    silent unless ``--verbose``); the result. GaveUp when the monitor gave up on the run."""
    names = [unit.name for unit in plan.units]
    limit, started = prepared.config.max_failures_in_a_row, time.monotonic()
    monitor = None
    try:
        with workers_silenced() as report:
            monitor = RunMonitor(job.ledger, names, started, report, max_failures_in_a_row=limit)
            with monitor:
                result = _run_graph(prepared, job, plan)
    except BaseException:  # the monitor stopped the main thread: Beam may wrap it in another error
        if monitor is not None and monitor.gave_up:
            raise GaveUp(monitor.gave_up) from None
        raise
    if monitor.gave_up:  # the units failing alike were the last ones: the rule holds all the same
        raise GaveUp(monitor.gave_up)
    return result


def _run_graph(prepared: PreparedRun, job: UnitJob, plan: UnitPlan):
    """The Beam pipeline over the plan's units, run to its end; its result."""
    p = pipeline_for(prepared.options)
    _ = p | "RegenerateClips" >> graph.RegenerateClips(job, plan.units, prepared.options)
    return run_to_end(p)


def beam_counters(result) -> dict[str, int] | None:
    """The run's Beam counters (``graph.COUNTERS``), or None when the runner reports none."""
    try:
        found = result.metrics().query(MetricsFilter().with_namespace(graph.METRICS_NAMESPACE))["counters"]
    except (NotImplementedError, AttributeError, KeyError):
        return None
    totals = {name: 0 for name in graph.COUNTERS}
    for item in found:
        value = item.committed if item.committed is not None else item.attempted
        totals[item.key.metric.name] = totals.get(item.key.metric.name, 0) + int(value or 0)
    return totals


class _ReportedByUs(logging.Filter):
    """Drops Beam's traceback of a step stopped by Ctrl-C or an output error: main says it in one line."""

    def filter(self, record: logging.LogRecord) -> bool:
        kind = record.exc_info[0] if record.exc_info else None
        return not (kind and issubclass(kind, (KeyboardInterrupt, OSError, OutputError)))


def print_summary(summary: RunSummary, metrics: dict[str, int] | None, output: str, source: str) -> None:
    """The closing lines: what this run did (its Beam counters, when the runner reports them), then
    the totals over every unit (finished-earlier ones included), the manifests, where things are."""
    dropped = ", ".join(f"{name} {summary.dropped_by_filter[name]}" for name in FILTER_ORDER)
    if metrics is not None:
        print(
            f"\nthis run (Beam counters): {metrics['units_read']} unit(s) read, "
            f"{metrics['units_resumed']} skipped as finished, {metrics['units_failed']} failed; "
            f"{metrics['clips_written']} of {metrics['clips_annotated']} annotated clip(s) written, "
            f"{metrics['tracks_written']} tracks; dropped by filter: "
            + ", ".join(f"{name} {metrics[f'tracks_dropped_{name}']}" for name in FILTER_ORDER)
        )
    print(
        f"\n{source}: {summary.units} unit(s), {summary.units_resumed} finished earlier, "
        f"{summary.units_failed} failed; {summary.clips_written} clip(s) written "
        f"({summary.clips_below_target} below their target track count)\n"
        f"tracks: {summary.candidate_tracks} candidates, dropped by filter: {dropped}; "
        f"{summary.tracks_passing_filters} passed, {summary.tracks_written} written\n"
        f"manifests: {manifest_line(summary.manifests, source)}\n"
        f"clips in {output}/{source}/, manifests in {output}/manifests/, "
        f"provenance in {provenance_path(output, source)}"
    )
    if summary.release is not None:
        print(f"{summary_line(summary.release)} (one row each in {release_verdicts_path(output, source)})")
    if summary.failures:
        print(f"{summary.failures} failure(s): see {failures_path(output, source)}", file=sys.stderr)


def manifest_line(counts: Mapping[str, int], source: str) -> str:
    """The manifests' entries of ``source`` per split, and every source's when others are listed."""
    line = f"minival {counts['minival']}, full_test {counts['full_test']} clip(s) of {source}"
    if (counts["minival_all"], counts["full_test_all"]) != (counts["minival"], counts["full_test"]):
        line += f" (every source: minival {counts['minival_all']}, full_test {counts['full_test_all']})"
    return line


def why_nothing(summary: RunSummary, config: RunConfig) -> str:
    """Why a run wrote no clip, in one line."""
    resumed = summary.units_resumed
    earlier = f" ({resumed} of them finished by an earlier run with these settings)" if resumed else ""
    return _why_nothing(summary, config) + earlier


def _why_nothing(summary: RunSummary, config: RunConfig) -> str:
    if not summary.units:
        return "no clip written: no unit to annotate (nothing in --input for this run)"
    if summary.units_failed:
        failed = "all" if summary.units_failed == summary.units else f"{summary.units_failed} of the"
        others = "" if summary.units_failed == summary.units else "; the others made no clip"
        cause, count = summary.common_failure, summary.common_failures
        fetched = "fetching --queries-from failed: " if "--queries-from" in cause else ""
        why = f"{fetched}{count} with {cause}"
        return f"no clip written: {failed} {summary.units} unit(s) failed ({why}){others}"
    if not summary.clips_annotated:
        given = ""
        if config.queries_from:
            given = f"; --queries-from {shown(config.queries_from)} holds none of their clips"
        return f"no clip written: the {summary.units} unit(s) made no clip{given}"
    if not summary.candidate_tracks:
        return f"no clip written: the {summary.clips_annotated} clip(s) made had no candidate track"
    if not summary.tracks_passing_filters:
        dropped = ", ".join(f"{name} {count}" for name, count in summary.dropped_by_filter.items() if count)
        candidates = summary.candidate_tracks
        return f"no clip written: every one of the {candidates} candidate tracks was dropped ({dropped})"
    return f"no clip written: no clip kept min_tracks={config.min_tracks} tracks"


def exit_status(summary: RunSummary) -> int:
    """0 done, 1 some unit failed, 3 nothing produced and nothing resumed."""
    if summary.failures:
        return 1
    nothing = summary.clips_written == 0 and summary.units_resumed == 0
    return NOTHING_PRODUCED if nothing else 0


def stopped(prepared: PreparedRun, gave_up: GaveUp | None = None) -> int:
    """After the run stopped itself (``gave_up``), a Ctrl-C, a SIGTERM or a closed output: this run's
    partial files removed; after the last three also the worker processes ended and what they left in
    the source's scratch folder removed. One line (when the output is still open); 4 (gave up), 130
    (Ctrl-C), 143 (SIGTERM), or 141 for a closed output."""
    if gave_up is None:
        stop_workers()
    partial = partial_files(prepared)
    removed = remove_abandoned(partial, include_own=True)
    if gave_up is not None:
        print(
            f"stopped: {gave_up}; finished units are kept: mend the cause and rerun the same command "
            "to resume",
            file=sys.stderr,
        )
        return STOPPED
    freed = 0
    if prepared.source.reclaim_scratch is not None:
        with contextlib.suppress(OSError):
            freed = prepared.source.reclaim_scratch(prepared.config)
    if READER_GONE.is_set():
        silence_output()
        return OUTPUT_CLOSED
    status, word = interrupted_status()
    note = f"; removed {removed} partial file(s)" if removed else ""
    note += f"; emptied {format_bytes(freed)} of scratch" if freed else ""
    print(
        f"{word}: stopped{note}; finished units are kept, rerun the same command to resume",
        file=sys.stderr,
    )
    return status


def stop_workers() -> None:
    """Kill this process's children (the DirectRunner's worker processes) and wait for them to be gone
    (a few seconds at most): their threads here would otherwise keep the interpreter from exiting
    after a Ctrl-C or a closed output, and their temporaries are reclaimable only once they are."""
    import psutil

    children = psutil.Process().children(recursive=True)
    for child in children:
        with contextlib.suppress(psutil.Error):
            child.kill()
    psutil.wait_procs(children, timeout=5)
