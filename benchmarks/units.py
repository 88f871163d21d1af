"""Per-unit benchmark of one source: the real work of one unit, its peak memory, the speed-up from
1 to N workers, and the CPU-hours of the whole benchmark (``python -m benchmarks``).

A unit is what the Beam graph hands one worker: DriveTrack (segment, camera), Panoptic Studio
(sequence, camera), ADT (sequence, 300-frame chunk). Its work is the graph's own,
``pipeline.unit.run_unit`` (``benchmarks.worker``), in a fresh single-threaded pinned process
(``benchmarks.processes``); the figures are printed by ``benchmarks.report``.

Each source's inputs are built (once, cached under the work folder) by
``benchmarks/inputs_<source>.py``: ``prepare(workdir, quick) -> UnitSetup`` (or None: skipped).
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import os
import shutil
import subprocess
import sys
import tempfile
import time

from benchmarks.processes import run_processes, single_threaded_env
from benchmarks.report import report, speedup_line


@dataclasses.dataclass
class UnitSetup:
    """One source's benchmark unit, as ``prepare`` builds it.

    units: the units of the scaling run (the first one is "the" unit); each is JSON-able.
    frames: frames of one unit's input (for the per-frame figure).
    extrapolate_frames: when set (ADT), a unit of that many frames is extrapolated from the
      measured one (fixed cost + per-frame cost x frames).
    full_units: units of the whole benchmark for the CPU-hours line, with ``full_units_note``.
    """

    source: str
    input_root: str
    units: list
    overrides: list[str]
    frames: int
    description: list[str]
    full_units: int
    full_units_note: str
    extrapolate_frames: int | None = None
    notes: list[str] = dataclasses.field(default_factory=list)
    extra: dict = dataclasses.field(default_factory=dict)  # passed to the worker in its spec


def _specs(setup: UnitSetup, workdir: str, tag: str) -> list[dict]:
    return [
        {
            "source": setup.source,
            "input_root": setup.input_root,
            "unit": unit,
            "overrides": setup.overrides,
            "output": os.path.join(workdir, f"out_{tag}_{i}"),
            **setup.extra,
        }
        for i, unit in enumerate(setup.units)
    ]


def bench_source(source: str, args: argparse.Namespace) -> dict:
    """Prepare the source's unit, run the scaling set with 1 and ``args.workers`` workers, print."""
    module = importlib.import_module(f"benchmarks.inputs_{source}")
    workdir = os.path.abspath(os.path.join(args.workdir, source))
    os.makedirs(workdir, exist_ok=True)
    print(f"\n=== {source}{' (--quick: reduced sizes)' if args.quick else ''} ===", flush=True)
    started = time.perf_counter()
    setup: UnitSetup | None = module.prepare(workdir, args.quick)
    if setup is None:
        return {}
    setup.units = (setup.units * args.units)[: args.units]
    print(f"input ready in {time.perf_counter() - started:.0f} s: {setup.input_root}")
    for line in setup.description:
        print(f"  {line}")
    scratch = tempfile.mkdtemp(prefix="runs-", dir=workdir)
    try:
        print(
            f"running {len(setup.units)} unit(s), one fresh single-threaded process each, 1 worker ...",
            flush=True,
        )
        one, one_wall = run_processes(_specs(setup, scratch, "w1"), 1, scratch, args.pin)
        many, many_wall = None, None
        if args.workers > 1 and len(setup.units) > 1:
            print(f"running the same {len(setup.units)} unit(s) with {args.workers} workers ...", flush=True)
            many, many_wall = run_processes(
                _specs(setup, scratch, f"w{args.workers}"), args.workers, scratch, args.pin
            )
        beam_args = getattr(module, "beam_run_args", None)
        if beam_args and args.workers > 1 and len(setup.units) > 1:
            beam_scaling(setup, beam_args(setup.units), args.workers, scratch)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    return report(setup, one, one_wall, many, many_wall, args.workers, args.pin)


def beam_scaling(setup: UnitSetup, run_args: list[str], workers: int, scratch: str) -> float:
    """The same units through ``python -m pipeline.run`` on Beam's DirectRunner in multi_processing
    mode, with 1 and then ``workers`` worker processes (single-threaded, not pinned): the speed-up
    a user gets from the runner itself, Beam's start-up and the finalize step included."""
    walls = {}
    for count in (1, workers):
        command = [
            sys.executable,
            "-m",
            "pipeline.run",
            "--source",
            setup.source,
            "--input",
            setup.input_root,
        ]
        command += ["--output", os.path.join(scratch, f"beam_w{count}"), "--overwrite", *run_args]
        command += ["--runner", "DirectRunner", "--direct_running_mode=multi_processing"]
        command += [f"--direct_num_workers={count}"]
        print(f"running them through Beam's DirectRunner, {count} worker process(es) ...", flush=True)
        started = time.perf_counter()
        subprocess.run(command, env=single_threaded_env(), check=True, capture_output=True)
        walls[count] = time.perf_counter() - started
    return speedup_line(
        "through Beam (DirectRunner multi_processing, whole command)", walls[1], walls[workers], workers
    )
