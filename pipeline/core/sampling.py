"""Seeded sampling: every random choice derives from (run seed, clip name)."""

from __future__ import annotations

import hashlib

import numpy as np


def rng_for(seed: int, name: str) -> np.random.Generator:
    """A generator that depends only on the run seed and a name (runner-independent)."""
    digest = hashlib.sha256(f"{seed}:{name}".encode()).digest()
    return np.random.default_rng(int.from_bytes(digest[:8], "little"))


def choose_subset(count: int, keep: int, rng: np.random.Generator) -> np.ndarray:
    """Sorted indices of ``min(keep, count)`` items drawn without replacement from ``count``."""
    if keep >= count:
        return np.arange(count)
    return np.sort(rng.choice(count, size=keep, replace=False))
