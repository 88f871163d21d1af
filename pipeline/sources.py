"""The registry of sources: each dataset the pipeline regenerates clips from is one ``Source``.

Everything that needs the list of sources (the command line, manifests, validate, sweep, the
benchmarks) reads it here. A source is plain Python on arrays and files: it never imports the Beam
shell (``pipeline.graph``) nor the per-unit driver (``pipeline.unit``), which sit above it.
Built-in sources are imported on first use, so listing names costs no heavy import.
"""

from __future__ import annotations

import dataclasses
import importlib
from collections.abc import Callable, Iterable

from pipeline.core.clip import ClipRecord
from pipeline.core.config import RunConfig


class NoSample(Exception):
    """A source without an embedded sample world; the message says how to get real input."""


@dataclasses.dataclass(frozen=True)
class Source:
    """One dataset, as the pipeline sees it.

    name: the ``--source`` value and the folder of its clips (``<out>/<name>/<clip>.npz``).
    list_units: (input root, config) -> the units of work (small picklable values), sorted.
    unit_name: unit -> a readable, unique name (``segment/camera_1``) for progress and records.
    annotate: (input root, unit, config) -> the unit's candidate clips (plain Python, no Beam);
      InputError naming the file and the cause on bad input.
    sample_input: folder -> input root of the embedded sample world written (once) there;
      raises NoSample when the source has none.
    mask_min_agreement: config -> the mask filter's threshold for this source's clips.
    sweepable: config keys of this source's filter thresholds (``pipeline.audit sweep``).
    group_of: unit -> the key of the units annotated together, in one worker, when inputs they
      share are cheaper read once (DriveTrack: a segment's cameras share its lidar); None: each
      unit alone.
    annotate_group: (input root, units of one group, config) -> per unit, in order, its candidate
      clips or the exception that failed it (one unit's bad input fails that unit only, unless
      the input is shared); a list, or a generator that hands each unit on as soon as it is made
      (it is written before the next is annotated). Required with ``group_of``.
    """

    name: str
    list_units: Callable[[str, RunConfig], list]
    unit_name: Callable[[object], str]
    annotate: Callable[[str, object, RunConfig], list[ClipRecord]]
    sample_input: Callable[[str], str]
    mask_min_agreement: Callable[[RunConfig], float]
    sweepable: tuple[str, ...] = ()
    group_of: Callable[[object], object] | None = None
    annotate_group: Callable[[str, list, RunConfig], Iterable[list[ClipRecord] | Exception]] | None = None

    def group_key(self, unit) -> str:
        """The key ``pipeline.graph`` groups ``unit`` under: its group's, else its own name."""
        return str(self.group_of(unit)) if self.group_of else self.unit_name(unit)


# name -> module defining ``SOURCE``: adding a source is one folder and one line here.
BUILT_IN = {
    "adt": "pipeline.adt.source",
    "drivetrack": "pipeline.drivetrack.source",
    "pstudio": "pipeline.pstudio.source",
}
_registered: dict[str, Source] = {}


def register(source: Source) -> Source:
    """Add (or replace) a source at run time, e.g. a plug-in or a test's toy source."""
    _registered[source.name] = source
    return source


def unregister(name: str) -> None:
    _registered.pop(name, None)


def names() -> tuple[str, ...]:
    """Every source's name, sorted."""
    return tuple(sorted({*BUILT_IN, *_registered}))


def get(name: str) -> Source:
    """The source called ``name``; KeyError listing the known names otherwise."""
    if name in _registered:
        return _registered[name]
    if name not in BUILT_IN:
        raise KeyError(f"unknown source {name!r}; known: {', '.join(names())}")
    return importlib.import_module(BUILT_IN[name]).SOURCE
