"""Flicker: how often a track's visibility changes state, and the threshold that drops a track."""

from __future__ import annotations

import numpy as np


def visibility_flips(visibility: np.ndarray) -> np.ndarray:
    """Number of visible/occluded changes along time per track: [T, N] bool -> [N] int64."""
    return np.count_nonzero(visibility[1:] != visibility[:-1], axis=0).astype(np.int64)


def passes_flicker(flips: np.ndarray, num_frames: int, max_fraction: float) -> np.ndarray:
    """Keep tracks whose flips are at most ``max_fraction`` of the number of frames."""
    return flips <= max_fraction * num_frames
