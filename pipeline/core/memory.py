"""Freed heap given back between units: glibc keeps the memory a unit's large arrays were freed from
(arenas and the top of the heap) resident in a long-lived worker; ``malloc_trim(0)`` returns it, so
the next unit starts from what the worker really holds. Elsewhere (another C library, another
system) nothing is done."""

from __future__ import annotations

import ctypes
import functools
import sys


@functools.cache
def _trim():
    """glibc's ``malloc_trim``, or None where there is none."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        return ctypes.CDLL("libc.so.6").malloc_trim
    except (OSError, AttributeError):
        return None


def release_freed_memory() -> None:
    """Give the heap freed since the last call back to the system (glibc's ``malloc_trim(0)``)."""
    trim = _trim()
    if trim is not None:
        trim(0)
