"""A source's benchmark entry, as the framework finds and calls it: the module that
``sources.get(name).bench_module`` names (``Source.bench``, by default ``benchmarks.<name>``),
defining ``INTERFACE`` (``benchmarks/__init__.py`` says what each name does); its ``prepare``
returns a ``UnitSetup``.
"""

from __future__ import annotations

import dataclasses
import importlib
import time
from types import ModuleType

INTERFACE = (
    "TARGETS",
    "FIXED_IN_WORK",
    "prepare",
    "measure_fixed_cost",
    "floor",
    "unit_of",
    "micro",
    "beam_run_args",
)
SIZES = ("quick", "default", "full")


@dataclasses.dataclass
class UnitSetup:
    """One source's benchmark unit, as ``prepare`` builds it.

    units: the units of the scaling run (the first one is "the" unit); each is a group of the
      source's units, each unit a JSON list of its fields (one ADT chunk: ``[[sequence, 0]]``).
    frames: frames of one unit's input as measured (for the per-frame figure).
    extrapolate_frames: when set, the release's unit of that many frames is extrapolated from the
      measured one: fixed cost (ADT: opening the sequence, measured apart; else 0) + per-frame
      cost x frames (ADT: its excerpt holds 2 frames; DriveTrack and Panoptic Studio at the
      default size: shorter inputs than the release's).
    full_units: units of the whole benchmark for the CPU-hours line, with ``full_units_note``.
    size: "quick", "default" or "full" (ADT: its excerpt whatever the size).
    variants: name -> settings added to ``overrides``: each unit of the 1-worker runs is run once
      more with each, one process right after its floor's, and their time printed beside the
      unit's (not in the table).
    """

    source: str
    input_root: str
    units: list
    overrides: list[str]
    frames: int
    description: list[str]
    full_units: int
    full_units_note: str
    extrapolate_frames: int | None = None
    size: str = "excerpt"
    notes: list[str] = dataclasses.field(default_factory=list)
    extra: dict = dataclasses.field(default_factory=dict)  # passed to the worker in its spec
    variants: dict[str, list[str]] = dataclasses.field(default_factory=dict)


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


def wall_and_cpu(function, *args) -> tuple[float, float]:
    """Wall and CPU seconds of ``function(*args)``."""
    wall, cpu = time.perf_counter(), time.process_time()
    function(*args)
    return time.perf_counter() - wall, time.process_time() - cpu
