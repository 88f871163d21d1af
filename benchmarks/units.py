"""Per-unit benchmark of each source: the real work of one unit, its peak memory, the speed-up from 1
to 2 workers, and the CPU-hours of the whole benchmark (``python -m pipeline.bench``).

A unit is what the Beam graph hands one worker: DriveTrack (segment, camera), Panoptic Studio
(sequence, camera), ADT (sequence, 300-frame chunk). Its work here is exactly the graph's:
the source's ``ANNOTATOR.annotate`` (read the inputs, annotate), ``apply_filters``, and
``WriteClip`` (encode and write the audit table and the ``.npz``), without Beam around it.

Every unit runs in a fresh ``python -m pipeline.bench_units --worker`` process, single-threaded
(``THREAD_ENV``: numba, OpenMP, BLAS, Arrow and OpenCV pools at one thread) and bound to one CPU
of its own (unless ``--no-pin``), so that one worker is one core and the 1-vs-2-worker
comparison is fair. The parent reaps each process with
``os.wait4`` for its CPU time; its peak resident memory is the process's own high-water mark
(``VmHWM``, read by the worker at its end; see ``peak_rss`` for why not ``ru_maxrss``).

Each source's inputs are built (once, cached under the work folder) by
``pipeline/<source>/bench_unit.py``: ``prepare(workdir, quick) -> UnitSetup``.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

# One thread per worker process: numba (pstudio's renderer), OpenMP (numba's omp layer, open3d),
# BLAS, Arrow's CPU pool (it reads OMP_NUM_THREADS) and OpenCV's pool.
THREAD_ENV = {
    "NUMBA_NUM_THREADS": "1",
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "VECLIB_MAXIMUM_THREADS": "1",
    "NUMEXPR_NUM_THREADS": "1",
    "OPENCV_FOR_THREADS_NUM": "1",
}
GIB = 1024**3
MEMORY_TARGET_GIB = {"drivetrack": 2.5}
SPEEDUP_TARGET = 1.6


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


# ---------------------------------------------------------------- worker side


def write_clips(clips, config, output: str) -> dict:
    """The graph's filter and write stages on a unit's clips (``graph.write_clip``); returns counts."""
    from pipeline import graph
    from pipeline.filters.select import apply_filters

    written = tracks = frames = 0
    for clip in clips:
        report, _ = graph.write_clip(output, *apply_filters(clip, config))
        written += report["written_tracks"] > 0
        tracks += report["written_tracks"]
        frames += report["frames"]
    return {"clips": len(clips), "clips_written": written, "tracks_written": tracks, "clip_frames": frames}


def run_annotator_unit(spec: dict) -> dict:
    """One unit through the source's Beam annotator, the filters and the writer, timed."""
    from pipeline.core.config import RunConfig, with_overrides

    module = importlib.import_module(f"pipeline.{spec['source']}.transform")
    config = with_overrides(RunConfig(), spec["overrides"])
    annotator = module.ANNOTATOR(spec["input_root"], config)
    wall, cpu = time.perf_counter(), time.process_time()
    clips = annotator.annotate(tuple(spec["unit"]))
    annotate_s = time.perf_counter() - wall
    counts = write_clips(clips, config, spec["output"])
    return {
        "work_s": time.perf_counter() - wall,
        "work_cpu_s": time.process_time() - cpu,
        "annotate_s": annotate_s,
        **counts,
    }


def peak_rss() -> int | None:
    """This process's own peak resident memory in bytes (VmHWM: the high-water mark of its
    address space since exec), or None off Linux.

    Not ``ru_maxrss``: on Linux a child's ru_maxrss (RUSAGE_SELF in it, or RUSAGE_CHILDREN /
    wait4 in its parent) starts from its parent's high-water mark, which exec carries over, so a
    parent that once held gigabytes (e.g. after writing the inputs) inflates every child's figure."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def worker(spec: dict) -> dict:
    if spec.get("cpu") is not None:  # before the imports, so every thread created later inherits it
        os.sched_setaffinity(0, {spec["cpu"]})
    import cv2

    if os.environ.get("OPENCV_FOR_THREADS_NUM") == "1":
        cv2.setNumThreads(1)
    module = importlib.import_module(f"pipeline.{spec['source']}.bench_unit")
    run = getattr(module, "run_unit", run_annotator_unit)
    return {**run(spec), "peak_rss": peak_rss()}


# ---------------------------------------------------------------- parent side


@dataclasses.dataclass
class UnitRun:
    result: dict
    wall_s: float  # the whole process: interpreter start, imports, work
    cpu_s: float  # user + system CPU of the whole process
    max_rss: int  # bytes: the process's own peak resident memory


def _spawn(spec: dict, workdir: str) -> tuple[subprocess.Popen, str]:
    handle, result_path = tempfile.mkstemp(prefix="unit-", suffix=".json", dir=workdir)
    os.close(handle)
    log = open(result_path[: -len(".json")] + ".log", "w")
    env = dict(os.environ, **THREAD_ENV)
    command = [sys.executable, "-m", "pipeline.bench_units", "--worker", json.dumps(spec), result_path]
    process = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, env=env)
    log.close()
    return process, result_path


def run_processes(
    specs: list[dict], workers: int, workdir: str, pin: bool = True
) -> tuple[list[UnitRun], float]:
    """Run one fresh process per spec, at most ``workers`` at a time; returns each process's
    figures (in spec order) and the wall time of the whole set. With ``pin`` (and enough CPUs),
    each running process is bound to a CPU of its own (``sched_setaffinity``), so a library that
    starts threads anyway (projectaria-tools' re-rendering does) cannot use more than one core."""
    pending = list(enumerate(specs))
    running: dict[int, tuple[int, subprocess.Popen, str, float, int | None]] = {}
    runs: list[UnitRun | None] = [None] * len(specs)
    cpus = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    free = cpus[:workers] if pin and len(cpus) >= workers else [None] * workers
    started = time.perf_counter()
    while pending or running:
        while pending and len(running) < workers:
            index, spec = pending.pop(0)
            cpu = free.pop(0)
            process, path = _spawn(dict(spec, cpu=cpu), workdir)
            running[process.pid] = (index, process, path, time.perf_counter(), cpu)
        pid, status, usage = os.wait4(-1, 0)
        if pid not in running:
            continue
        index, process, path, begun, cpu = running.pop(pid)
        free.append(cpu)
        process.returncode = os.waitstatus_to_exitcode(status)
        log_path = path[: -len(".json")] + ".log"
        if process.returncode != 0:
            for _, other, *_ in running.values():  # stop the other units this call started
                other.kill()
                other.wait()
            with open(log_path) as f:
                tail = f.read()[-3000:]
            raise RuntimeError(f"benchmark unit process failed (exit {process.returncode}):\n{tail}")
        with open(path) as f:
            result = json.load(f)
        os.remove(path)
        os.remove(log_path)
        peak = result.get("peak_rss") or usage.ru_maxrss * 1024  # see peak_rss()
        runs[index] = UnitRun(result, time.perf_counter() - begun, usage.ru_utime + usage.ru_stime, peak)
    return runs, time.perf_counter() - started


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


def _mean(values) -> float:
    return statistics.fmean(values)


def bench_source(source: str, args: argparse.Namespace) -> dict:
    """Prepare the source's unit, run the scaling set with 1 and ``args.workers`` workers, print."""
    module = importlib.import_module(f"pipeline.{source}.bench_unit")
    workdir = os.path.abspath(os.path.join(args.workdir, source))
    os.makedirs(workdir, exist_ok=True)
    print(f"\n=== {source}{' (--quick: reduced sizes)' if args.quick else ''} ===", flush=True)
    started = time.perf_counter()
    setup: UnitSetup = module.prepare(workdir, args.quick)
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
        subprocess.run(command, env=dict(os.environ, **THREAD_ENV), check=True, capture_output=True)
        walls[count] = time.perf_counter() - started
    speedup = walls[1] / walls[workers]
    status = "met" if speedup >= SPEEDUP_TARGET else "MISSED"
    print(
        f"through Beam (DirectRunner multi_processing, whole command): 1 worker {walls[1]:.1f} s, "
        f"{workers} workers {walls[workers]:.1f} s -> speed-up {speedup:.2f}x (target >= {SPEEDUP_TARGET}x: "
        f"{status})"
    )
    return speedup


def report(
    setup: UnitSetup, one: list[UnitRun], one_wall: float, many, many_wall, workers: int, pinned: bool = True
) -> dict:
    source = setup.source
    work = _mean(r.result["work_s"] for r in one)
    work_cpu = _mean(r.result["work_cpu_s"] for r in one)
    annotate = _mean(r.result["annotate_s"] for r in one)
    process_wall = _mean(r.wall_s for r in one)
    process_cpu = _mean(r.cpu_s for r in one)
    max_rss = max(r.max_rss for r in one) / GIB
    first = one[0].result
    frames = setup.frames
    where = "one thread, bound to one CPU" if pinned else "one thread"
    print(f"one unit on one worker (mean of {len(one)} run(s), each a fresh process, {where}):")
    print(
        f"  unit work (read inputs + annotate + filter + encode/write): {work:8.2f} s wall, "
        f"{work_cpu:8.2f} s CPU"
    )
    print(f"    of which read + annotate {annotate:.2f} s, filter + encode + write {work - annotate:.2f} s")
    print(f"  CPU / wall of the unit work: {work_cpu / work:.2f} (1.00 = one busy core; above: threads)")
    print(f"  per frame ({frames} input frames per unit):                {1000 * work / frames:8.1f} ms")
    print(
        f"  whole process (+ interpreter start and imports):            {process_wall:8.2f} s wall, "
        f"{process_cpu:8.2f} s CPU"
    )
    print(
        f"  output: {first['clips']} candidate clip(s), {first['clips_written']} written, "
        f"{first['tracks_written']} tracks, {first['clip_frames']} clip frames in all"
    )
    unit_cpu = work_cpu
    unit_wall = work
    if setup.extrapolate_frames:
        fixed, fixed_cpu = first["fixed_s"], first["fixed_cpu_s"]
        per_frame = _mean((r.result["work_s"] - r.result["fixed_s"]) / frames for r in one)
        per_frame_cpu = _mean((r.result["work_cpu_s"] - r.result["fixed_cpu_s"]) / frames for r in one)
        n = setup.extrapolate_frames
        unit_wall = fixed + n * per_frame
        unit_cpu = fixed_cpu + n * per_frame_cpu
        print(
            f"  per frame without the fixed cost (opening the sequence, {1000 * fixed:.0f} ms): "
            f"{1000 * per_frame:.1f} ms wall, {1000 * per_frame_cpu:.1f} ms CPU"
        )
        print(
            f"  EXTRAPOLATED {n}-frame unit: {fixed:.2f} + {n} x {per_frame:.3f} = {unit_wall:.1f} s wall, "
            f"{unit_cpu:.1f} s CPU"
        )
    target = MEMORY_TARGET_GIB.get(source)
    verdict = ""
    if target:
        verdict = f"   target <= {target} GiB: {'met' if max_rss <= target else 'MISSED'}"
    print(f"  peak memory of the unit's process (max RSS, its VmHWM): {max_rss:.2f} GiB{verdict}")
    speedup = None
    if many is not None:
        speedup = one_wall / many_wall
        status = "met" if speedup >= SPEEDUP_TARGET else "MISSED"
        print(
            f"scaling: the same {len(one)} unit(s): 1 worker {one_wall:.1f} s, {workers} workers "
            f"{many_wall:.1f} s -> speed-up {speedup:.2f}x (target >= {SPEEDUP_TARGET}x: {status}; "
            f"{os.cpu_count()} CPU(s) here)"
        )
        print(
            f"  peak memory per process with {workers} workers: {max(r.max_rss for r in many) / GIB:.2f} GiB"
        )
    cpu_hours = unit_cpu * setup.full_units / 3600
    print(
        f"CPU-hours, full benchmark: {setup.full_units} units x {unit_cpu:.1f} s CPU = "
        f"{cpu_hours:.2f} CPU-hours ({setup.full_units_note})"
    )
    for note in setup.notes:
        print(f"  note: {note}")
    figures = {
        "source": source,
        "unit_s": unit_wall,
        "unit_cpu_s": unit_cpu,
        "per_frame_ms": 1000 * work / frames,
        "max_rss_gib": max_rss,
        "speedup": speedup,
        "cpu_hours": cpu_hours,
        "extrapolated": bool(setup.extrapolate_frames),
    }
    print(
        "RESULT "
        + " ".join(
            f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}"
            for k, v in figures.items()
            if k != "extrapolated"
        )
    )
    return figures


def print_summary(figures: list[dict]) -> None:
    print("\n=== summary (provisional unless taken on an idle machine) ===")
    print(
        f"{'source':<11} {'unit s':>9} {'unit CPU s':>11} {'ms/frame':>9} {'max RSS GiB':>12} "
        f"{'speed-up':>9} {'CPU-hours':>10}"
    )
    for f in figures:
        speedup = f"{f['speedup']:.2f}x" if f["speedup"] else "-"
        mark = "*" if f["extrapolated"] else " "
        print(
            f"{f['source']:<11} {f['unit_s']:8.1f}{mark} {f['unit_cpu_s']:10.1f}{mark} "
            f"{f['per_frame_ms']:9.1f} {f['max_rss_gib']:12.2f} {speedup:>9} {f['cpu_hours']:10.2f}"
        )
    total = sum(f["cpu_hours"] for f in figures)
    print(f"{'all':<11} {'':>9} {'':>11} {'':>9} {'':>12} {'':>9} {total:10.2f}")
    if any(f["extrapolated"] for f in figures):
        print("* extrapolated to a 300-frame unit from the measured per-frame cost (ADT excerpt)")


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--worker"]:
        spec, result_path = json.loads(argv[1]), argv[2]
        result = worker(spec)
        with open(result_path, "w") as f:
            json.dump(result, f)
        return 0
    print("use python -m pipeline.bench", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
