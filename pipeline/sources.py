"""The registry of sources: each dataset the pipeline regenerates clips from is one ``Source``.

Everything that needs the list of sources (the command line, the settings' sections, manifests,
validate, sweep, compare, the benchmarks) reads it here. A built-in source is one package and one
line of ``BUILT_IN``: ``<package>/source.py`` defines ``SOURCE``, ``<package>/settings.py`` its
settings section ``SETTINGS``. A plug-in is registered at run time (``register``), or named in the
environment (``PLUGINS_ENV``: modules defining ``SOURCE``), which worker processes inherit.
A source is plain Python on arrays and files: it never imports the Beam shell (``pipeline.graph``)
nor the per-unit driver (``pipeline.unit``), which sit above it. Built-in sources are imported on
first use, so listing names and settings costs no heavy import.
"""

from __future__ import annotations

import dataclasses
import importlib
import os
from collections.abc import Callable, Iterable, Iterator, Mapping
from typing import TYPE_CHECKING

from pipeline.core.clip import ClipRecord
from pipeline.core.outcomes import UnitClips

if TYPE_CHECKING:
    from pipeline.settings import RunConfig

# Modules defining a plug-in's ``SOURCE``, comma-separated, registered on the registry's first use.
PLUGINS_ENV = "TAPVID3D_SOURCES"


class NoSample(Exception):
    """A source without an embedded sample world; the message says how to get real input."""


@dataclasses.dataclass(frozen=True)
class UnitPlan:
    """The units of a run, listed from its input (on a release run, only those its clips need).

    units: the units of work (small picklable values), sorted.
    expected: on a release run, unit name -> the release's clips that unit is to make.
    absent: on a release run, release clip -> why no unit of the input makes it (the segment,
      sequence or camera is not in ``--input``; a run on the sample world says ``the sample world``
      instead, ``prepare.plan_units``).
    not_made: on a release run, release clip -> why the input, as the settings read it, makes no
      clip of that name (a chunk past a sequence's end, a camera the settings leave out).
    notes: lines to print before the run starts (what the run will fetch, where).
    scratch_per_worker: the most scratch disk one worker needs at a time (bytes; 0: none), printed
      with the number of workers at start.
    """

    units: list
    expected: Mapping[str, tuple[str, ...]] = dataclasses.field(default_factory=dict)
    absent: Mapping[str, str] = dataclasses.field(default_factory=dict)
    not_made: Mapping[str, str] = dataclasses.field(default_factory=dict)
    notes: tuple[str, ...] = ()
    scratch_per_worker: int = 0


# One unit's wanted clip names (a release run's), or None for every clip it can make.
Wanted = frozenset[str] | None


@dataclasses.dataclass(frozen=True)
class Source:
    """One dataset, as the pipeline sees it.

    name: the ``--source`` value and the folder of its clips (``<out>/<name>/<clip>.npz``).
    list_units: (input root, config, release clip names or None) -> its UnitPlan; InputError when
      the input cannot be listed.
    unit_name: unit -> a readable, unique name (``segment/camera_1``) for progress and records.
    annotate_group: (input root, units of one group, config, per unit its Wanted) -> per unit, in
      order, its ``UnitClips`` or the exception that failed it (one unit's bad input fails that unit
      only, unless the input is shared); a list, or a generator that hands each unit on as soon as
      it is made (it is written before the next is annotated). A source that works unit by unit
      wraps its per-unit function with ``one_by_one``.
    sample_input: folder -> input root of the embedded sample world written (once) there;
      raises NoSample when the source has none.
    mask_min_agreement: config -> the mask filter's threshold for this source's clips.
    sweepable: config keys of this source's filter thresholds (``pipeline.audit sweep``).
    group_of: unit -> the key of the units annotated together, in one worker, when inputs they
      share are cheaper read once (DriveTrack: a segment's cameras share its lidar); None: each
      unit alone.
    settings: the dataclass of the source's settings section (``--set <name>.<field>``), or None.
    bench: the module of the source's benchmark entry (``python -m benchmarks <name>``, see
      ``benchmarks/__init__.py``); default ``benchmarks.<name>``.
    """

    name: str
    list_units: Callable[[str, RunConfig, frozenset[str] | None], UnitPlan]
    unit_name: Callable[[object], str]
    annotate_group: Callable[[str, list, RunConfig, list[Wanted]], Iterable[UnitClips | Exception]]
    sample_input: Callable[[str], str]
    mask_min_agreement: Callable[[RunConfig], float]
    sweepable: tuple[str, ...] = ()
    group_of: Callable[[object], object] | None = None
    settings: type | None = None
    bench: str = ""

    @property
    def bench_module(self) -> str:
        return self.bench or f"benchmarks.{self.name}"

    def group_key(self, unit) -> str:
        """The key ``pipeline.graph`` groups ``unit`` under: its group's, else its own name."""
        return str(self.group_of(unit)) if self.group_of else self.unit_name(unit)


def one_by_one(
    annotate: Callable[[str, object, RunConfig], list[ClipRecord]],
) -> Callable[[str, list, RunConfig, list[Wanted]], Iterator[UnitClips | Exception]]:
    """The ``annotate_group`` of a source that annotates each unit alone with ``annotate(input root,
    unit, config) -> its candidate clips``: per unit its clips, or the exception that failed it."""

    def annotate_each(input_root: str, units: list, config: RunConfig, wanted: list[Wanted]):
        for unit in units:
            try:
                result = UnitClips(tuple(annotate(input_root, unit, config)))
            except Exception as error:  # noqa: BLE001 - every failure becomes data
                result = error
            yield result

    return annotate_each


# name -> the package of a built-in source. Sources are listed in this order (tapnet's evaluation
# order, in which its overall score sums the sources' means), then plug-ins.
BUILT_IN = {
    "drivetrack": "pipeline.drivetrack",
    "adt": "pipeline.adt",
    "pstudio": "pipeline.pstudio",
}
_registered: dict[str, Source] = {}
_plugins_loaded = False


def register(source: Source) -> Source:
    """Add (or replace) a source at run time, e.g. a plug-in or a test's toy source."""
    _registered[source.name] = source
    return source


def unregister(name: str) -> None:
    _registered.pop(name, None)


def _load_plugins() -> None:
    """Register the sources of the modules ``PLUGINS_ENV`` names (once per process)."""
    global _plugins_loaded
    if _plugins_loaded:
        return
    _plugins_loaded = True
    for module in filter(None, (part.strip() for part in os.environ.get(PLUGINS_ENV, "").split(","))):
        register(importlib.import_module(module).SOURCE)


def names() -> tuple[str, ...]:
    """Every source's name: the built-in ones in ``BUILT_IN``'s order, then plug-ins in the order
    they were registered."""
    _load_plugins()
    return (*BUILT_IN, *(name for name in _registered if name not in BUILT_IN))


def get(name: str) -> Source:
    """The source called ``name``; KeyError listing the known names otherwise."""
    _load_plugins()
    if name in _registered:
        return _registered[name]
    if name not in BUILT_IN:
        raise KeyError(f"unknown source {name!r}; known: {', '.join(names())}")
    return importlib.import_module(f"{BUILT_IN[name]}.source").SOURCE


def settings_of(name: str) -> type | None:
    """The settings section class of source ``name`` (None for a source without settings), read for
    a built-in source from its light ``settings`` module."""
    _load_plugins()
    if name in _registered:
        return _registered[name].settings
    return importlib.import_module(f"{BUILT_IN[name]}.settings").SETTINGS
