"""The filter stage: per-track verdicts from recorded statistics, then the seeded subsample.

Filters run in a fixed order; a track is counted against the first filter that rejects it.
The statistics stay with every candidate track, so an audit can replay other thresholds.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np

from pipeline.core.clip import ClipRecord
from pipeline.core.outcomes import FILTER_ORDER
from pipeline.core.sampling import choose_subset, rng_for
from pipeline.filters.flicker import passes_flicker, visibility_flips

if TYPE_CHECKING:
    from pipeline.settings.run_config import RunConfig


# The statistics every filter reads; a clip's audit table holds them and the source's own.
FILTERED_BY = ("visible_frames", "visibility_flips", "mask_agreement")


@dataclasses.dataclass(frozen=True)
class FilterStats:
    """What the filters read of each candidate track, each [N], with the source's own statistics:
    the statistics columns of a clip's audit table.

    visible_frames: [N] int64 frames where the track is visible (the never_visible filter).
    visibility_flips: [N] int64 visibility changes (the flicker filter).
    mask_agreement: [N] float64 (the mask filter; ``TrackStats.mask_agreement``), or None.
    extra: name -> [N], the source's own (``TrackStats.extra``).
    """

    visible_frames: np.ndarray
    visibility_flips: np.ndarray
    mask_agreement: np.ndarray | None = None
    extra: Mapping[str, np.ndarray] = dataclasses.field(default_factory=dict)

    @classmethod
    def of(cls, clip: ClipRecord) -> FilterStats:
        """A candidate clip's: counted from its visibility, with the statistics its source recorded."""
        return cls(
            clip.visibility.sum(axis=0).astype(np.int64),
            visibility_flips(clip.visibility),
            clip.track_stats.mask_agreement,
            clip.track_stats.extra,
        )

    @classmethod
    def from_columns(cls, columns: Mapping[str, np.ndarray]) -> FilterStats:
        """From an audit table's statistics columns (name -> [N]); KeyError naming a missing one."""
        extra = {name: values for name, values in columns.items() if name not in FILTERED_BY}
        return cls(
            columns["visible_frames"], columns["visibility_flips"], columns.get("mask_agreement"), extra
        )

    def columns(self) -> dict[str, np.ndarray]:
        """Name -> [N]: every statistic, as the audit table's columns."""
        named = {"visible_frames": self.visible_frames, "visibility_flips": self.visibility_flips}
        if self.mask_agreement is not None:
            named["mask_agreement"] = self.mask_agreement
        return {**self.extra, **named}

    @property
    def count(self) -> int:
        return len(self.visible_frames)


@dataclasses.dataclass
class FilterOutcome:
    """What the filter stage decided for one clip.

    verdicts: filter name -> [N] bool (True = passes), over all candidates.
    stats: the statistics the verdicts were read from, over all candidates.
    selected: [K] indices of the candidates written, in output order.
    """

    clip: str
    source: str
    unit: str
    num_frames: int
    target_tracks: int
    verdicts: dict[str, np.ndarray]
    stats: FilterStats
    selected: np.ndarray

    @property
    def candidates(self) -> int:
        return len(next(iter(self.verdicts.values())))

    def dropped_by(self) -> dict[str, int]:
        """Tracks rejected per filter, each counted against the first filter that rejects it."""
        return count_dropped(self.verdicts)

    @property
    def passed(self) -> int:
        return int(np.logical_and.reduce(list(self.verdicts.values())).sum())


def count_dropped(verdicts: dict[str, np.ndarray]) -> dict[str, int]:
    """Tracks rejected per filter in FILTER_ORDER, each counted against the first that rejects it."""
    alive = np.ones(len(next(iter(verdicts.values()))), bool)
    counts = {}
    for name in FILTER_ORDER:
        counts[name] = int((alive & ~verdicts[name]).sum())
        alive &= verdicts[name]
    return counts


def verdicts_from_stats(
    stats: FilterStats, num_frames: int, config: RunConfig, mask_min_agreement: float
) -> dict[str, np.ndarray]:
    """Verdict per filter [N] bool from recorded statistics [N]: the filter stage's only rule,
    also replayed by ``pipeline.audit sweep`` at other thresholds. ``mask_min_agreement`` is the
    clip's source's threshold (``Source.mask_min_agreement``)."""
    flips = np.asarray(stats.visibility_flips)
    verdicts = {
        "never_visible": np.asarray(stats.visible_frames) > 0,
        "flicker": passes_flicker(flips, num_frames, config.flicker.max_fraction),
        "mask": np.ones(stats.count, bool),
    }
    if stats.mask_agreement is not None:
        score = np.asarray(stats.mask_agreement, dtype=np.float64)
        verdicts["mask"] = np.isnan(score) | (score >= mask_min_agreement)
    return verdicts


def decide(
    clip: ClipRecord, config: RunConfig, mask_min_agreement: float
) -> tuple[dict[str, np.ndarray], FilterStats]:
    """Verdict per filter [N] bool, and the statistics they read."""
    stats = FilterStats.of(clip)
    return verdicts_from_stats(stats, clip.num_frames, config, mask_min_agreement), stats


def apply_filters(
    clip: ClipRecord, config: RunConfig, mask_min_agreement: float
) -> tuple[ClipRecord, FilterOutcome]:
    """Keep the tracks every filter passes, then the clip's target count of them: those with the
    lowest ``track_keys`` when the clip has keys, else a seeded draw; none when fewer than
    ``min_tracks`` pass. A clip of given queries keeps every track, in order (the verdicts are still
    recorded)."""
    verdicts, stats = decide(clip, config, mask_min_agreement)
    survivors = np.nonzero(np.logical_and.reduce([verdicts[name] for name in FILTER_ORDER]))[0]
    if clip.track_keys is not None:
        lowest = np.argsort(clip.track_keys[survivors], kind="stable")[: clip.target_tracks]
        selected = survivors[np.sort(lowest)]
    else:
        rng = rng_for(config.seed, f"{clip.name}/subsample")
        selected = survivors[choose_subset(len(survivors), clip.target_tracks, rng)]
    if len(survivors) < config.min_tracks:
        selected = survivors[:0]
    if clip.given_queries:
        selected = np.arange(clip.num_tracks)
    outcome = FilterOutcome(
        clip=clip.name,
        source=clip.source,
        unit=clip.unit,
        num_frames=clip.num_frames,
        target_tracks=clip.target_tracks,
        verdicts=verdicts,
        stats=stats,
        selected=selected,
    )
    return clip.select_tracks(selected), outcome
