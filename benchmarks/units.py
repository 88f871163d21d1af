"""Per-unit benchmark of one source: the real work of one unit, its peak memory, the speed-up from
1 to N workers, its read+decode floor, and the CPU-hours of the whole benchmark
(``python -m benchmarks``).

A unit is a group of the source's units, as the Beam graph hands them to one worker (each entry's
``prepare`` says which: DriveTrack a segment's three cameras, which share one read of the lidar).
Its work is the graph's own, ``pipeline.runner.stages.run_group`` (``benchmarks.worker``), in a fresh
single-threaded pinned process (``benchmarks.processes``); its floor (the entry's ``floor``) is
measured in one more such process right after each 1-worker run; with ``--beam`` the source's
groups also run through ``python -m pipeline.run`` on Beam (``benchmarks.beam``); the figures are
printed by ``benchmarks.report``.

Each source's inputs are built (once, cached under the work folder) by its entry's
``prepare(workdir, size) -> UnitSetup`` (or None: skipped).
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time

from benchmarks.beam import beam_scaling
from benchmarks.entry import entry, entry_name
from benchmarks.processes import run_processes
from benchmarks.report import Runs, report
from pipeline.core.benchmark import UnitSetup


def _specs(setup: UnitSetup, workdir: str, tag: str) -> list[dict]:
    """One worker spec per unit of the scaling set, outputs under ``workdir``."""
    module = entry_name(setup.source)
    return [
        {
            "source": setup.source,
            "entry": module,
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
    workdir = os.path.abspath(os.path.join(args.workdir, source))
    os.makedirs(workdir, exist_ok=True)
    started = time.perf_counter()
    return entry(source).prepare(workdir, args.size), time.perf_counter() - started


def prepare_side_by_side(names: tuple[str, ...], args: argparse.Namespace) -> dict:
    """Each source's ``prepare_source`` result, the inputs written by one process per CPU at once
    (before anything is timed); {} for a single source (``bench_source`` prepares it)."""
    if len(names) < 2:
        return {}
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    print(f"preparing the inputs of {', '.join(names)} side by side (written once, reused later) ...")
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(min(len(names), os.cpu_count() or 1), mp_context=context) as pool:
        futures = {source: pool.submit(prepare_source, source, args) for source in names}
        return {source: future.result() for source, future in futures.items()}


def bench_source(
    source: str, args: argparse.Namespace, prepared: tuple[UnitSetup | None, float] | None = None
) -> dict:
    """Prepare the source's unit (unless ``prepared``: ``prepare_source``'s result), run it
    (``run_units``), print; returns the figures (``report``), {} when skipped."""
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
        runs = run_units(setup, args, scratch)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    return report(setup, runs)


def run_units(setup: UnitSetup, args: argparse.Namespace, scratch: str) -> Runs:
    """The scaling set with 1 worker (each run paired with its read+decode floor), then with
    ``args.workers`` workers (and, with ``args.beam``, the source's groups through Beam with 1 and
    ``args.workers`` workers: ``benchmarks.beam``), outputs under ``scratch``."""
    print(
        f"running {len(setup.units)} unit(s), one fresh single-threaded process each, 1 worker, each "
        "followed by its read+decode floor (one more such process)"
        + (" and by the unit with each variant" if setup.variants else "")
        + " ...",
        flush=True,
    )
    # name -> the unit's settings with the variant's
    variants = {name: [*setup.overrides, *overrides] for name, overrides in setup.variants.items()}
    one, one_wall, floors, variant_runs = paired_with_floors(
        _specs(setup, scratch, "w1"), scratch, args.pin, variants
    )
    many, many_wall = None, None
    scaling = args.workers > 1 and len(setup.units) > 1
    if scaling:
        print(f"running the same {len(setup.units)} unit(s) with {args.workers} workers ...", flush=True)
        many, many_wall = run_processes(
            _specs(setup, scratch, f"w{args.workers}"), args.workers, scratch, args.pin
        )
    beam = beam_scaling(setup, args.workers, scratch) if args.beam and args.workers > 1 else None
    return Runs(one, one_wall, floors, many, many_wall, args.workers, args.pin, variant_runs, beam)


def paired_with_floors(
    specs: list[dict], scratch: str, pin: bool, variants: dict[str, list[str]]
) -> tuple[list, float, list, dict[str, list]]:
    """The 1-worker runs, each unit's process followed at once by a process measuring its read+decode
    floor (``mode="floor"``), so that the two figures of each pair meet the same state of a shared
    machine (the unit first: files not yet in the page cache slow the unit, not its floor), then by
    one process per variant (name -> the settings it runs the unit with): (unit runs, their wall time
    in all, floor runs, variant name -> its runs, one per unit)."""
    runs, floors, wall = [], [], 0.0
    variant_runs: dict[str, list] = {name: [] for name in variants}
    for spec in specs:
        (run,), seconds = run_processes([spec], 1, scratch, pin)
        (floor,), _ = run_processes([dict(spec, mode="floor")], 1, scratch, pin)
        runs.append(run)
        floors.append(floor)
        wall += seconds
        for number, (name, overrides) in enumerate(variants.items()):
            variant_spec = dict(spec, overrides=overrides, output=f"{spec['output']}_variant{number}")
            (variant,), _ = run_processes([variant_spec], 1, scratch, pin)
            variant_runs[name].append(variant)
    return runs, wall, floors, variant_runs
