"""Per-unit benchmark of one source: the real work of one unit, its peak memory, the speed-up from
1 to N workers, its read+decode floor, and the CPU-hours of the whole benchmark
(``python -m benchmarks``).

A unit is what the Beam graph hands one worker: DriveTrack a segment's three cameras (the group
of its (segment, camera) units, which share one read of the lidar), Panoptic Studio
(sequence, camera), ADT (sequence, 300-frame chunk). Its work is the graph's own,
``pipeline.unit.run_group`` (``benchmarks.worker``), in a fresh single-threaded pinned process
(``benchmarks.processes``); its floor (``benchmarks.floors``) is measured in one more such
process right after each 1-worker run; the figures are printed by ``benchmarks.report``.

Each source's inputs are built (once, cached under the work folder) by
``benchmarks/<source>.py``: ``prepare(workdir, quick[, full]) -> UnitSetup`` (or None:
skipped); ``full`` (full-size inputs) is passed only to a ``prepare`` that takes it.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import inspect
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

    units: the units of the scaling run (the first one is "the" unit); each is a group of the
      source's units, a JSON list (one ADT chunk: a group of one).
    frames: frames of one unit's input as measured (for the per-frame figure).
    extrapolate_frames: when set, the release's unit of that many frames is extrapolated from the
      measured one: fixed cost (ADT: opening the sequence, measured apart; else 0) + per-frame
      cost x frames (ADT: its excerpt holds 2 frames; DriveTrack and Panoptic Studio at the
      default size: shorter inputs than the release's).
    full_units: units of the whole benchmark for the CPU-hours line, with ``full_units_note``.
    size: "quick", "default" or "full" (ADT: its excerpt whatever the size).
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
    size: str = "excerpt"
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


def prepare_source(source: str, args: argparse.Namespace) -> tuple[UnitSetup | None, float]:
    """The source's ``prepare`` (its inputs written once under the work folder): (setup, seconds)."""
    module = importlib.import_module(f"benchmarks.{source}")
    workdir = os.path.abspath(os.path.join(args.workdir, source))
    os.makedirs(workdir, exist_ok=True)
    started = time.perf_counter()
    full = {"full": True} if args.full and "full" in inspect.signature(module.prepare).parameters else {}
    return module.prepare(workdir, args.quick, **full), time.perf_counter() - started


def prepare_side_by_side(sources, args: argparse.Namespace) -> dict:
    """Each source's ``prepare_source`` result, the inputs written by one process per CPU at once
    (before anything is timed); {} for a single source (``bench_source`` prepares it)."""
    if len(sources) < 2:
        return {}
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    print(f"preparing the inputs of {', '.join(sources)} side by side (written once, reused later) ...")
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(min(len(sources), os.cpu_count() or 1), mp_context=context) as pool:
        futures = {source: pool.submit(prepare_source, source, args) for source in sources}
        return {source: future.result() for source, future in futures.items()}


def bench_source(
    source: str, args: argparse.Namespace, prepared: tuple[UnitSetup | None, float] | None = None
) -> dict:
    """Prepare the source's unit (unless ``prepared``: ``prepare_source``'s result), run the scaling
    set with 1 (each run paired with its read+decode floor) and ``args.workers`` workers, print; returns
    the figures (``report``), {} when skipped."""
    module = importlib.import_module(f"benchmarks.{source}")
    workdir = os.path.abspath(os.path.join(args.workdir, source))
    size = "quick: reduced sizes, figures meaningless" if args.quick else "full size" if args.full else ""
    print(f"\n=== {source}{f' ({size})' if size else ''} ===", flush=True)
    setup, seconds = prepared or prepare_source(source, args)
    if setup is None:
        return {}
    setup.units = (setup.units * args.units)[: args.units]
    print(f"input ready in {seconds:.0f} s: {setup.input_root}")
    for line in setup.description:
        print(f"  {line}")
    scratch = tempfile.mkdtemp(prefix="runs-", dir=workdir)
    try:
        print(
            f"running {len(setup.units)} unit(s), one fresh single-threaded process each, 1 worker, each "
            "followed by its read+decode floor (one more such process) ...",
            flush=True,
        )
        one, one_wall, floors = paired_with_floors(_specs(setup, scratch, "w1"), scratch, args.pin)
        many, many_wall = None, None
        if args.workers > 1 and len(setup.units) > 1:
            print(f"running the same {len(setup.units)} unit(s) with {args.workers} workers ...", flush=True)
            many, many_wall = run_processes(
                _specs(setup, scratch, f"w{args.workers}"), args.workers, scratch, args.pin
            )
        beam_args = getattr(module, "beam_run_args", None)
        if args.beam and beam_args and args.workers > 1 and len(setup.units) > 1:
            beam_scaling(setup, beam_args(setup.units), args.workers, scratch)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    return report(setup, one, one_wall, many, many_wall, floors, args.workers, args.pin)


def paired_with_floors(specs: list[dict], scratch: str, pin: bool) -> tuple[list, float, list]:
    """The 1-worker runs, each unit's process followed at once by a process measuring its read+decode
    floor (``mode="floor"``), so that the two figures of each pair meet the same state of a shared
    machine (the unit first: files not yet in the page cache slow the unit, not its floor):
    (unit runs, their wall time in all, floor runs)."""
    runs, floors, wall = [], [], 0.0
    for spec in specs:
        (run,), seconds = run_processes([spec], 1, scratch, pin)
        (floor,), _ = run_processes([dict(spec, mode="floor")], 1, scratch, pin)
        runs.append(run)
        floors.append(floor)
        wall += seconds
    return runs, wall, floors


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
