"""The one table of every benchmarked source against its targets (``python -m benchmarks``), its
lines and its JSON.

Targets: a source's own (ms per input frame on one core, peak memory of the unit's process) are its
entry's ``TARGETS``; the others are every source's: the speed-up from 1 to 2 workers (of the unit
processes, and with ``--beam`` of the whole ``pipeline.run`` command through Beam), a unit's time
over its read+decode floor, and the whole benchmark's CPU-hours (the ``all`` row's).
"""

from __future__ import annotations

import json
import os

from benchmarks.entry import entry
from pipeline import sources

SPEEDUP_TARGET = 1.8
FLOOR_RATIO_TARGET = 2.0
CPU_HOURS_TARGET = 15.0
# What the release under its rules is to cost in all, in time: printed with the gap to it, not judged.
CPU_HOURS_GOAL = 6.0
OWN_TARGETS = ("ms_per_frame", "peak_rss_gib")  # the columns each entry's TARGETS may judge

# The table's figure columns: key, heading, format, target comparison, width.
COLUMNS = (
    ("ms_per_frame", "ms/frame", "{:.1f}", "<=", 19),
    ("peak_rss_gib", "peak RSS GiB", "{:.2f}", "<=", 17),
    ("speedup", "speed-up", "{:.2f}x", ">=", 17),
    ("speedup_cpu", "(CPU)", "{:.2f}x", None, 8),
    ("beam_speedup", "Beam", "{:.2f}x", ">=", 17),
    ("cpu_hours", "CPU-hours", "{:.2f}", "<=", 18),
    ("floor_ratio", "unit/floor", "{:.2f}", "<=", 16),
    ("cpu_per_wall", "CPU/wall", "{:.2f}", None, 8),
)
EXTRAPOLATED = ("ms_per_frame", "cpu_hours", "floor_ratio")


def targets(source: str) -> dict:
    """Each column's target for ``source``; None where it is not judged."""
    own = entry(source).TARGETS
    return {key: own.get(key) for key in OWN_TARGETS} | {
        "speedup": SPEEDUP_TARGET,
        "beam_speedup": SPEEDUP_TARGET,
        "cpu_hours": None,  # one target for the whole benchmark: the `all` row's
        "floor_ratio": FLOOR_RATIO_TARGET,
        "speedup_cpu": None,  # not judged: an estimate, next to the measured speed-up
        "cpu_per_wall": None,  # not a target: how busy the machine was
    }


def _verdict(value, op: str, target) -> bool | None:
    if value is None or target is None:
        return None
    return value <= target if op == "<=" else value >= target


def _source_row(figures: dict, judged: bool) -> dict:
    """One source's row: its figures, each column with ``<key>_target`` and ``<key>_pass``."""
    row = {"source": figures["source"], "size": figures["size"], "extrapolated": figures["extrapolated"]}
    goals = targets(figures["source"])
    for key, _, _, op, _ in COLUMNS:
        verdict = _verdict(figures[key], op, goals[key]) if judged else None
        row.update({key: figures[key], f"{key}_target": goals[key], f"{key}_pass": verdict})
    row.update({k: figures[k] for k in figures if k not in row})
    return row


def _all_row(figures: list[dict], size: str, judged: bool) -> dict:
    """The ``all`` row: the total CPU-hours, judged when every registered source ran."""
    total = sum(f["cpu_hours"] for f in figures)
    complete = sorted(f["source"] for f in figures) == sorted(sources.names())
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
            "cpu_hours_goal": CPU_HOURS_GOAL,
            "cpu_hours_gap": total - CPU_HOURS_GOAL,
        }
    )
    return every


def summary_table(figures: list[dict], size: str) -> dict:
    """The table as a JSON-able dict: ``rows`` = one per source (every figure, with
    ``<key>_target`` and ``<key>_pass``, None where there is none) and last the ``all`` row (the
    total CPU-hours; judged against ``CPU_HOURS_TARGET`` only when every source ran). Nothing is
    judged at the quick size (its figures are meaningless): every ``_pass`` is None there."""
    judged = size != "quick"
    own = {
        key: {f["source"]: goal for f in figures if (goal := targets(f["source"])[key]) is not None}
        for key in OWN_TARGETS
    }
    return {
        "size": size,
        "columns": ["source", *(key for key, *_ in COLUMNS)],
        "headings": {"source": "source", **{key: heading for key, heading, *_ in COLUMNS}},
        "targets": {
            **own,
            "speedup": SPEEDUP_TARGET,
            "beam_speedup": SPEEDUP_TARGET,
            "cpu_hours_all": CPU_HOURS_TARGET,
            "floor_ratio": FLOOR_RATIO_TARGET,
        },
        "rows": [*(_source_row(f, judged) for f in figures), _all_row(figures, size, judged)],
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
        return lines
    every = table["rows"][-1]
    if every["cpu_hours_pass"] is None:
        lines.append("n/a: the total is judged against the benchmark's target when every source ran")
    else:
        lines.append(
            f"the release under its rules: {every['cpu_hours']:.2f} CPU-hours in all, "
            f"{every['cpu_hours_gap']:+.2f} from the goal of {every['cpu_hours_goal']:g}"
        )
    units = ", ".join(f"{row['source']} {row['unit_frames']}" for row in table["rows"][:-1])
    return lines + [
        f"ms/frame, CPU-hours, unit/floor: of a release unit ({units} frames, a frame being one camera's),",
        "  in time on one core (the CPU time of a single-threaded process bound to one CPU: its wall "
        "time on an idle machine);",
        "  * = extrapolated from a shorter measured input (fixed cost + frames x per-frame cost);",
        "  peak RSS: measured, at the size benched; CPU/wall: the lowest of the unit processes' (below "
        "~0.95 the machine",
        "  was busy: wall times, hence the speed-up, were stretched by other processes); (CPU): the "
        "speed-up with the waits",
        "  for a CPU taken out (the 1-worker set's CPU time / the N-worker set's CPU time per worker, "
        "at least its largest process's; not judged);",
        "  Beam (--beam): the speed-up of the whole python -m pipeline.run command on Beam's DirectRunner, "
        "its start and finish included",
    ]


def write_json(table: dict, path: str, extra: dict) -> None:
    """``table`` (``summary_table``) and ``extra`` (machine, command) as JSON at ``path``."""
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    with open(path, "w") as f:
        json.dump({**extra, **table}, f, indent=1)
        f.write("\n")
