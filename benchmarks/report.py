"""The figures of one source's per-unit benchmark (printed, and returned for the table), the one
table of every source with its targets (issue 15, point 4) and the JSON it is written as.

Figures of a release unit (``unit_frames`` frames): ms/frame = its time on one core / its
frames; CPU-hours = that time x the release's units; unit/floor = that time / the same for the
bare reading and decoding of its inputs (``benchmarks.floors``). Where the measured input is
shorter than a release unit (ADT's 2-frame excerpt; DriveTrack and Panoptic Studio at the default
size), the unit is extrapolated: fixed cost (ADT: opening and closing the sequence, measured
apart) + frames x the measured per-frame cost, and its floor likewise; such figures carry ``*``.
Peak memory (max RSS) is always the measured process's, at the size benched.

"Time on one core" is the CPU time of the single-threaded process bound to one CPU: on an idle
machine it equals its wall time; on a busy one the wall time also counts the waits for that CPU
(the ``CPU/wall`` column: below ~0.95 the machine was busy, and the speed-up, a ratio of wall
times, is not to be trusted). The wall-time figures are in the JSON too (``*_wall``).
"""

from __future__ import annotations

import json
import os
from statistics import fmean

from benchmarks.processes import UnitRun

GIB = 1024**3
# Targets (issue 15, point 4): per input frame on one core; memory (DriveTrack); 1 -> 2 workers;
# the whole benchmark's CPU-hours; a unit's wall time over its read+decode floor.
MS_PER_FRAME_TARGET = {"adt": 60.0, "drivetrack": 150.0, "pstudio": 100.0}
MEMORY_TARGET_GIB = {"drivetrack": 2.5}
SPEEDUP_TARGET = 1.8
CPU_HOURS_TARGET = 15.0
FLOOR_RATIO_TARGET = 2.0
SOURCES = ("drivetrack", "pstudio", "adt")

# The table's figure columns: key, heading, format, target comparison, width.
COLUMNS = (
    ("ms_per_frame", "ms/frame", "{:.1f}", "<=", 19),
    ("peak_rss_gib", "peak RSS GiB", "{:.2f}", "<=", 17),
    ("speedup", "speed-up", "{:.2f}x", ">=", 17),
    ("speedup_cpu", "(CPU)", "{:.2f}x", None, 8),
    ("cpu_hours", "CPU-hours", "{:.2f}", "<=", 18),
    ("floor_ratio", "unit/floor", "{:.2f}", "<=", 16),
    ("cpu_per_wall", "CPU/wall", "{:.2f}", None, 8),
)
EXTRAPOLATED = ("ms_per_frame", "cpu_hours", "floor_ratio")
# A floor process's timed figures (``benchmarks.floors.measure``), averaged over the floor runs.
FLOOR_FIGURES = ("floor_s", "floor_cpu_s", "floor_open_s", "floor_open_cpu_s")


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
    setup,
    one: list[UnitRun],
    one_wall: float,
    many: list[UnitRun] | None,
    many_wall: float | None,
    floors: list[UnitRun],
    workers: int,
    pinned: bool = True,
) -> dict:
    """Print one source's figures (``setup``: its ``benchmarks.units.UnitSetup``; ``one`` / ``many``:
    the runs with 1 and ``workers`` workers; ``floors``: the floor process run right after each of
    ``one``) and return them."""
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
    print(
        f"  per frame ({frames} input frames measured):                {1000 * work / frames:8.1f} ms wall, "
        f"{1000 * work_cpu / frames:8.1f} ms CPU"
    )
    print(
        f"  whole process (+ interpreter start and imports):            {process_wall:8.2f} s wall, "
        f"{process_cpu:8.2f} s CPU"
    )
    print(
        f"  output: {first['clips']} candidate clip(s), {first['clips_written']} written, "
        f"{first['tracks_written']} tracks, {first['clip_frames']} clip frames in all "
        f"({first['clip_frames'] / frames:.1f} per input frame)"
    )
    unit_frames, unit_wall, unit_cpu = frames, work, work_cpu
    if setup.extrapolate_frames:
        # fixed_s: one opening, measured apart; fixed_in_work_s: the openings the repeated runs paid
        fixed, fixed_cpu = first.get("fixed_s", 0.0), first.get("fixed_cpu_s", 0.0)
        # write_unit_s: a release unit's write stage measured apart (ADT): the runs' own is taken out
        per_unit = "write_unit_s" in first
        work_key, cpu_key = ("annotate_s", "annotate_cpu_s") if per_unit else ("work_s", "work_cpu_s")
        per_frame = fmean((r.result[work_key] - r.result.get("fixed_in_work_s", 0.0)) / frames for r in one)
        per_frame_cpu = fmean(
            (r.result[cpu_key] - r.result.get("fixed_in_work_cpu_s", 0.0)) / frames for r in one
        )
        if per_unit:
            fixed += first["write_unit_s"]
            fixed_cpu += first["write_unit_cpu_s"]
        unit_frames = setup.extrapolate_frames
        unit_wall = fixed + unit_frames * per_frame
        unit_cpu = fixed_cpu + unit_frames * per_frame_cpu
        if fixed:
            share = 1000 * first["fixed_s"]
            opening = f"its share of its group's opening and closing of the sequence, {share:.0f} ms"
            if "open_s" in first:
                opening += f" of {1000 * first['open_s']:.0f} ms"
            if per_unit:
                opening += f", + writing a {unit_frames}-frame clip, {1000 * first['write_unit_s']:.0f} ms"
            print(
                f"  per frame without the fixed cost ({opening}): {1000 * per_frame:.1f} ms wall, "
                f"{1000 * per_frame_cpu:.1f} ms CPU"
            )
        print(
            f"  EXTRAPOLATED {unit_frames}-frame unit: {f'{fixed:.2f} + ' if fixed else ''}{unit_frames} x "
            f"{per_frame:.3f} = {unit_wall:.1f} s wall, {unit_cpu:.1f} s CPU"
        )
    if "first_calls_s" in first:
        print(
            f"  numba's first calls, {1000 * first['first_calls_s']:.0f} ms, once per worker process "
            "like the imports: measured before the runs, not counted"
        )
    target = MEMORY_TARGET_GIB.get(source)
    verdict = f"   target <= {target} GiB: {'met' if max_rss <= target else 'MISSED'}" if target else ""
    print(f"  peak memory of the unit's process (max RSS, its VmHWM): {max_rss:.2f} GiB{verdict}")
    # The floor (mean of the runs paired with the unit's), at the measured size, then for the
    # release unit like the unit itself.
    measured = {key: fmean(f.result[key] for f in floors) for key in FLOOR_FIGURES if key in floors[0].result}
    frames_read = floors[0].result["floor_frames"]
    floor_open, floor_open_cpu = measured.get("floor_open_s", 0.0), measured.get("floor_open_cpu_s", 0.0)
    # A unit's share of the opening (ADT: a group of chunks opens and closes its sequence once).
    open_share = floors[0].result.get("floor_open_share", 1.0)
    floor_unit = open_share * floor_open + unit_frames * (measured["floor_s"] - floor_open) / frames_read
    floor_unit_cpu = (
        open_share * floor_open_cpu + unit_frames * (measured["floor_cpu_s"] - floor_open_cpu) / frames_read
    )
    floor_ratio = unit_cpu / floor_unit_cpu
    print(
        f"read+decode floor of the unit's inputs (a fresh process right after each unit's, {where}; mean of "
        f"{len(floors)}): {measured['floor_s']:.2f} s wall, {measured['floor_cpu_s']:.2f} s CPU for "
        f"{frames_read} frames"
        + (f" (opening {floor_open_cpu:.2f} s CPU)" if floor_open else "")
        + f"; peak memory {max(f.max_rss for f in floors) / GIB:.2f} GiB"
    )
    print(
        "  floor / unit work CPU of each pair (s, at the measured size): "
        + ", ".join(
            f"{f.result['floor_cpu_s']:.2f} / {r.result['work_cpu_s']:.2f}"
            for f, r in zip(floors, one, strict=True)
        )
    )
    print(
        f"  {'EXTRAPOLATED ' if setup.extrapolate_frames else ''}{unit_frames}-frame unit: floor "
        f"{floor_unit_cpu:.1f} s CPU, unit {unit_cpu:.1f} s CPU -> unit/floor {floor_ratio:.2f} "
        f"(target <= {FLOOR_RATIO_TARGET}: {'met' if floor_ratio <= FLOOR_RATIO_TARGET else 'MISSED'}; "
        f"in wall time {floor_unit:.1f} s, {unit_wall:.1f} s -> {unit_wall / floor_unit:.2f})"
    )
    runs = one + (many or [])
    cpu_per_wall = min(r.result["work_cpu_s"] / r.result["work_s"] for r in runs)
    speedup = speedup_cpu = None
    if many is not None:
        # Without the waits for a CPU (other processes on the machine): the 1-worker set's CPU
        # time over the N-worker set's CPU time per worker (at least its largest process's).
        per_worker = max(max(r.cpu_s for r in many), sum(r.cpu_s for r in many) / workers)
        speedup_cpu = sum(r.cpu_s for r in one) / per_worker
        speedup = speedup_line(
            f"scaling: the same {len(one)} unit(s)",
            one_wall,
            many_wall,
            workers,
            f"; {os.cpu_count()} CPU(s) here",
        )
        for count, runs_of in ((1, one), (workers, many)):
            print(
                f"  {count} worker(s): each process (wall / CPU, s): "
                + ", ".join(f"{r.wall_s:.1f} / {r.cpu_s:.1f}" for r in runs_of)
                + "; CPU / wall of their unit work: "
                + ", ".join(f"{r.result['work_cpu_s'] / r.result['work_s']:.2f}" for r in runs_of)
            )
        print(
            f"  CPU speed-up (the waits for a CPU taken out: the 1-worker set's CPU time / the "
            f"{workers}-worker set's CPU time per worker, at least its largest process's): {speedup_cpu:.2f}x"
        )
        print(
            f"  peak memory per process with {workers} workers: {max(r.max_rss for r in many) / GIB:.2f} GiB"
            " (CPU / wall below ~0.95: the CPUs were shared with other processes)"
        )
    cpu_hours = unit_cpu * setup.full_units / 3600
    print(
        f"CPU-hours, full benchmark: {setup.full_units} units x {unit_cpu:.1f} s CPU = "
        f"{cpu_hours:.2f} CPU-hours ({setup.full_units_note})"
    )
    for note in setup.notes:
        print(f"  note: {note}")
    return {
        "source": source,
        "size": setup.size,
        "extrapolated": bool(setup.extrapolate_frames),
        "measured_frames": frames,
        "unit_frames": unit_frames,
        "unit_s": unit_wall,
        "unit_cpu_s": unit_cpu,
        "ms_per_frame": 1000 * unit_cpu / unit_frames,
        "ms_per_frame_wall": 1000 * unit_wall / unit_frames,
        "peak_rss_gib": max_rss,
        "speedup": speedup,
        "speedup_cpu": speedup_cpu,
        "full_units": setup.full_units,
        "cpu_hours": cpu_hours,
        "floor_s": floor_unit,
        "floor_cpu_s": floor_unit_cpu,
        "floor_ratio": floor_ratio,
        "floor_ratio_wall": unit_wall / floor_unit,
        "cpu_per_wall": cpu_per_wall,
        "clips_written": first["clips_written"],
        "tracks_written": first["tracks_written"],
        "clip_frames_per_frame": first["clip_frames"] / frames,
        "notes": list(setup.notes),
    }


def _verdict(value, op: str, target) -> bool | None:
    if value is None or target is None:
        return None
    return value <= target if op == "<=" else value >= target


def _targets(source: str) -> dict:
    return {
        "ms_per_frame": MS_PER_FRAME_TARGET.get(source),
        "peak_rss_gib": MEMORY_TARGET_GIB.get(source),
        "speedup": SPEEDUP_TARGET,
        "cpu_hours": None,  # one target for the whole benchmark: the `all` row's
        "floor_ratio": FLOOR_RATIO_TARGET,
        "speedup_cpu": None,  # not judged: an estimate, next to the measured speed-up
        "cpu_per_wall": None,  # not a target: how busy the machine was
    }


def summary_table(figures: list[dict], size: str) -> dict:
    """The table as a JSON-able dict: ``rows`` = one per source (every figure, with
    ``<key>_target`` and ``<key>_pass``, None where there is none) and last the ``all`` row (the
    total CPU-hours; judged against ``CPU_HOURS_TARGET`` only when every source ran). Nothing is
    judged at the quick size (its figures are meaningless): every ``_pass`` is None there."""
    judged = size != "quick"
    rows = []
    for f in figures:
        row = {"source": f["source"], "size": f["size"], "extrapolated": f["extrapolated"]}
        for key, _, _, op, _ in COLUMNS:
            target = _targets(f["source"])[key]
            verdict = _verdict(f[key], op, target) if judged else None
            row.update({key: f[key], f"{key}_target": target, f"{key}_pass": verdict})
        row.update({k: f[k] for k in f if k not in row})
        rows.append(row)
    total = sum(f["cpu_hours"] for f in figures)
    complete = sorted(f["source"] for f in figures) == sorted(SOURCES)
    every = {"source": "all", "size": size, "extrapolated": any(f["extrapolated"] for f in figures)}
    for key, *_ in COLUMNS:
        every.update({key: None, f"{key}_target": None, f"{key}_pass": None})
    every.update(
        {
            "cpu_hours": total,
            "cpu_hours_target": CPU_HOURS_TARGET,
            "cpu_hours_pass": total <= CPU_HOURS_TARGET if complete and judged else None,
            "full_units": sum(f["full_units"] for f in figures),
            "sources": [f["source"] for f in figures],
        }
    )
    rows.append(every)
    return {
        "size": size,
        "columns": ["source", *(key for key, *_ in COLUMNS)],
        "headings": {"source": "source", **{key: heading for key, heading, *_ in COLUMNS}},
        "targets": {
            "ms_per_frame": MS_PER_FRAME_TARGET,
            "peak_rss_gib": MEMORY_TARGET_GIB,
            "speedup": SPEEDUP_TARGET,
            "cpu_hours_all": CPU_HOURS_TARGET,
            "floor_ratio": FLOOR_RATIO_TARGET,
        },
        "rows": rows,
    }


def _cell(row: dict, key: str, form: str, op: str) -> str:
    value = row[key]
    if value is None:
        return "-"
    text = form.format(value) + ("*" if row["extrapolated"] and key in EXTRAPOLATED else "")
    target = row[f"{key}_target"]
    if target is not None:
        verdict = {True: "pass", False: "FAIL", None: "n/a"}[row[f"{key}_pass"]]
        text += f" {op}{target:g} {verdict}"
    return text


def format_table(table: dict) -> list[str]:
    """The table's lines: a heading, one line per source, the `all` line, the footnotes."""
    lines = [f"{'source':<11}" + "".join(f"{heading:<{width}}" for _, heading, *_, width in COLUMNS).rstrip()]
    for row in table["rows"]:
        cells = [(_cell(row, key, form, op), width) for key, _, form, op, width in COLUMNS]
        lines.append(f"{row['source']:<11}" + "".join(f"{cell:<{width}}" for cell, width in cells).rstrip())
    if table["size"] == "quick":
        lines.append("--quick: reduced inputs; the figures only show that the code runs (n/a: not judged)")
    else:
        if table["rows"][-1]["cpu_hours_pass"] is None:
            lines.append("n/a: the total is judged against the benchmark's target when every source ran")
        lines += [
            "ms/frame, CPU-hours, unit/floor: of a release unit (DriveTrack a segment's 3 cameras x 199 "
            "frames, a frame being one camera's; Panoptic Studio 150, ADT 300),",
            "  in time on one core (the CPU time of a single-threaded process bound to one CPU: its wall "
            "time on an idle machine);",
            "  * = extrapolated from a shorter measured input (fixed cost + frames x per-frame cost);",
            "  peak RSS: measured, at the size benched; CPU/wall: the lowest of the unit processes' (below "
            "~0.95 the machine",
            "  was busy: wall times, hence the speed-up, were stretched by other processes); (CPU): the "
            "speed-up with the waits",
            "  for a CPU taken out (the 1-worker set's CPU time / the N-worker set's CPU time per worker, "
            "at least its largest process's; not judged)",
        ]
    return lines


def write_json(table: dict, path: str, extra: dict) -> None:
    """``table`` (``summary_table``) and ``extra`` (machine, command) as JSON at ``path``."""
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    with open(path, "w") as f:
        json.dump({**extra, **table}, f, indent=1)
        f.write("\n")
