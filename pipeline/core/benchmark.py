"""What a source's benchmark entry (``pipeline/<source>/bench.py``) hands the benchmark harness
(``benchmarks/``, which is not installed and imports the package, never the other way round): the
``UnitSetup`` its ``prepare`` returns, and the clock its measurements use.
"""

from __future__ import annotations

import dataclasses
import time


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
    full_clips: the clips those units make (the release's), for the clips-per-CPU-hour line (what
      a training run of this source costs a clip); 0: not printed.
    size: "quick", "default" or "full" (ADT: its excerpt whatever the size).
    variants: name -> settings added to ``overrides``: each unit of the 1-worker runs is run once
      more with each, one process right after its floor's, and their time and peak memory
      printed beside the unit's (not in the table's columns).
    rule_sets: rule set -> the variant that runs the unit under it (a name of ``variants``): the
      table's peak memory per rule set (``peak_rss_gib_by_rules``) holds each one's beside the
      unit's own, under the rule set its ``overrides`` set (a plain run's, ``refined``, when they
      set none).
    """

    source: str
    input_root: str
    units: list
    overrides: list[str]
    frames: int
    description: list[str]
    full_units: int
    full_units_note: str
    full_clips: int = 0
    extrapolate_frames: int | None = None
    size: str = "excerpt"
    notes: list[str] = dataclasses.field(default_factory=list)
    extra: dict = dataclasses.field(default_factory=dict)  # passed to the worker in its spec
    variants: dict[str, list[str]] = dataclasses.field(default_factory=dict)
    rule_sets: dict[str, str] = dataclasses.field(default_factory=dict)


def wall_and_cpu(function, *args) -> tuple[float, float]:
    """Wall and CPU seconds of ``function(*args)``."""
    wall, cpu = time.perf_counter(), time.process_time()
    function(*args)
    return time.perf_counter() - wall, time.process_time() - cpu
