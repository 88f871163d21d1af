"""A source's benchmark entry, as the framework finds and calls it: the module that
``sources.get(name).bench_module`` names (``Source.bench``: a built-in source's is
``pipeline/<source>/bench.py``), defining ``INTERFACE`` (``benchmarks/__init__.py`` says what each
name does); its ``prepare`` returns a ``pipeline.core.benchmark.UnitSetup``.
"""

from __future__ import annotations

import importlib
from types import ModuleType

INTERFACE = (
    "TARGETS",
    "FIXED_IN_WORK",
    "prepare",
    "measure_fixed_cost",
    "floor",
    "unit_of",
    "micro",
    "beam_input",
    "RELEASE_SHAPE",
)


def entry_name(source: str) -> str:
    """The module of ``source``'s benchmark entry."""
    # Imported here: a floor process imports its entry (hence this module) and, before its timings,
    # only what its floor reads.
    from pipeline import sources

    return sources.get(source).bench_module


def entry(source: str) -> ModuleType:
    """``source``'s benchmark entry, imported; TypeError naming what it lacks of ``INTERFACE``."""
    module = importlib.import_module(entry_name(source))
    missing = [name for name in INTERFACE if not hasattr(module, name)]
    if missing:
        raise TypeError(f"{module.__name__}, the benchmark entry of {source!r}, lacks {', '.join(missing)}")
    return module
