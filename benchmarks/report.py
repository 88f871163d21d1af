"""The figures of one source's per-unit benchmark (printed, and returned for the summary), the
summary table of all sources, and the CPU-hours of the whole benchmark."""

from __future__ import annotations

import os
from statistics import fmean

from benchmarks.processes import UnitRun

GIB = 1024**3
MEMORY_TARGET_GIB = {"drivetrack": 2.5}
SPEEDUP_TARGET = 1.6


def speedup_line(what: str, one_wall: float, many_wall: float, workers: int, tail: str = "") -> float:
    """Print the 1-vs-``workers`` line with its verdict against ``SPEEDUP_TARGET``; the speed-up."""
    speedup = one_wall / many_wall
    status = "met" if speedup >= SPEEDUP_TARGET else "MISSED"
    print(
        f"{what}: 1 worker {one_wall:.1f} s, {workers} workers {many_wall:.1f} s -> speed-up "
        f"{speedup:.2f}x (target >= {SPEEDUP_TARGET}x: {status}{tail})"
    )
    return speedup


def report(
    setup, one: list[UnitRun], one_wall: float, many, many_wall, workers: int, pinned: bool = True
) -> dict:
    """Print one source's figures (``setup``: its ``benchmarks.units.UnitSetup``; ``one`` / ``many``:
    the runs with 1 and ``workers`` workers); returns them for ``print_summary``."""
    source = setup.source
    work = fmean(r.result["work_s"] for r in one)
    work_cpu = fmean(r.result["work_cpu_s"] for r in one)
    annotate = fmean(r.result["annotate_s"] for r in one)
    process_wall = fmean(r.wall_s for r in one)
    process_cpu = fmean(r.cpu_s for r in one)
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
        # fixed_s: one opening, measured apart; fixed_in_work_s: the openings the repeated runs paid
        fixed, fixed_cpu = first["fixed_s"], first["fixed_cpu_s"]
        per_frame = fmean((r.result["work_s"] - r.result["fixed_in_work_s"]) / frames for r in one)
        per_frame_cpu = fmean(
            (r.result["work_cpu_s"] - r.result["fixed_in_work_cpu_s"]) / frames for r in one
        )
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
        speedup = speedup_line(
            f"scaling: the same {len(one)} unit(s)",
            one_wall,
            many_wall,
            workers,
            f"; {os.cpu_count()} CPU(s) here",
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
    """The table of every source's figures, with the total CPU-hours."""
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
