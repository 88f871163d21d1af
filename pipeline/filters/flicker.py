"""Flicker: how often a track's visibility changes state, and the threshold that drops a track."""

from __future__ import annotations

import dataclasses

import numpy as np

from pipeline.settings.fields import ranged


def visibility_flips(visibility: np.ndarray) -> np.ndarray:
    """Number of visible/occluded changes along time per track: [T, N] bool -> [N] int64."""
    return np.count_nonzero(visibility[1:] != visibility[:-1], axis=0).astype(np.int64)


def passes_flicker(flips: np.ndarray, num_frames: int, max_fraction: float) -> np.ndarray:
    """Keep tracks whose flips are at most ``max_fraction`` of the number of frames."""
    return flips <= max_fraction * num_frames


@dataclasses.dataclass(frozen=True)
class FlickerConfig:
    """Drop a track whose visibility changes state more than ``max_fraction`` x T times.

    max_fraction: a track is dropped when its visibility flips (visible to occluded or back) more
      than this fraction of its T frames (the paper's 10%).
    """

    max_fraction: float = ranged(0.10, "[0, 1]")
