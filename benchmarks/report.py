"""The figures of one source's per-unit benchmark: computed from its runs (``figures``), printed
(``print_figures``), and the table's share of them returned (``report``).

Figures of a release unit (``unit_frames`` frames): ms/frame = its time on one core / its
frames; CPU-hours = that time x the release's units; unit/floor = that time / the same for the
bare reading and decoding of its inputs (the entry's ``floor``). Where the measured input is
shorter than a release unit (ADT's 2-frame excerpt; DriveTrack and Panoptic Studio at the default
size), the unit is extrapolated: fixed cost (ADT: opening and closing the sequence, measured
apart) + frames x the measured per-frame cost, and its floor likewise; such figures carry ``*``.
Peak memory (max RSS) is always the measured process's, at the size benched.

"Time on one core" is the CPU time of the single-threaded process bound to one CPU: on an idle
machine it equals its wall time; on a busy one the wall time also counts the waits for that CPU
(the ``CPU/wall`` column: below ~0.95 the machine was busy, and the speed-up, a ratio of wall
times, is not to be trusted). The wall-time figures are in the JSON too (``*_wall``).

Per rule set (``peak_rss_gib_by_rules``): the peak memory of the unit's process under its own rule
set and under each variant's that ``UnitSetup.rule_sets`` names. With ``--beam``: the groups'
``pipeline.run`` command's wall time with 1 and N workers (``beam_wall_s``, by worker count), its
speed-up (``beam_speedup``) and its serial start (``beam_serial_s``, ``benchmarks.beam``).
"""

from __future__ import annotations

import dataclasses
import os
from statistics import fmean

from benchmarks.beam import BeamRuns
from benchmarks.processes import UnitRun
from benchmarks.table import SPEEDUP_TARGET, targets
from pipeline.core.benchmark import UnitSetup

GIB = 1024**3
# A floor process's timed figures (the entry's ``floor``), averaged over the floor runs.
FLOOR_FIGURES = ("floor_s", "floor_cpu_s", "floor_open_s", "floor_open_cpu_s")
# The figures ``report`` returns: the table's row of the source.
ROW = (
    "source",
    "size",
    "extrapolated",
    "measured_frames",
    "unit_frames",
    "unit_s",
    "unit_cpu_s",
    "ms_per_frame",
    "ms_per_frame_wall",
    "peak_rss_gib",
    "peak_rss_gib_by_rules",
    "speedup",
    "speedup_cpu",
    "full_units",
    "cpu_hours",
    "clips_per_cpu_hour",
    "floor_s",
    "floor_cpu_s",
    "floor_ratio",
    "floor_ratio_wall",
    "cpu_per_wall",
    "clips_written",
    "tracks_written",
    "clip_frames_per_frame",
    "beam_groups",
    "beam_wall_s",
    "beam_speedup",
    "beam_serial_s",
    "notes",
)


@dataclasses.dataclass
class Runs:
    """What one source's benchmark ran: ``one``, the units with 1 worker (``one_wall`` seconds in
    all), each followed by its floor process (``floors``); ``many``, the same units with
    ``workers`` workers (``many_wall`` seconds; None: not run); ``pinned``: each process bound to a
    CPU of its own; ``variants``: name -> the units run with that variant's settings
    (``UnitSetup.variants``), each right after its unit's floor; ``beam``: the source's groups
    through ``pipeline.run`` (None: not run)."""

    one: list[UnitRun]
    one_wall: float
    floors: list[UnitRun]
    many: list[UnitRun] | None
    many_wall: float | None
    workers: int
    pinned: bool
    variants: dict[str, list[UnitRun]] = dataclasses.field(default_factory=dict)
    beam: BeamRuns | None = None


def report(setup: UnitSetup, runs: Runs) -> dict:
    """Print the figures of ``setup``'s benchmark; return its row of the table (``ROW``)."""
    every = figures(setup, runs)
    print_figures(setup, runs, every)
    return {key: every[key] for key in ROW}


def figures(setup: UnitSetup, runs: Runs) -> dict:
    """Every figure of one source's benchmark: the unit as measured, the release unit (measured, or
    extrapolated), its floor, the scaling and the CPU-hours."""
    measured = _measured(setup, runs.one)
    unit = _release_unit(setup, runs.one, measured)
    return {
        "source": setup.source,
        "size": setup.size,
        "extrapolated": bool(setup.extrapolate_frames),
        **measured,
        **unit,
        "ms_per_frame": 1000 * unit["unit_cpu_s"] / unit["unit_frames"],
        "ms_per_frame_wall": 1000 * unit["unit_s"] / unit["unit_frames"],
        "peak_rss_gib_by_rules": peaks_by_rules(setup, runs),
        **_floor(runs.floors, unit),
        **_scaling(runs),
        **_beam(runs.beam),
        "full_units": setup.full_units,
        "cpu_hours": unit["unit_cpu_s"] * setup.full_units / 3600,
        "clips_per_cpu_hour": setup.full_clips * 3600 / (unit["unit_cpu_s"] * setup.full_units)
        if setup.full_clips
        else None,
        "notes": list(setup.notes),
    }


def _measured(setup: UnitSetup, one: list[UnitRun]) -> dict:
    """The unit at the size benched: means of the 1-worker runs, the first run's output."""
    first = one[0].result
    return {
        "measured_frames": setup.frames,
        "work_s": fmean(r.result["work_s"] for r in one),
        "work_cpu_s": fmean(r.result["work_cpu_s"] for r in one),
        "annotate_s": fmean(r.result["annotate_s"] for r in one),
        "process_s": fmean(r.wall_s for r in one),
        "process_cpu_s": fmean(r.cpu_s for r in one),
        "peak_rss_gib": max(r.max_rss for r in one) / GIB,
        "clips_written": first["clips_written"],
        "tracks_written": first["tracks_written"],
        "clip_frames_per_frame": first["clip_frames"] / setup.frames,
    }


def peaks_by_rules(setup: UnitSetup, runs: Runs) -> dict[str, float]:
    """Rule set -> the peak memory (GiB) of the unit's processes under it: the unit's own rule set
    (its ``overrides``', as the worker reads them) and each of ``UnitSetup.rule_sets``."""
    from pipeline.settings.fields import with_overrides
    from pipeline.settings.run_config import RunConfig

    own = with_overrides(RunConfig(), setup.overrides).rules
    under = {own: runs.one, **{rules: runs.variants[name] for rules, name in setup.rule_sets.items()}}
    return {rules: max(run.max_rss for run in runs_of) / GIB for rules, runs_of in under.items()}


def _release_unit(setup: UnitSetup, one: list[UnitRun], measured: dict) -> dict:
    """The release's unit: the measured one, or fixed cost + ``extrapolate_frames`` x the measured
    per-frame cost (unit_frames, unit_s / unit_cpu_s, and fixed_s / fixed_cpu_s, per_frame_s /
    per_frame_cpu_s)."""
    frames = setup.frames
    if not setup.extrapolate_frames:
        return {"unit_frames": frames, "unit_s": measured["work_s"], "unit_cpu_s": measured["work_cpu_s"]}
    first = one[0].result
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
    return {
        "unit_frames": unit_frames,
        "unit_s": fixed + unit_frames * per_frame,
        "unit_cpu_s": fixed_cpu + unit_frames * per_frame_cpu,
        "fixed_s": fixed,
        "fixed_cpu_s": fixed_cpu,
        "per_frame_s": per_frame,
        "per_frame_cpu_s": per_frame_cpu,
    }


def _floor(floors: list[UnitRun], unit: dict) -> dict:
    """The floor: the mean of the runs paired with the unit's, at the measured size, then for the
    release unit like the unit itself."""
    measured = {key: fmean(f.result[key] for f in floors) for key in FLOOR_FIGURES if key in floors[0].result}
    frames_read = floors[0].result["floor_frames"]
    floor_open, floor_open_cpu = measured.get("floor_open_s", 0.0), measured.get("floor_open_cpu_s", 0.0)
    # A unit's share of the opening (ADT: a group of chunks opens and closes its sequence once).
    open_share = floors[0].result.get("floor_open_share", 1.0)
    frames = unit["unit_frames"]
    floor_unit = open_share * floor_open + frames * (measured["floor_s"] - floor_open) / frames_read
    floor_unit_cpu = (
        open_share * floor_open_cpu + frames * (measured["floor_cpu_s"] - floor_open_cpu) / frames_read
    )
    return {
        "floor_measured_s": measured["floor_s"],
        "floor_measured_cpu_s": measured["floor_cpu_s"],
        "floor_open_s": floor_open,
        "floor_open_cpu_s": floor_open_cpu,
        "floor_frames": frames_read,
        "floor_peak_rss_gib": max(f.max_rss for f in floors) / GIB,
        "floor_s": floor_unit,
        "floor_cpu_s": floor_unit_cpu,
        "floor_ratio": unit["unit_cpu_s"] / floor_unit_cpu,
        "floor_ratio_wall": unit["unit_s"] / floor_unit,
    }


def _scaling(runs: Runs) -> dict:
    """cpu_per_wall (the lowest of every unit process's), and with ``many``: the speed-up from 1 to
    ``workers`` workers in wall time, and without the waits for a CPU (other processes on the
    machine): the 1-worker set's CPU time over the N-worker set's CPU time per worker (at least
    its largest process's)."""
    every = runs.one + (runs.many or [])
    scaling = {
        "cpu_per_wall": min(r.result["work_cpu_s"] / r.result["work_s"] for r in every),
        "speedup": None,
        "speedup_cpu": None,
    }
    if runs.many is not None:
        per_worker = max(max(r.cpu_s for r in runs.many), sum(r.cpu_s for r in runs.many) / runs.workers)
        scaling["speedup"] = runs.one_wall / runs.many_wall
        scaling["speedup_cpu"] = sum(r.cpu_s for r in runs.one) / per_worker
    return scaling


def _beam(beam: BeamRuns | None) -> dict:
    """The groups through ``pipeline.run``: their count, the command's wall time and serial start
    by worker count, and its speed-up; None each without ``--beam``."""
    if beam is None:
        return dict.fromkeys(("beam_groups", "beam_wall_s", "beam_speedup", "beam_serial_s"))
    runs = (beam.one, beam.many)
    return {
        "beam_groups": beam.groups,
        "beam_wall_s": {str(run.workers): run.wall_s for run in runs},
        "beam_speedup": beam.one.wall_s / beam.many.wall_s,
        "beam_serial_s": {str(run.workers): run.serial_s for run in runs},
    }


def print_speedup(what: str, one_wall: float, many_wall: float, workers: int, tail: str = "") -> None:
    """Print the 1-vs-``workers`` line with its verdict against ``SPEEDUP_TARGET``."""
    speedup = one_wall / many_wall
    status = "met" if speedup >= SPEEDUP_TARGET else "MISSED"
    print(
        f"{what}: 1 worker {one_wall:.1f} s, {workers} workers {many_wall:.1f} s -> speed-up "
        f"{speedup:.2f}x (target >= {SPEEDUP_TARGET}x: {status}{tail})"
    )


def print_figures(setup: UnitSetup, runs: Runs, f: dict) -> None:
    """Print ``figures``' ``f``: the unit, its floor, the scaling, the CPU-hours."""
    where = "one thread, bound to one CPU" if runs.pinned else "one thread"
    _print_unit(setup, runs.one, f, where)
    _print_variants(setup, runs)
    _print_floor(setup, runs, f, where)
    if runs.many is not None:
        _print_scaling(runs, f)
    if runs.beam is not None:
        _print_beam(runs.beam)
    print(
        f"CPU-hours, full benchmark: {setup.full_units} units x {f['unit_cpu_s']:.1f} s CPU = "
        f"{f['cpu_hours']:.2f} CPU-hours ({setup.full_units_note})"
    )
    if f["clips_per_cpu_hour"] is not None:
        print(f"clips per CPU-hour: {f['clips_per_cpu_hour']:.0f} ({setup.full_clips} clips in those units)")
    for note in setup.notes:
        print(f"  note: {note}")


def _print_unit(setup: UnitSetup, one: list[UnitRun], f: dict, where: str) -> None:
    work, work_cpu, annotate, frames = f["work_s"], f["work_cpu_s"], f["annotate_s"], setup.frames
    first = one[0].result
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
        f"  whole process (+ interpreter start and imports):            {f['process_s']:8.2f} s wall, "
        f"{f['process_cpu_s']:8.2f} s CPU"
    )
    print(
        f"  output: {first['clips']} candidate clip(s), {first['clips_written']} written, "
        f"{first['tracks_written']} tracks, {first['clip_frames']} clip frames in all "
        f"({first['clip_frames'] / frames:.1f} per input frame)"
    )
    if setup.extrapolate_frames:
        _print_extrapolation(first, f)
    if "first_unit_extra_cpu_s" in first:
        print(
            f"  the first unit of each process, {first['first_unit_cpu_s']:.2f} s CPU "
            f"({_first_unit_extra(one):+.2f} s over the timed run's: imports on first use, numba's cache "
            "loads), run before the timed runs, not counted"
        )
    if "first_calls_s" in first:
        print(
            f"  numba's first calls, {1000 * first['first_calls_s']:.0f} ms, once per worker process "
            "like the imports: measured before the runs, not counted"
        )
    target = targets(setup.source)["peak_rss_gib"]
    max_rss = f["peak_rss_gib"]
    verdict = f"   target <= {target} GiB: {'met' if max_rss <= target else 'MISSED'}" if target else ""
    print(f"  peak memory of the unit's process (max RSS, its VmHWM): {max_rss:.2f} GiB{verdict}")


def _first_unit_extra(runs: list[UnitRun]) -> float:
    """Mean CPU seconds a process's first (warm-up) unit took over a timed run."""
    return fmean(run.result["first_unit_extra_cpu_s"] for run in runs)


def _print_variants(setup: UnitSetup, runs: Runs) -> None:
    """Each variant's unit work beside the unit's: means of the 1-worker runs, and the ratio of each
    variant run's CPU time to its own unit run's (run close together: the same state of a shared
    machine)."""
    for name, variant_runs in runs.variants.items():
        work = fmean(run.result["work_s"] for run in variant_runs)
        cpu = fmean(run.result["work_cpu_s"] for run in variant_runs)
        pairs = [
            variant.result["work_cpu_s"] / run.result["work_cpu_s"]
            for variant, run in zip(variant_runs, runs.one, strict=True)
        ]
        print(
            f"  with {name} ({' '.join(setup.variants[name])}): unit work {work:8.2f} s wall, {cpu:8.2f} s "
            f"CPU = {fmean(pairs):.2f} x the unit's CPU (each run over its unit's: "
            f"{', '.join(f'{ratio:.2f}' for ratio in pairs)}); peak memory "
            f"{max(run.max_rss for run in variant_runs) / GIB:.2f} GiB"
            + (
                f"; its first unit {_first_unit_extra(variant_runs):+.2f} s CPU, not counted"
                if "first_unit_extra_cpu_s" in variant_runs[0].result
                else ""
            )
        )


def _print_extrapolation(first: dict, f: dict) -> None:
    """The per-frame cost without the fixed cost, and the release unit made of them."""
    fixed, unit_frames = f["fixed_s"], f["unit_frames"]
    if fixed:
        opening = (
            f"its share of its group's opening and closing of the sequence, {1000 * first['fixed_s']:.0f} ms"
        )
        if "open_s" in first:
            opening += f" of {1000 * first['open_s']:.0f} ms"
        if "write_unit_s" in first:
            opening += f", + writing a {unit_frames}-frame clip, {1000 * first['write_unit_s']:.0f} ms"
        print(
            f"  per frame without the fixed cost ({opening}): {1000 * f['per_frame_s']:.1f} ms wall, "
            f"{1000 * f['per_frame_cpu_s']:.1f} ms CPU"
        )
    print(
        f"  EXTRAPOLATED {unit_frames}-frame unit: {f'{fixed:.2f} + ' if fixed else ''}{unit_frames} x "
        f"{f['per_frame_s']:.3f} = {f['unit_s']:.1f} s wall, {f['unit_cpu_s']:.1f} s CPU"
    )


def _print_floor(setup: UnitSetup, runs: Runs, f: dict, where: str) -> None:
    target = targets(setup.source)["floor_ratio"]
    print(
        f"read+decode floor of the unit's inputs (a fresh process right after each unit's, {where}; mean of "
        f"{len(runs.floors)}): {f['floor_measured_s']:.2f} s wall, {f['floor_measured_cpu_s']:.2f} s CPU for "
        f"{f['floor_frames']} frames"
        + (f" (opening {f['floor_open_cpu_s']:.2f} s CPU)" if f["floor_open_s"] else "")
        + f"; peak memory {f['floor_peak_rss_gib']:.2f} GiB"
    )
    print(
        "  floor / unit work CPU of each pair (s, at the measured size): "
        + ", ".join(
            f"{floor.result['floor_cpu_s']:.2f} / {run.result['work_cpu_s']:.2f}"
            for floor, run in zip(runs.floors, runs.one, strict=True)
        )
    )
    print(
        f"  {'EXTRAPOLATED ' if setup.extrapolate_frames else ''}{f['unit_frames']}-frame unit: floor "
        f"{f['floor_cpu_s']:.1f} s CPU, unit {f['unit_cpu_s']:.1f} s CPU -> unit/floor "
        f"{f['floor_ratio']:.2f} "
        f"(target <= {target}: {'met' if f['floor_ratio'] <= target else 'MISSED'}; "
        f"in wall time {f['floor_s']:.1f} s, {f['unit_s']:.1f} s -> {f['floor_ratio_wall']:.2f})"
    )


def _print_scaling(runs: Runs, f: dict) -> None:
    workers = runs.workers
    print_speedup(
        f"scaling: the same {len(runs.one)} unit(s)",
        runs.one_wall,
        runs.many_wall,
        workers,
        f"; {os.cpu_count()} CPU(s) here",
    )
    for count, runs_of in ((1, runs.one), (workers, runs.many)):
        print(
            f"  {count} worker(s): each process (wall / CPU, s): "
            + ", ".join(f"{r.wall_s:.1f} / {r.cpu_s:.1f}" for r in runs_of)
            + "; CPU / wall of their unit work: "
            + ", ".join(f"{r.result['work_cpu_s'] / r.result['work_s']:.2f}" for r in runs_of)
        )
    print(
        f"  CPU speed-up (the waits for a CPU taken out: the 1-worker set's CPU time / the "
        f"{workers}-worker set's CPU time per worker, at least its largest process's): "
        f"{f['speedup_cpu']:.2f}x"
    )
    print(
        f"  peak memory per process with {workers} workers: {max(r.max_rss for r in runs.many) / GIB:.2f} GiB"
        " (CPU / wall below ~0.95: the CPUs were shared with other processes)"
    )


def _print_beam(beam: BeamRuns) -> None:
    """The ``pipeline.run`` command's speed-up, and the serial start of each run."""
    one, many = beam.one, beam.many
    print_speedup(
        f"through Beam: {beam.groups} groups ({one.units} units) by python -m pipeline.run on the "
        "DirectRunner (multi_processing), the whole command",
        one.wall_s,
        many.wall_s,
        many.workers,
    )
    print(
        "  serial start (the command's start to its first unit's start + its last unit's end to the "
        "command's end; each unit's start and end from its checkpoint: written as it ends, it records "
        "the seconds the unit took): "
        + ", ".join(
            f"{run.workers} worker(s) {run.start_s:.1f} + {run.end_s:.1f} = {run.serial_s:.1f} s"
            for run in (one, many)
        )
    )
