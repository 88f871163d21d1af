"""``python -m pipeline.run --source {adt,drivetrack,pstudio} --runner DirectRunner ...``

Regenerates TAPVid-3D clips from a source dataset. Any option not listed here is passed to
Beam (``--runner``, ``--direct_num_workers``, ``--direct_running_mode``, Dataflow/Flink/Spark
options, ...). Without ``--input`` it runs on the embedded sample world.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import os
import platform
import sys
import time

import apache_beam as beam
import numpy as np
from apache_beam.metrics.metric import MetricsFilter
from apache_beam.options.pipeline_options import PipelineOptions

import pipeline
from pipeline import graph, sources, storage
from pipeline.core.config import RunConfig, with_overrides
from pipeline.core.errors import InputError, OutputError, root_cause
from pipeline.export.files import is_local, read_bytes, remove_quietly, write_atomic
from pipeline.export.layout import failures_path, run_record_path, sample_folder
from pipeline.export.manifests import load_official_splits
from pipeline.filters.select import FILTER_ORDER
from pipeline.resume import remove_partial_files
from pipeline.sources import NoSample
from pipeline.unit import UnitJob

MAX_SPLITS_BYTES = 64 << 20
DASK_RUNNER = "apache_beam.runners.dask.dask_runner.DaskRunner"

log = logging.getLogger("pipeline")


def parse_args(argv: list[str]) -> tuple[argparse.Namespace, list[str]]:
    parser = argparse.ArgumentParser(
        prog="python -m pipeline.run",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--source", required=True, choices=sources.names())
    parser.add_argument("--input", help="source data (DriveTrack: a Waymo Open v2 split folder)")
    parser.add_argument("--output", default="tapvid3d_out", help="output folder (default %(default)s)")
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
    parser.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a config field, e.g. flicker.max_fraction=0.2 (repeatable)",
    )
    return parser.parse_known_args(argv)


def configure_logging() -> None:
    logging.basicConfig(
        level=logging.INFO, force=True, format="%(asctime)s %(levelname)s %(message)s", datefmt="%H:%M:%S"
    )
    for noisy in ("apache_beam", "root"):
        logging.getLogger(noisy).setLevel(logging.WARNING)


def record_metrics(result, output: str, source: str) -> dict[str, int] | None:
    """The run's Beam counters (``graph.COUNTERS``), added to its run record as ``metrics``; None
    when the runner reports none (then the record says so)."""
    try:
        found = result.metrics().query(MetricsFilter().with_namespace(graph.METRICS_NAMESPACE))["counters"]
    except (NotImplementedError, AttributeError, KeyError):
        found = None
    counters = None
    if found is not None:
        totals = {name: 0 for name in graph.COUNTERS}
        for item in found:
            value = item.committed if item.committed is not None else item.attempted
            totals[item.key.metric.name] = totals.get(item.key.metric.name, 0) + int(value or 0)
        counters = totals
    path = run_record_path(output, source)
    record = json.loads(read_bytes(path))
    record["metrics"] = counters if counters is not None else "not reported by this runner"
    write_atomic(path, json.dumps(record, indent=2, sort_keys=True).encode())
    return counters


def print_summary(summary: dict, counters: dict[str, int] | None, output: str, source: str) -> None:
    """The closing lines: what this run did (its Beam counters, when the runner reports them), then
    the totals over every unit (finished-earlier ones included), the manifests, where things are."""
    dropped = ", ".join(f"{name} {summary['dropped_by_filter'][name]}" for name in FILTER_ORDER)
    if counters is not None:
        print(
            f"\nthis run (Beam counters): {counters['units_read']} unit(s) read, "
            f"{counters['units_resumed']} skipped as finished, {counters['units_failed']} failed; "
            f"{counters['clips_written']} of {counters['clips_annotated']} annotated clip(s) written, "
            f"{counters['tracks_written']} tracks; dropped by filter: "
            + ", ".join(f"{name} {counters[f'tracks_dropped_{name}']}" for name in FILTER_ORDER)
        )
    print(
        f"\n{source}: {summary['units']} unit(s), {summary['units_resumed']} finished earlier, "
        f"{summary['units_failed']} failed; "
        f"{summary['clips_written']} clip(s) written ({summary['clips_below_target']} below "
        f"their target track count)\n"
        f"tracks: {summary['candidate_tracks']} candidates, dropped by filter: {dropped}; "
        f"{summary['tracks_passing_filters']} passed, {summary['tracks_written']} written\n"
        f"manifests: minival {summary['manifests']['minival']}, full_test "
        f"{summary['manifests']['full_test']} clip(s)\n"
        f"clips in {output}/{source}/, manifests in {output}/manifests/, "
        f"provenance in {run_record_path(output, source)}"
    )
    if summary["failures"]:
        print(f"{summary['failures']} failure(s): see {failures_path(output, source)}", file=sys.stderr)


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


PROBE_BYTES = 4 << 20


def check_writable(output: str) -> None:
    """Raise OSError unless ``output`` takes a real write of PROBE_BYTES (a full disk fails here,
    not after hours of work), which is then removed."""
    probe = f"{output}/.write_probe-{os.getpid()}"
    write_atomic(probe, os.urandom(PROBE_BYTES))
    remove_quietly([probe])


def check_inputs(input_root: str | None, config: RunConfig) -> tuple[dict, dict] | None:
    """Fail before any work: every local path the run will read exists, and ``splits_file`` is read
    and parsed. Returns the official (minival, full_eval) membership, or None without
    ``splits_file``. Raises InputError."""
    paths = {
        "--input": input_root,
        "--queries-from": config.queries_from,
        "pstudio.params_dir": config.pstudio.params_dir,
        "drivetrack.masks_dir": config.drivetrack.masks_dir,
        "splits_file": config.splits_file,
    }
    for what, path in paths.items():
        if path:
            storage.check_scheme(path)
        if path and is_local(path) and not os.path.exists(path):
            raise InputError(f"{what} {path} does not exist")
    if not config.splits_file:
        return None
    try:
        return load_official_splits(read_bytes(config.splits_file, MAX_SPLITS_BYTES).decode())
    except (OSError, UnicodeDecodeError, ValueError) as error:
        what = f"splits_file {config.splits_file}"
        raise InputError(f"{what}: not the release's splits JSON ({error})") from error


def absolute(path: str) -> str:
    """A local path made absolute (workers may run elsewhere); remote URLs unchanged."""
    return os.path.abspath(path) if path and is_local(path) else path


class _ReportedByUs(logging.Filter):
    """Drops Beam's traceback of a step stopped by Ctrl-C or an output error: main says it in one line."""

    def filter(self, record: logging.LogRecord) -> bool:
        kind = record.exc_info[0] if record.exc_info else None
        return not (kind and issubclass(kind, (KeyboardInterrupt, OSError, OutputError)))


def main(argv: list[str] | None = None) -> int:
    """The command; exit 0 when every unit succeeded, 1 when some failed, 2 when the run could not
    start or finish, 130 when interrupted (Ctrl-C)."""
    args, beam_args = parse_args(sys.argv[1:] if argv is None else argv)
    configure_logging()
    output = absolute(args.output)
    try:
        return run(args, beam_args, output)
    except KeyboardInterrupt:
        removed = remove_partial_files(output, args.source, include_own=True)
        note = f"; removed {removed} partial file(s)" if removed else ""
        print(
            f"interrupted: stopped{note}; finished units are kept, rerun the same command to resume",
            file=sys.stderr,
        )
        return 130


def run(args: argparse.Namespace, beam_args: list[str], output: str) -> int:
    """``main`` without the Ctrl-C handling."""
    source = sources.get(args.source)
    beam_args = runner_args(beam_args)
    options = PipelineOptions(beam_args)
    storage.use_options(options)
    try:
        storage.check_scheme(output)
        config = with_overrides(RunConfig(), args.overrides)
        if args.export_depth:
            config = dataclasses.replace(config, export_depth=True)
        config = dataclasses.replace(
            config, queries_from=absolute(args.queries_from or ""), splits_file=absolute(config.splits_file)
        )
        official = check_inputs(args.input, config)
    except (ValueError, InputError) as error:
        print(f"cannot start: {error}", file=sys.stderr)
        return 2
    try:
        check_writable(output)
    except OSError as error:
        print(f"cannot start: output folder {output} is not writable ({error})", file=sys.stderr)
        return 2
    input_root = args.input
    if input_root is None:
        if not is_local(output):
            print(
                f"cannot start: the embedded sample world is written under a local --output; with {output} "
                "pass --input (a copy of the sample uploaded there works)",
                file=sys.stderr,
            )
            return 2
        try:
            input_root = source.sample_input(sample_folder(output, source.name))
        except NoSample as message:
            print(message, file=sys.stderr)
            return 2
        print(f"no --input given: running on the embedded sample world in {input_root}")
    elif "://" not in input_root:
        input_root = os.path.abspath(input_root)
    try:
        units = source.list_units(input_root, config)
    except (InputError, OSError) as error:
        print(f"cannot start: {error}", file=sys.stderr)
        return 2
    provenance = {
        "package": "tapvid3d-pipeline",
        "version": pipeline.__version__,
        "source": args.source,
        "input": input_root,
        "output": output,
        "config": config.to_dict(),
        "units": [source.unit_name(unit) for unit in units],
        "beam_options": beam_args,
        "environment": {
            "python": platform.python_version(),
            "numpy": np.__version__,
            "apache_beam": beam.__version__,
        },
        "started": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    print(f"{args.source}: {len(units)} unit(s) to annotate from {input_root}")
    removed = remove_partial_files(output, args.source)
    if removed:
        print(f"removed {removed} partial file(s) an interrupted run left in {output}")
    started = time.monotonic()
    job = UnitJob(source, input_root, config, output, resume=not args.overwrite)
    quiet = _ReportedByUs()
    logging.getLogger("apache_beam").addFilter(quiet)
    logging.getLogger("apache_beam.runners.common").addFilter(quiet)
    try:
        p = beam.Pipeline(options=options)
        _ = p | "RegenerateClips" >> graph.RegenerateClips(job, units, provenance, official, options)
        result = p.run()
        try:
            result.wait_until_finish()
        finally:
            # Beam's Dask runner opens a distributed.Client for the run and never closes it: a
            # caller that goes on (a notebook, the tests) would keep a client that tries to
            # reconnect once the cluster is gone.
            client = getattr(result, "client", None)
            if client is not None:
                client.close()
    except Exception as error:  # noqa: BLE001 - Beam wraps a step's error; say the cause in one line
        cause = root_cause(error)
        if isinstance(cause, KeyboardInterrupt):
            raise cause from None
        if not isinstance(cause, (OSError, OutputError)):
            raise
        print(f"cannot finish: {cause}", file=sys.stderr)
        return 2
    counters = record_metrics(result, output, source.name)
    summary = json.loads(read_bytes(run_record_path(output, source.name)))["summary"]
    print_summary(summary, counters, output, source.name)
    print(f"finished in {time.monotonic() - started:.1f} s")
    return 1 if summary["failures"] else 0


if __name__ == "__main__":
    sys.exit(main())
