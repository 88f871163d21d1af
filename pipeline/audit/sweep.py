"""``python -m pipeline.audit sweep OUT --source S --grid KEY=V1,V2``: replay the filter stage at
other thresholds.

The filter stage records every candidate track's statistics in ``OUT/audit/<source>/*.parquet`` (one
table per clip). The sweep reads them and evaluates every combination of the ``--grid`` thresholds
with the filter stage's own rule (``verdicts_from_stats``), without annotating again. It writes, into
``--out`` (default ``OUT/sweep_<source>``), together (``pipeline.io.file_set``: all new, or all as
they were), ``report.md`` (a table per combination, statistic summaries), ``sweep.parquet`` (the same
table) and two PNGs: the survival curve of each filter and the histogram of each statistic. A folder
holding no run of the source is refused, unless ``--run-sample`` asks to run the pipeline on the
source's sample world into it first.

On a release run (``--release``, or the run's own), only the release's clips are replayed, and each
combination also counts, per split, the release clips that survive it: written, with at least
``min_tracks`` tracks passing the filters. A release clip the run could not make (its input absent,
its unit failed, no clip of its name) survives no threshold.
"""

from __future__ import annotations

import argparse
import dataclasses
import io
import itertools
import json
import os
import sys
from collections.abc import Iterable, Mapping

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from pipeline import sources
from pipeline.commandline import StrictParser, closest
from pipeline.core.errors import InputError
from pipeline.core.outcomes import FILTER_ORDER
from pipeline.export.layout import audit_path, provenance_path, sweep_folder
from pipeline.filters.select import FILTERED_BY, FilterStats, count_dropped, verdicts_from_stats
from pipeline.io.file_set import complete_commits, reclaim_temporaries, write_together
from pipeline.io.files import list_files, read_bytes
from pipeline.runner.splits import SPLITS, Release, read_release
from pipeline.settings.fields import (
    SettingsError,
    add_set_argument,
    config_from_dict,
    setting_keys,
    value_at,
    with_overrides,
)
from pipeline.settings.run_config import RunConfig
from pipeline.sources import Source


def sweepable(source: Source) -> tuple[str, ...]:
    """The config keys a sweep may vary for ``source``: the filter stage's thresholds only."""
    return ("flicker.max_fraction", "min_tracks", *source.sweepable)


# An audit table's columns that are not statistics.
NOT_STATISTICS = ("source", "clip", "num_frames", "target_tracks", "candidate", "output_index")


@dataclasses.dataclass(frozen=True)
class AuditTable:
    """One clip's audit table as the audit reads it: the clip, its frames, its target track count
    and its candidates' statistics."""

    clip: str
    num_frames: int
    target_tracks: int
    stats: FilterStats


def read_audit_table(path: str, columns: tuple[str, ...] | None = None) -> AuditTable:
    """One clip's audit table, with every statistic, or the filters' and those of ``columns``;
    ValueError naming the file when it is unreadable or lacks the columns the filters read."""
    try:
        names = pq.read_schema(path).names
        chosen = (*NOT_STATISTICS, *FILTERED_BY, *(columns or ()))
        wanted = names if columns is None else [name for name in chosen if name in names]
        table = pq.read_table(path, columns=wanted)
    except (pa.ArrowException, OSError) as error:
        raise ValueError(f"audit table {path} is unreadable ({error})") from error
    missing = {"clip", "num_frames", "target_tracks", "visible_frames", "visibility_flips"} - set(
        table.column_names
    )
    if missing:
        raise ValueError(f"audit table {path} lacks column(s) {sorted(missing)}")
    found = {name: table.column(name).to_numpy(zero_copy_only=False) for name in table.column_names}
    rows = len(found["clip"])
    stats = {
        name: values
        for name, values in found.items()
        if not name.startswith("pass_") and name not in NOT_STATISTICS
    }
    return AuditTable(
        str(found["clip"][0]) if rows else os.path.basename(path)[: -len(".parquet")],
        int(found["num_frames"][0]) if rows else 0,
        int(found["target_tracks"][0]) if rows else 0,
        FilterStats.from_columns(stats),
    )


def load_statistics(output: str, source: str) -> list[AuditTable]:
    """Per clip of ``source`` in ``output``: its audit table (``read_audit_table``)."""
    return [read_audit_table(path) for path in list_files(audit_path(output, source, "*"))]


@dataclasses.dataclass(frozen=True)
class ClipCount:
    """One clip replayed at some thresholds: its candidates, the tracks each filter drops (each
    against the first that rejects it), the tracks passing every filter and its target."""

    clip: str
    candidates: int
    dropped: Mapping[str, int]
    passed: int
    target_tracks: int


@dataclasses.dataclass(frozen=True)
class Totals:
    """The filter stage's totals over clips: candidates, the tracks each filter drops (``FILTER_ORDER``
    -> count), those passing every filter, the clips written (at least ``min_tracks`` passing), those
    below their target track count, the tracks written (at most the target per clip) and, on a
    release run, the release clips written per split (None otherwise)."""

    candidates: int
    dropped: Mapping[str, int]
    passed: int
    clips_written: int
    clips_below_target: int
    tracks_written: int
    release: Mapping[str, int] | None = None


def totals(counts: Iterable[ClipCount], min_tracks: int, splits: dict[str, str] | None = None) -> Totals:
    """The ``Totals`` of ``counts``, written clips per split with the release's ``splits`` (clip ->
    split)."""
    dropped = dict.fromkeys(FILTER_ORDER, 0)
    candidates = passed = written = below = tracks_written = 0
    release = dict.fromkeys(SPLITS, 0)
    for count in counts:
        for name in FILTER_ORDER:
            dropped[name] += count.dropped[name]
        candidates += count.candidates
        passed += count.passed
        kept = count.passed >= min_tracks
        written += kept
        below += kept and count.passed < count.target_tracks
        tracks_written += min(count.passed, count.target_tracks) if kept else 0
        if splits is not None and kept and count.clip in splits:
            release[splits[count.clip]] += 1
    return Totals(
        candidates, dropped, passed, written, below, tracks_written, release if splits is not None else None
    )


def evaluate(
    clips: list[AuditTable], source: Source, config: RunConfig, splits: dict[str, str] | None = None
) -> Totals:
    """The filter stage's totals at ``config``, replayed from the recorded statistics."""

    def replayed(clip: AuditTable) -> ClipCount:
        verdicts = verdicts_from_stats(clip.stats, clip.num_frames, config, source.mask_min_agreement(config))
        survivors = int(np.logical_and.reduce([verdicts[name] for name in FILTER_ORDER]).sum())
        return ClipCount(clip.clip, clip.stats.count, count_dropped(verdicts), survivors, clip.target_tracks)

    return totals(map(replayed, clips), config.min_tracks, splits)


def parse_grid(assignments: list[str], source: Source, base: RunConfig) -> dict[str, list[str]]:
    """``key=v1,v2`` -> {key: [v1, v2]}; only thresholds the filter stage reads can be swept, each
    value checked as ``--set`` checks it. SettingsError lists every problem."""
    grid, problems = {}, []
    for assignment in assignments:
        key, sep, values = assignment.partition("=")
        key = key.strip()
        if not sep or not values.strip(","):
            problems.append(f"--grid {assignment!r}: expected key=v1,v2,...")
        elif key not in setting_keys(base):
            near = closest(key, sweepable(source))
            hint = f"did you mean {near}? " if near else ""
            problems.append(
                f"--grid {key}: unknown key; {hint}the keys a sweep varies: {', '.join(sweepable(source))}"
            )
        elif key not in sweepable(source):
            problems.append(
                f"--grid {key}: the sweep replays the filter stage only ({', '.join(sweepable(source))}); "
                "a setting that changes annotation needs a new run (python -m pipeline.run --set ...)"
            )
        else:
            grid[key] = [v.strip() for v in values.split(",") if v.strip()]
            for value in grid[key]:
                try:
                    with_overrides(base, [f"{key}={value}"], option="--grid")
                except SettingsError as error:
                    problems += error.problems
    if problems:
        raise SettingsError(problems)
    return grid


def _pyplot():
    """matplotlib's pyplot on the file-only Agg backend (imported when a figure is drawn)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def png_bytes(figure) -> bytes:
    """A matplotlib figure as PNG bytes (the figure closed)."""
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=110)
    _pyplot().close(figure)
    return buffer.getvalue()


def survival_figure(clips: list[AuditTable], source: Source, config: RunConfig) -> bytes:
    """Share of candidates each filter keeps as its threshold varies (default marked), as a PNG."""
    plt = _pyplot()
    flips = np.concatenate([c.stats.visibility_flips / max(c.num_frames, 1) for c in clips])
    figure, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    grid = np.linspace(0, 0.5, 201)
    axes[0].plot(grid, [(flips <= g + 1e-12).mean() for g in grid])
    axes[0].axvline(config.flicker.max_fraction, color="k", linestyle="--", label="default")
    axes[0].set(xlabel="flicker.max_fraction (flips / T)", ylabel="share of candidates kept", title="flicker")
    agreement = [c.stats.mask_agreement for c in clips if c.stats.mask_agreement is not None]
    if agreement:
        score = np.concatenate(agreement).astype(np.float64)
        grid = np.linspace(0, 1, 201)
        axes[1].plot(grid, [(np.isnan(score) | (score >= g)).mean() for g in grid])
        axes[1].axvline(source.mask_min_agreement(config), color="k", linestyle="--", label="default")
    axes[1].set(xlabel=f"{source.name}.mask_min_agreement", ylabel="share of candidates kept", title="mask")
    for ax in axes:
        ax.set_ylim(0, 1.02)
        ax.grid(alpha=0.3)
        ax.legend()
    figure.suptitle(f"{source.name}: survival per filter ({sum(c.stats.count for c in clips)} candidates)")
    figure.tight_layout()
    return png_bytes(figure)


def histogram_figure(statistics: dict[str, np.ndarray], source: str) -> bytes:
    """One histogram per statistic [N] over all candidates, as a PNG."""
    plt = _pyplot()
    names = sorted(statistics)
    figure, axes = plt.subplots(1, len(names), figsize=(3.6 * len(names), 3.2), squeeze=False)
    for ax, name in zip(axes[0], names, strict=True):
        values = statistics[name][np.isfinite(statistics[name])]
        ax.hist(values, bins=40, color="tab:blue")
        ax.set(title=name, ylabel="candidate tracks")
    figure.suptitle(f"{source}: statistics of all candidate tracks")
    figure.tight_layout()
    return png_bytes(figure)


def numeric_statistics(clips: list[AuditTable]) -> dict[str, np.ndarray]:
    """Every numeric statistic over all candidates, flips as a fraction of T."""
    columns = [c.stats.columns() for c in clips]
    names = sorted(set.intersection(*(set(named) for named in columns)))
    result = {}
    for name in names:
        parts = [np.asarray(named[name]) for named in columns]
        if all(p.dtype.kind in "fiu" for p in parts) and name not in ("gaussian_index", "object_id"):
            result[name] = np.concatenate(parts).astype(np.float64)
    result["flip_fraction"] = np.concatenate([c.stats.visibility_flips / max(c.num_frames, 1) for c in clips])
    return result


@dataclasses.dataclass(frozen=True)
class SweepRow:
    """One combination of thresholds: config key -> value (as given; the run's own as text), its
    totals, where it comes from (``run``: the run's own thresholds; ``grid``; ``run = grid``: the
    run's own, which the grid also names) and, on the run's own row when the run left its summary,
    whether they reproduce it."""

    values: dict[str, str]
    result: Totals
    matches_run: bool | None = None
    origin: str = "grid"


def report_markdown(
    source: str,
    rows: list[SweepRow],
    run_summary: dict | None,
    statistics: dict[str, np.ndarray],
    named: dict[str, int] | None = None,
) -> str:
    """The report: the table of combinations (with, on a release run, the release clips surviving
    per split of ``named``: split -> release clips named), then the statistics' quantiles."""
    keys = list(rows[0].values)
    lines = [f"# Threshold sweep: {source}", ""]
    if named is not None:
        lines += [
            "Release run: the release's clips only; `release <split>` = release clips that survive "
            "(written, at least min_tracks tracks passing) of those the release names.",
            "",
        ]
    if run_summary is not None:
        matches = rows[0].matches_run
        lines += [
            f"First row = the run's own thresholds; it {'reproduces' if matches else 'DOES NOT reproduce'} "
            "the run's counts (run_<source>.json summary).",
            "",
        ]
    header = (
        ["thresholds", *keys, "candidates"]
        + [f"dropped: {n}" for n in FILTER_ORDER]
        + ["passed", "clips", "below target"]
    )
    header += [f"release {split}" for split in SPLITS] if named is not None else []
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for row in rows:
        r = row.result
        cells: list[object] = [row.origin, *(row.values[k] for k in keys), r.candidates]
        cells += [*(r.dropped[n] for n in FILTER_ORDER), r.passed, r.clips_written, r.clips_below_target]
        if named is not None and r.release is not None:
            cells += [f"{r.release[split]} of {named[split]}" for split in SPLITS]
        lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    lines += ["", "## Statistics over all candidates", "", "| statistic | min | 5% | median | 95% | max |"]
    lines.append("|---|---|---|---|---|---|")
    for name, values in sorted(statistics.items()):
        finite = values[np.isfinite(values)]
        if len(finite):
            q = np.percentile(finite, [0, 5, 50, 95, 100])
            lines.append(f"| {name} | " + " | ".join(f"{v:.4g}" for v in q) + " |")
    lines += ["", "![survival](survival.png)", "", "![histograms](histograms.png)", ""]
    return "\n".join(lines)


def run_provenance(output: str, source: str) -> dict | None:
    """The run's record (``run_<source>.json``), None when there is none."""
    path = provenance_path(output, source)
    if not os.path.exists(path) and "://" not in output:
        return None
    return json.loads(read_bytes(path))


def run_summary_and_config(record: dict | None, overrides: list[str]) -> tuple[dict | None, RunConfig]:
    if record is None:
        return None, with_overrides(RunConfig(), overrides)
    return record["summary"], with_overrides(config_from_dict(RunConfig, record["config"]), overrides)


def release_of(given: str | None, record: dict | None) -> Release | None:
    """The release a sweep counts: ``--release``, else the one the run was restricted to."""
    path = given or (record or {}).get("release")
    return read_release(path, f"--release {path}" if given else f"the run's release {path}") if path else None


# Old spellings of the options, and what replaced them.
RENAMED = {
    "--output": "is now the positional OUT (python -m pipeline.audit sweep OUT --source S ...)",
    "--report": "is now --out",
    "--input": "is gone: run python -m pipeline.run --source S --input DIR --output OUT first",
}


def command_parser() -> StrictParser:
    parser = StrictParser(
        prog="python -m pipeline.audit sweep",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        renamed=RENAMED,
    )
    parser.add_argument("output", metavar="OUT", help="the output folder of the run to replay")
    parser.add_argument("--source", required=True, choices=sources.names(), help="the source to replay")
    parser.add_argument(
        "--grid",
        action="append",
        default=[],
        metavar="KEY=V1,V2,...",
        help="a threshold and the values to try, e.g. flicker.max_fraction=0.05,0.2 (repeatable)",
    )
    add_set_argument(
        parser,
        "change a setting of the run before replaying it (repeatable)",
    )
    parser.add_argument("--out", metavar="DIR", help="the report's folder (default OUT/sweep_<source>)")
    parser.add_argument(
        "--release",
        metavar="SPLITS_JSON",
        help="count, per split, the release's clips that survive each combination (default: the run's "
        "own --release); a run made with --run-sample is restricted to them",
    )
    parser.add_argument(
        "--run-sample",
        action="store_true",
        help="when OUT holds no run of the source, first run the pipeline on its sample world into OUT "
        "(python -m pipeline.run --source S --output OUT)",
    )
    return parser


def main(argv: list[str]) -> int:
    args = command_parser().parse_args(argv)
    try:
        return sweep(args)
    except SettingsError as problem:
        print(f"sweep: {len(problem.problems)} problem(s):", file=sys.stderr)
        for line in problem.problems:
            print(f"  {line}", file=sys.stderr)
        return 2
    except (ValueError, KeyError, OSError, pa.ArrowException, InputError) as error:
        print(f"sweep: {error}", file=sys.stderr)
        return 2


def holds_run(output: str, source: str) -> bool:
    """Whether ``output`` holds a run of ``source``: its run's provenance or its audit tables."""
    return run_provenance(output, source) is not None or bool(list_files(audit_path(output, source, "*")))


def run_sample(output: str, source: str, release: str | None, overrides: list[str]) -> int:
    """``python -m pipeline.run`` on the source's sample world into ``output``; its exit status."""
    from pipeline.runner import command as run

    print(f"--run-sample: running the pipeline on the {source} sample world into {output} first")
    command = ["--source", source, "--output", output] + (["--release", release] if release else [])
    return run.main(command + [f"--set={o}" for o in overrides])


def sweep(args: argparse.Namespace) -> int:
    """The sweep of ``main``'s arguments; raises ValueError, KeyError, OSError or ArrowException on
    bad input, which ``main`` prints as one line."""
    source = sources.get(args.source)
    grid = parse_grid(args.grid, source, with_overrides(RunConfig(), args.overrides))
    output = os.path.abspath(args.output) if "://" not in args.output else args.output
    if "://" not in output and os.path.isfile(output):
        raise ValueError(f"OUT {output} is a file, not a folder")
    if not holds_run(output, args.source):
        if not args.run_sample:
            print(
                f"sweep: no {args.source} run in {output} (no run_{args.source}.json, no audit tables): run "
                f"python -m pipeline.run --source {args.source} --output {output} first, or add --run-sample",
                file=sys.stderr,
            )
            return 2
        if run_sample(output, args.source, args.release, args.overrides) == 2:
            return 2
    record = run_provenance(output, args.source)
    run_summary, base = run_summary_and_config(record, args.overrides)
    release = release_of(args.release, record)
    splits = dict(release.clips.get(args.source, {})) if release is not None else None
    clips = load_statistics(output, args.source)
    if splits is not None:
        clips = [clip for clip in clips if clip.clip in splits]
    if not clips:
        which = " of the release's clips" if splits is not None else ""
        print(f"sweep: no audit tables{which} in {output}/audit/{args.source}/", file=sys.stderr)
        return 1
    keys = list(grid)
    own = evaluate(clips, source, base, splits)
    matches = matches_run(own, run_summary) if run_summary is not None else None
    rows = [SweepRow({k: _current(base, k) for k in keys}, own, matches, "run")]
    for values in itertools.product(*grid.values()) if keys else []:
        config = with_overrides(base, [f"{k}={v}" for k, v in zip(keys, values, strict=True)])
        if config == base:  # the run's own combination: its row says so, once
            rows[0] = dataclasses.replace(rows[0], origin="run = grid")
            continue
        rows.append(SweepRow(dict(zip(keys, values, strict=True)), evaluate(clips, source, config, splits)))
    report = args.out or sweep_folder(output, args.source)
    statistics = numeric_statistics(clips)
    named = (
        {split: sum(s == split for s in splits.values()) for split in SPLITS} if splits is not None else None
    )
    markdown = report_markdown(args.source, rows, run_summary, statistics, named)
    files = {
        f"{report}/report.md": markdown.encode(),
        f"{report}/sweep.parquet": _rows_parquet(rows),
        f"{report}/survival.png": survival_figure(clips, source, base),
        f"{report}/histograms.png": histogram_figure(statistics, args.source),
    }
    try:
        complete_commits(report)  # what an earlier sweep killed while writing here left
        reclaim_temporaries(list(files))
        write_together(files, report)  # the report's files are one result: all new or all as they were
    except OSError as error:
        print(f"sweep: cannot write the report in {report}: {error}", file=sys.stderr)
        return 2
    print(markdown.split("\n## Statistics")[0])
    print(f"report: {report}/report.md (with survival.png, histograms.png, sweep.parquet)")
    return 1 if rows[0].matches_run is False else 0


def _current(config: RunConfig, key: str) -> str:
    return str(value_at(config, key))


def matches_run(result: Totals, summary: dict) -> bool:
    """Whether replayed counts equal the run's own summary."""
    return (
        result.candidates == summary["candidate_tracks"]
        and result.dropped == summary["dropped_by_filter"]
        and result.passed == summary["tracks_passing_filters"]
        and result.clips_below_target == summary["clips_below_target"]
    )


def _rows_parquet(rows: list[SweepRow]) -> bytes:
    """The table of combinations: a column per swept key, then the totals (``report_markdown``'s)."""
    columns: dict[str, list] = {"thresholds": [row.origin for row in rows]}
    columns |= {key: [row.values[key] for row in rows] for key in rows[0].values}
    columns["candidates"] = [row.result.candidates for row in rows]
    for name in FILTER_ORDER:
        columns[f"dropped_{name}"] = [row.result.dropped[name] for row in rows]
    columns["passed"] = [row.result.passed for row in rows]
    columns["clips_written"] = [row.result.clips_written for row in rows]
    columns["clips_below_target"] = [row.result.clips_below_target for row in rows]
    releases = [row.result.release for row in rows if row.result.release is not None]
    if releases:
        for split in SPLITS:
            columns[f"release_{split}"] = [release[split] for release in releases]
    buffer = io.BytesIO()
    pq.write_table(pa.table(columns), buffer)
    return buffer.getvalue()
