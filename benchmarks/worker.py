"""One benchmark unit in this (fresh) process: ``python -m benchmarks.worker SPEC_JSON RESULT_PATH``,
started by ``benchmarks.processes``.

The work is the Beam graph's, through the same function its stages call:
``pipeline.runner.stages.run_group(UnitJob(source, input_root, config, output, resume=False), units)`` (read
the inputs and annotate, filter, encode and write the clips, record each unit), ``spec["repeat"]``
times (default 1); ``spec["unit"]`` is a group of the source's units (``unit_group``). The source's
``annotate`` and ``annotate_group`` are wrapped only to time them (a generator group: the
making of each unit's clips, not the writing between). The source's benchmark entry
(``spec["entry"]``, a module name) measures apart, before the runs, the costs that do not scale
with the frames (``measure_fixed_cost(spec, config)``; ADT: opening and closing the sequence) for
the extrapolation in ``report``; the functions it names in ``FIXED_IN_WORK`` ((module, name) pairs:
ADT's ``open_sequence`` and ``close_sequence``, which each repeated run calls again) are timed
inside the runs too, so that the report can take exactly what the runs paid for them out of the
per-frame cost. With ``spec["warm_up"]`` (the setup's ``extra``: DriveTrack's), the unit runs once
before the timed runs, apart: what only a worker's first unit pays (imports made on first use,
numba's cache loads) is measured, reported and not counted.

With ``spec["mode"] == "floor"`` the process measures the unit's read+decode floor instead (the
entry's ``floor(spec)``): the bare cost of reading and decoding the unit's inputs.
"""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import json
import os
import shutil
import sys
import time

from benchmarks.processes import peak_rss
from pipeline.core.benchmark import wall_and_cpu


def unit_counts(reports: list) -> dict:
    """Clips, clips written, tracks written and clip frames of one unit's clip reports."""
    return {
        "clips": len(reports),
        "clips_written": sum(r.written for r in reports),
        "tracks_written": sum(r.written_tracks for r in reports),
        "clip_frames": sum(r.frames for r in reports),
    }


def unit_group(group: list, entry) -> list:
    """The spec's unit, a group of the source's units in JSON ([[segment, 1], [segment, 2], ...]:
    DriveTrack's cameras of one segment; [[sequence, chunk]]: one ADT chunk), as ``run_group`` runs
    them: each the source's unit again (the entry's ``unit_of``)."""
    return [entry.unit_of(fields) for fields in group]


def timed_into(totals: list[float], step):
    """step(), its wall and CPU seconds added to totals [2] (wall, CPU)."""
    started, started_cpu = time.perf_counter(), time.process_time()
    try:
        return step()
    finally:
        totals[0] += time.perf_counter() - started
        totals[1] += time.process_time() - started_cpu


def clock_apart(functions, totals: list[float]) -> None:
    """Wrap each function named by ``functions`` ((module, name) pairs) in its module so that
    every call adds its wall and CPU seconds to totals [2] (wall, CPU)."""

    def clocked(function):
        return lambda *args, **kwargs: timed_into(totals, lambda: function(*args, **kwargs))

    for module_name, name in functions:
        module = importlib.import_module(module_name)
        setattr(module, name, clocked(getattr(module, name)))


def clocked_group(annotate_group, totals: list[float]):
    """``annotate_group`` wrapped so that its calls add their wall and CPU seconds to totals [2]
    (wall, CPU); of a generator group, the making of each unit's clips, not the caller's work
    between (the writing)."""

    def clocked(step):
        return timed_into(totals, step)

    def each_timed(items):
        done = object()
        while (item := clocked(lambda: next(items, done))) is not done:
            yield item

    def call(*args):
        result = clocked(lambda: annotate_group(*args))
        return each_timed(result) if inspect.isgenerator(result) else result

    return call


def run(spec: dict) -> dict:
    """The spec's floor (``mode == "floor"``), or its unit's work (``unit_work``), and peak_rss."""
    if spec.get("cpu") is not None:  # before the imports, so every thread created later inherits it
        os.sched_setaffinity(0, {spec["cpu"]})
    import cv2

    if os.environ.get("OPENCV_FOR_THREADS_NUM") == "1":
        cv2.setNumThreads(1)
    entry = importlib.import_module(spec["entry"])
    measured = entry.floor(spec) if spec.get("mode") == "floor" else unit_work(spec, entry)
    return {**measured, "peak_rss": peak_rss()}


def unit_work(spec: dict, entry) -> dict:
    """The unit's work, timed: work_s / work_cpu_s (all runs), annotate_s / annotate_cpu_s (the
    source's annotate), the output counts of the last run, the fixed costs measured apart (the
    entry's ``measure_fixed_cost``) and those paid inside the runs (``FIXED_IN_WORK``). With
    ``spec["warm_up"]``, the unit is run once before the timed runs, into a folder of its own
    (first_unit_s / first_unit_cpu_s; first_unit_extra_cpu_s: over a timed run): the timed runs are
    a worker's steady state."""
    from pipeline import sources
    from pipeline.runner.stages import UnitJob
    from pipeline.settings.fields import with_overrides, with_rules
    from pipeline.settings.run_config import RunConfig

    # As a run does: the rule set named (a plain run's by default) sets its defaults, --set wins.
    rules = with_overrides(RunConfig(), spec["overrides"]).rules
    config = with_overrides(with_rules(RunConfig(), rules), spec["overrides"])
    source = sources.get(spec["source"])
    group = unit_group(spec["unit"], entry)
    fixed = entry.measure_fixed_cost(spec, config)
    release_size_clip = getattr(entry, "release_size_clip", None)
    if release_size_clip is not None:
        fixed["write_unit_s"], fixed["write_unit_cpu_s"] = release_size_write(
            UnitJob(source, spec["input_root"], config, spec["output"], resume=False),
            release_size_clip(spec, config),
        )
    annotating = [0.0, 0.0]  # wall, CPU seconds of the source's annotate
    fixed_in_work = [0.0, 0.0]  # wall, CPU seconds of the FIXED_IN_WORK functions inside the runs
    clock_apart(entry.FIXED_IN_WORK, fixed_in_work)
    annotate_group = clocked_group(source.annotate_group, annotating)
    job = UnitJob(
        dataclasses.replace(source, annotate_group=annotate_group),
        spec["input_root"],
        config,
        spec["output"],
        resume=False,
    )
    if spec.get("warm_up"):
        first_output = f"{spec['output']}_first"
        fixed["first_unit_s"], fixed["first_unit_cpu_s"] = wall_and_cpu(
            checked_run, dataclasses.replace(job, output=first_output), group
        )
        shutil.rmtree(first_output, ignore_errors=True)
        annotating[:], fixed_in_work[:] = [0.0, 0.0], [0.0, 0.0]
    wall, cpu = time.perf_counter(), time.process_time()
    repeat = spec.get("repeat", 1)
    for _ in range(repeat):
        outcomes = checked_run(job, group)
    work_s, work_cpu_s = time.perf_counter() - wall, time.process_time() - cpu
    if "first_unit_cpu_s" in fixed:  # what the first run took over a timed one
        fixed["first_unit_extra_cpu_s"] = fixed["first_unit_cpu_s"] - work_cpu_s / repeat
    return {
        "work_s": work_s,
        "work_cpu_s": work_cpu_s,
        "annotate_s": annotating[0],
        "annotate_cpu_s": annotating[1],
        **unit_counts([report for outcome in outcomes for report in outcome.reports]),
        **fixed,
        "fixed_in_work_s": fixed_in_work[0],
        "fixed_in_work_cpu_s": fixed_in_work[1],
    }


def release_size_write(job, clip, runs: int = 3) -> tuple[float, float]:
    """Wall and CPU seconds (mean of ``runs``) of the filter, encode and write stage of a release
    unit's clip (an entry's ``release_size_clip``), through ``pipeline.runner.stages.filter_unit``
    and ``write_unit`` into a scratch folder beside the unit's output."""
    import tempfile

    from pipeline.core.outcomes import UnitClips
    from pipeline.runner.stages import Annotated, filter_unit, write_unit

    scratch = tempfile.mkdtemp(prefix="write-", dir=os.path.dirname(job.output))
    try:
        job = dataclasses.replace(job, output=scratch)
        wall, cpu = time.perf_counter(), time.process_time()
        for _ in range(runs):
            write_unit(job, filter_unit(job, Annotated("release_size", UnitClips((clip,)), time.time())))
        return (time.perf_counter() - wall) / runs, (time.process_time() - cpu) / runs
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def checked_run(job, group: list) -> list:
    """``run_group(job, group)``'s outcomes; RuntimeError naming a unit that failed."""
    from pipeline.runner.stages import run_group

    outcomes = run_group(job, group)
    for outcome in outcomes:
        if outcome.failures:
            raise RuntimeError(f"unit {outcome.name} failed: {outcome.failures}")
    return outcomes


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 2:
        print(
            "usage: python -m benchmarks.worker SPEC_JSON RESULT_PATH (started by benchmarks)",
            file=sys.stderr,
        )
        return 2
    spec, result_path = json.loads(argv[0]), argv[1]
    result = run(spec)
    with open(result_path, "w") as f:
        json.dump(result, f)
    return 0


if __name__ == "__main__":
    sys.exit(main())
