"""Seeded sampling: every random choice derives from (run seed, clip name)."""

from __future__ import annotations

import hashlib

import numpy as np

from pipeline.core.geometry import project


def rng_for(seed: int, name: str) -> np.random.Generator:
    """A generator that depends only on the run seed and a name (runner-independent)."""
    digest = hashlib.sha256(f"{seed}:{name}".encode()).digest()
    return np.random.default_rng(int.from_bytes(digest[:8], "little"))


def sample_query_frames(visibility: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Query frame per track, uniform among its visible frames.

    Args:
      visibility: [T, N] bool.
    Returns:
      [N] int64 frame indices; -1 for tracks never visible.
    """
    counts = visibility.sum(axis=0)
    draws = rng.random(visibility.shape[1])
    rank = np.minimum((draws * counts).astype(np.int64), np.maximum(counts - 1, 0))
    # Index of the (rank+1)-th visible frame: first t where the running count exceeds rank.
    running = np.cumsum(visibility, axis=0)
    t_q = np.argmax(running > rank[None, :], axis=0).astype(np.int64)
    t_q[counts == 0] = -1
    return t_q


def queries_from_tracks(
    tracks_xyz: np.ndarray, query_frames: np.ndarray, fx_fy_cx_cy: np.ndarray
) -> np.ndarray:
    """Queries [N, 3] (x, y, t): the projection of each track at its query frame [N]."""
    n = tracks_xyz.shape[1]
    points = tracks_xyz[query_frames, np.arange(n)]
    xy = project(points, fx_fy_cx_cy)
    return np.concatenate([xy, query_frames[:, None].astype(np.float64)], axis=1)


def choose_subset(count: int, keep: int, rng: np.random.Generator) -> np.ndarray:
    """Sorted indices of ``min(keep, count)`` items drawn without replacement from ``count``."""
    if keep >= count:
        return np.arange(count)
    return np.sort(rng.choice(count, size=keep, replace=False))
