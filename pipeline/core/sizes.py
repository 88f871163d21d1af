"""Sizes in messages."""

from __future__ import annotations


def format_bytes(count: int) -> str:
    """``count`` bytes for messages: ``512 B``, ``12.3 MB``, ``1.7 TB`` (powers of 1000)."""
    units, power = ("B", "kB", "MB", "GB", "TB"), 0
    while power < len(units) - 1 and abs(count) >= 1000 ** (power + 1):
        power += 1
    return f"{count} B" if power == 0 else f"{count / 1000**power:.1f} {units[power]}"
