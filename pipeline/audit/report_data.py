"""The audit page's data: per source, the filter stage's statistics folded so that the page recounts,
at every slider position it offers, exactly what ``python -m pipeline.audit sweep`` counts there.

A slider offers a grid of values (``flicker.max_fraction`` and ``<source>.mask_min_agreement``: 0 to
1 in steps of 0.01, plus the run's own value; ``min_tracks``: every integer from 1 to the most
candidates of a clip). Each candidate track that passes ``never_visible`` gets two bucket numbers:

flicker bucket f: how many flicker values of the grid reject it (``passes_flicker`` is monotone in
  the threshold, so it passes at grid index k exactly when k >= f);
mask bucket m: how many mask values of the grid it passes (no mask evidence: all of them), so it
  passes at grid index k exactly when k < m.

Per clip, the page gets the sparse counts of tracks per (f, m) pair and the count of never-visible
tracks; survivors at (k_flicker, k_mask) are the counts with f <= k_flicker and m > k_mask, compared
with ``min_tracks`` and the clip's target as ``evaluate`` compares them.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from pipeline import sources
from pipeline.audit.sweep import AuditTable, ClipCount, Totals, read_audit_table, run_provenance, totals
from pipeline.audit.verdict_rows import VerdictRow, read_verdicts
from pipeline.export.layout import audit_path
from pipeline.filters.flicker import passes_flicker
from pipeline.io.files import list_files
from pipeline.runner.splits import SPLITS
from pipeline.settings.fields import config_from_dict
from pipeline.settings.run_config import RunConfig
from pipeline.sources import Source

GRID_STEPS = 100  # fractions: 0, 0.01, ..., 1


def fraction_grid(run_value: float) -> list[float]:
    """0, 0.01, ..., 1 and the run's own value, ascending (k / 100 is the double nearest to the decimal
    ``0.0k``, the value ``--grid`` parses)."""
    return sorted({k / GRID_STEPS for k in range(GRID_STEPS + 1)} | {float(run_value)})


def flicker_buckets(flips: np.ndarray, num_frames: int, grid: list[float]) -> np.ndarray:
    """Per track [N] int: how many values of ``grid`` (ascending) ``passes_flicker`` rejects it at."""
    flips = np.asarray(flips)
    rejections = np.zeros(len(flips), np.int64)
    for fraction in grid:
        rejections += ~passes_flicker(flips, num_frames, fraction)
    return rejections


def mask_buckets(agreement: np.ndarray | None, count: int, grid: list[float]) -> np.ndarray:
    """Per track [N] int: how many values of ``grid`` (ascending) the mask filter passes it at (NaN
    agreement, or none recorded: every one)."""
    if agreement is None:
        return np.full(count, len(grid), np.int64)
    score = np.asarray(agreement, dtype=np.float64)[:, None]
    return (np.isnan(score) | (score >= np.asarray(grid)[None, :])).sum(axis=1)


def read_clip_table(path: str) -> AuditTable:
    """The statistics of one audit table the filters read (``read_audit_table``)."""
    return read_audit_table(path, ())


@dataclasses.dataclass(frozen=True)
class FoldedClip:
    """One clip as the page recounts it: its frames, target track count, candidates and never-visible
    tracks, and the sparse (flicker bucket, mask bucket) pairs of the others: ``flicker``, ``mask``
    [P] int64 and their track counts ``count`` [P] int64."""

    clip: str
    num_frames: int
    target_tracks: int
    candidates: int
    never_visible: int
    flicker: np.ndarray
    mask: np.ndarray
    count: np.ndarray


def fold_clip(table: AuditTable, flicker_grid: list[float], mask_grid: list[float]) -> FoldedClip:
    """One clip's audit table folded over the slider grids."""
    stats = table.stats
    seen = np.asarray(stats.visible_frames) > 0
    flips = np.asarray(stats.visibility_flips)[seen]
    agreement = None if stats.mask_agreement is None else np.asarray(stats.mask_agreement)[seen]
    flicker = flicker_buckets(flips, table.num_frames, flicker_grid)
    mask = mask_buckets(agreement, len(flips), mask_grid)
    pairs, counts = np.unique(flicker * (len(mask_grid) + 1) + mask, return_counts=True)
    return FoldedClip(
        table.clip,
        table.num_frames,
        table.target_tracks,
        len(seen),
        int((~seen).sum()),
        (pairs // (len(mask_grid) + 1)).astype(np.int64),
        (pairs % (len(mask_grid) + 1)).astype(np.int64),
        counts.astype(np.int64),
    )


def histogram_counts(table: AuditTable, flicker_grid: list[float], mask_grid: list[float]) -> dict:
    """One clip's histograms over all its candidates: per flicker bucket [len(grid) + 1], per mask
    bucket [len(grid) + 1] (tracks with agreement only), tracks without mask evidence, visible frames
    per count [T + 1]."""
    stats = table.stats
    flicker = flicker_buckets(stats.visibility_flips, table.num_frames, flicker_grid)
    agreement = stats.mask_agreement
    scored = np.zeros(0) if agreement is None else np.asarray(agreement, np.float64)[~np.isnan(agreement)]
    mask = mask_buckets(scored, len(scored), mask_grid)
    visible = np.clip(np.asarray(stats.visible_frames), 0, table.num_frames)
    return {
        "flicker": np.bincount(flicker, minlength=len(flicker_grid) + 1),
        "mask": np.bincount(mask, minlength=len(mask_grid) + 1),
        "no_mask_evidence": stats.count - len(scored),
        "visible_frames": np.bincount(visible, minlength=table.num_frames + 1),
    }


def add_histograms(total: dict, part: dict) -> dict:
    """``total`` + ``part``, bins of different lengths padded with zeros."""
    out = {"no_mask_evidence": total.get("no_mask_evidence", 0) + part["no_mask_evidence"]}
    for name in ("flicker", "mask", "visible_frames"):
        a, b = total.get(name, np.zeros(0, np.int64)), part[name]
        size = max(len(a), len(b))
        out[name] = np.pad(a, (0, size - len(a))) + np.pad(b, (0, size - len(b)))
    return out


def run_config(record: dict | None) -> RunConfig:
    """The run's own config (the defaults when it left no provenance file)."""
    return RunConfig() if record is None else config_from_dict(RunConfig, record["config"])


@dataclasses.dataclass(frozen=True)
class SourceData:
    """Everything the page shows of one source: the run's ``thresholds`` and the sliders' ``grids``
    (config key -> value, values: flicker.max_fraction, <source>.mask_min_agreement, min_tracks),
    its folded clips (sorted by name), the histograms of all candidates (``histogram_counts``'s, as
    lists), the run's summary and release file (None without provenance), its release verdicts and
    the release clips named per split (None on a run without a release)."""

    name: str
    thresholds: dict[str, float]
    grids: dict[str, list[float]]
    clips: list[FoldedClip]
    histograms: dict[str, Any]
    summary: dict[str, Any] | None
    release_path: str | None
    verdicts: list[VerdictRow] | None
    named: dict[str, int] | None


def source_data(output: str, source: Source) -> SourceData | None:
    """Everything the page shows of one source, None when ``output`` holds neither an audit table of
    it nor release verdicts (a release run that annotated no clip has verdicts alone: ``clips`` is
    then empty).

    On a release run (``release_<source>.jsonl``) only the release's clips count, as in the sweep.
    """
    paths = list_files(audit_path(output, source.name, "*"))
    verdicts = read_verdicts(output, source.name)
    if not paths and verdicts is None:
        return None
    record = run_provenance(output, source.name)
    config = run_config(record)
    splits = None if verdicts is None else {row.verdict.clip: row.verdict.split for row in verdicts}
    flicker_grid = fraction_grid(config.flicker.max_fraction)
    mask_grid = fraction_grid(source.mask_min_agreement(config))
    clips: list[FoldedClip] = []
    histograms: dict[str, Any] = {}
    for path in sorted(paths):
        table = read_clip_table(path)
        if splits is not None and table.clip not in splits:
            continue
        clips.append(fold_clip(table, flicker_grid, mask_grid))
        histograms = add_histograms(histograms, histogram_counts(table, flicker_grid, mask_grid))
    clips.sort(key=lambda clip: clip.clip)
    most = max([clip.candidates for clip in clips] + [config.min_tracks, 1])
    return SourceData(
        source.name,
        thresholds={
            "flicker.max_fraction": config.flicker.max_fraction,
            f"{source.name}.mask_min_agreement": source.mask_min_agreement(config),
            "min_tracks": config.min_tracks,
        },
        grids={
            "flicker.max_fraction": flicker_grid,
            f"{source.name}.mask_min_agreement": mask_grid,
            "min_tracks": list(range(1, most + 1)),
        },
        clips=clips,
        histograms={name: np.asarray(v).tolist() for name, v in histograms.items()},
        summary=None if record is None else record["summary"],
        release_path=None if record is None else record.get("release"),
        verdicts=verdicts,
        named=None if splits is None else {split: list(splits.values()).count(split) for split in SPLITS},
    )


def counts_at(data: SourceData, flicker_index: int, mask_index: int, min_tracks: int) -> Totals:
    """The totals ``evaluate`` reports (``sweep.totals``) at grid positions (``flicker_index``,
    ``mask_index``) and ``min_tracks``, from the folded clips alone (the page's own rule)."""

    def folded(clip: FoldedClip) -> ClipCount:
        flicker_ok = clip.flicker <= flicker_index
        mask_ok = clip.mask > mask_index
        dropped = {
            "never_visible": clip.never_visible,
            "flicker": int(clip.count[~flicker_ok].sum()),
            "mask": int(clip.count[flicker_ok & ~mask_ok].sum()),
        }
        survivors = int(clip.count[flicker_ok & mask_ok].sum())
        return ClipCount(clip.clip, clip.candidates, dropped, survivors, clip.target_tracks)

    verdicts = data.verdicts
    splits = {row.verdict.clip: row.verdict.split for row in verdicts} if verdicts is not None else None
    return totals(map(folded, data.clips), min_tracks, splits)


def page_data(output: str, names: list[str]) -> list[SourceData]:
    """``source_data`` of each named source that has audit tables in ``output``."""
    found = (source_data(output, sources.get(name)) for name in names)
    return [data for data in found if data is not None]
