"""Stable per-point draws for DriveTrack: each lidar point of a clip has its own pseudo-random key
from (run seed, clip name, frame timestamp, range-image pixel), so whether a point is drawn, and
its query frame, never depend on which other points exist nor on their order. One point more or
less in an object's box changes the draw by at most that point."""

from __future__ import annotations

import hashlib

import numpy as np

_QUERY_SALT = np.uint64(0x5157_4552_5946_524D)


def _mix(values: np.ndarray) -> np.ndarray:
    """splitmix64's finaliser on uint64 [...], wrapping arithmetic: a bijection that spreads bits."""
    values = (values ^ (values >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    values = (values ^ (values >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return values ^ (values >> np.uint64(31))


def point_keys(seed: int, clip: str, timestamps: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """uint64 keys [P] of points named by their frame timestamps [P] and range-image pixels [P]."""
    digest = hashlib.sha256(f"{seed}:{clip}".encode()).digest()
    base = np.full(len(pixels), int.from_bytes(digest[:8], "little"), np.uint64)
    stamps = np.asarray(timestamps, np.int64).view(np.uint64)
    return _mix(_mix(base ^ _mix(stamps)) ^ np.asarray(pixels, np.int64).view(np.uint64))


def lowest_keys(keys: np.ndarray, count: int) -> np.ndarray:
    """Sorted indices of the ``count`` (at most all) smallest keys [P]."""
    return np.sort(np.argsort(keys, kind="stable")[:count])


def query_draws(keys: np.ndarray) -> np.ndarray:
    """A uniform draw in [0, 1) [N] per point key [N], independent of the key's rank."""
    return (_mix(keys ^ _QUERY_SALT) >> np.uint64(11)).astype(np.float64) * 2.0**-53
