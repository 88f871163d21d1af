"""``python -m pipeline.run --source {adt,drivetrack,pstudio} --runner DirectRunner ...``

Regenerates TAPVid-3D clips from a source dataset. Any option not listed here is passed to
Beam (``--runner``, ``--direct_num_workers``, ``--direct_running_mode``, Dataflow/Flink/Spark
options, ...). Without ``--input`` it runs on the embedded sample world.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import json
import logging
import os
import platform
import sys
import time

import apache_beam as beam
import numpy as np
from apache_beam.options.pipeline_options import PipelineOptions

import pipeline
from pipeline import graph
from pipeline.core.config import RunConfig, with_overrides
from pipeline.core.errors import InputError
from pipeline.export.files import read_bytes
from pipeline.filters.select import FILTER_ORDER

# Each source module provides list_units, unit_name, ANNOTATOR and sample_input.
SOURCE_MODULES = {
    "adt": "pipeline.adt.transform",
    "drivetrack": "pipeline.drivetrack.transform",
    "pstudio": "pipeline.pstudio.transform",
}

log = logging.getLogger("pipeline")


def parse_args(argv: list[str]) -> tuple[argparse.Namespace, list[str]]:
    parser = argparse.ArgumentParser(
        prog="python -m pipeline.run",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--source", required=True, choices=graph.SOURCES)
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
        level=logging.INFO, format="%(asctime)s %(levelname)s %(message)s", datefmt="%H:%M:%S"
    )
    for noisy in ("apache_beam", "root"):
        logging.getLogger(noisy).setLevel(logging.WARNING)


def print_summary(summary: dict, output: str, source: str) -> None:
    dropped = ", ".join(f"{name} {summary['dropped_by_filter'][name]}" for name in FILTER_ORDER)
    print(
        f"\n{source}: {summary['units']} unit(s), {summary['units_failed']} failed; "
        f"{summary['clips_written']} clip(s) written ({summary['clips_below_target']} below "
        f"their target track count)\n"
        f"tracks: {summary['candidate_tracks']} candidates, dropped by filter: {dropped}; "
        f"{summary['tracks_passing_filters']} passed, {summary['tracks_written']} written\n"
        f"manifests: minival {summary['manifests']['minival']}, full_test "
        f"{summary['manifests']['full_test']} clip(s)\n"
        f"clips in {output}/{source}/, manifests in {output}/manifests/, "
        f"provenance in {output}/run_{source}.json"
    )
    if summary["failures"]:
        print(f"{summary['failures']} failure(s): see {output}/failures_{source}.jsonl", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    args, beam_args = parse_args(sys.argv[1:] if argv is None else argv)
    configure_logging()
    if args.source not in SOURCE_MODULES:
        print(
            f"source {args.source!r} is not built yet; available: {sorted(SOURCE_MODULES)}", file=sys.stderr
        )
        return 2
    try:
        config = with_overrides(RunConfig(), args.overrides)
        if args.export_depth:
            config = dataclasses.replace(config, export_depth=True)
        if args.queries_from:
            folder = args.queries_from if "://" in args.queries_from else os.path.abspath(args.queries_from)
            config = dataclasses.replace(config, queries_from=folder)
    except ValueError as error:
        print(error, file=sys.stderr)
        return 2
    module = importlib.import_module(SOURCE_MODULES[args.source])
    output = os.path.abspath(args.output) if "://" not in args.output else args.output
    input_root = args.input
    if input_root is None:
        input_root = module.sample_input(f"{output}/sample_input/{args.source}")
        print(f"no --input given: running on the embedded sample world in {input_root}")
    elif "://" not in input_root:
        input_root = os.path.abspath(input_root)
    try:
        units = module.list_units(input_root, config)
        if config.splits_file:
            read_bytes(config.splits_file)
    except (InputError, OSError) as error:
        print(f"cannot start: {error}", file=sys.stderr)
        return 2
    if not any(a.startswith("--runner") for a in beam_args):
        beam_args = ["--runner", "DirectRunner", *beam_args]
    options = PipelineOptions(beam_args)
    provenance = {
        "package": "tapvid3d-pipeline",
        "version": pipeline.__version__,
        "source": args.source,
        "input": input_root,
        "output": output,
        "config": config.to_dict(),
        "units": [module.unit_name(unit) for unit in units],
        "beam_options": beam_args,
        "environment": {
            "python": platform.python_version(),
            "numpy": np.__version__,
            "apache_beam": beam.__version__,
        },
        "started": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    print(f"{args.source}: {len(units)} unit(s) to annotate from {input_root}")
    started = time.monotonic()
    annotate = module.ANNOTATOR(input_root, config)
    with beam.Pipeline(options=options) as p:
        graph.build(p, units, annotate, output, config, provenance)
    summary = json.loads(read_bytes(f"{output}/run_{args.source}.json"))["summary"]
    print_summary(summary, output, args.source)
    print(f"finished in {time.monotonic() - started:.1f} s")
    return 1 if summary["failures"] else 0


if __name__ == "__main__":
    sys.exit(main())
