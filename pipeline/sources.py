"""The registry of sources: each dataset the pipeline regenerates clips from is one ``Source``.

Everything that needs the list of sources (the command line, manifests, validate, sweep, compare,
the benchmarks) reads it here. A built-in source is one package and one line of ``BUILT_IN``
(``pipeline/settings/sections.py``, which the run's settings read too): ``<package>/source.py``
defines ``SOURCE``, ``<package>/settings.py`` its settings section ``SETTINGS``. A plug-in is
registered at run time (``register``), or named in the environment (``PLUGINS_ENV``: modules
defining ``SOURCE``), which worker processes inherit. A source is plain Python on arrays and files:
it never imports the run's orchestration (``pipeline/runner/``), which sits above it. Built-in
sources are imported on first use, so listing names and settings costs no heavy import.
"""

from __future__ import annotations

import dataclasses
import importlib
from collections.abc import Callable, Iterable, Iterator, Mapping
from typing import Any, Generic, Protocol, TypeVar

from pipeline.core.clip import ClipRecord
from pipeline.core.outcomes import UnitClips
from pipeline.io.given_queries import GivenQueries
from pipeline.settings import sections
from pipeline.settings.run_config import RunConfig

# The registry's lists, kept where the settings read them too (re-exported as the registry's own).
from pipeline.settings.sections import BUILT_IN as BUILT_IN
from pipeline.settings.sections import PLUGINS_ENV as PLUGINS_ENV
from pipeline.settings.sections import names as names
from pipeline.settings.sections import settings_of as settings_of
from pipeline.settings.sections import unregister as unregister


class NoSample(Exception):
    """A source without an embedded sample world; the message says how to get real input."""


class Unit(Protocol):
    """A unit of work: a small frozen record of the source's (``SegmentCamera``, ``SequenceChunk``,
    ``SequenceCamera``), picklable for the workers, ordered (a plan's units are sorted), and named
    uniquely and readably (``segment/camera_1``) for progress and checkpoints."""

    @property
    def name(self) -> str: ...

    def __lt__(self, other: Any, /) -> bool: ...


U = TypeVar("U", bound=Unit)


@dataclasses.dataclass(frozen=True)
class UnitPlan(Generic[U]):
    """The units of a run, listed from its input (on a release run, only those its clips need).

    units: the units of work, sorted.
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

    units: list[U]
    expected: Mapping[str, tuple[str, ...]] = dataclasses.field(default_factory=dict)
    absent: Mapping[str, str] = dataclasses.field(default_factory=dict)
    not_made: Mapping[str, str] = dataclasses.field(default_factory=dict)
    notes: tuple[str, ...] = ()
    scratch_per_worker: int = 0


# One unit's wanted clip names (a release run's), or None for every clip it can make.
Wanted = frozenset[str] | None


@dataclasses.dataclass(frozen=True)
class RunChoices:
    """What a source's annotation reads of the run's settings besides its own section (its entry
    hands its algorithm code these and its section, never the whole ``RunConfig``).

    seed: every random choice is seeded from it and the clip's name (``core.sampling.rng_for``).
    given: the source's clips of ``--queries-from`` (inactive without one): re-annotate their
      queries, and make only the clips found there.
    export_depth: also keep the depth each visibility test read (``ClipRecord.depth_export``).
    """

    seed: int
    given: GivenQueries
    export_depth: bool

    @classmethod
    def of(cls, config: RunConfig, source: str) -> RunChoices:
        return cls(config.seed, GivenQueries(config.queries_from, source, config.http), config.export_depth)

    def wants(self, clip: str, wanted: Wanted) -> bool:
        """Whether a unit is to make clip ``clip``: the run wants it (``wanted``: a release run's
        names, None: every clip) and ``--queries-from``, when given, holds it. A clip not wanted is
        not made, and the run says why (``pipeline.runner.stages.annotate_group``)."""
        return (wanted is None or clip in wanted) and self.given.admits(clip)


@dataclasses.dataclass(frozen=True)
class Licence:
    """The terms a source's data is used under, as a training run's dataset card names them: the
    terms in words, and the pages that state them."""

    terms: str
    links: tuple[str, ...]


@dataclasses.dataclass(frozen=True)
class Source(Generic[U]):
    """One dataset, as the pipeline sees it, its units of type U.

    name: the ``--source`` value and the folder of its clips (``<out>/<name>/<clip>.npz``).
    list_units: (input root, config, release clip names or None) -> its UnitPlan; InputError when
      the input cannot be listed.
    annotate_group: (input root, units of one group, config, per unit its Wanted) -> an iterator:
      per unit, in order, its ``UnitClips`` or the exception that failed it (one unit's bad input
      fails that unit only, unless the input is shared), each handed on as soon as it is made (it is
      written before the next is annotated). A unit makes only the clips ``RunChoices.wants``; the
      run says why for each wanted name it does not make. A source that works unit by unit wraps
      its per-unit function with ``one_by_one``.
    sample_input: folder -> input root of the embedded sample world written (once) there;
      raises NoSample when the source has none.
    has_sample: False for a source without an embedded sample world: a run without ``--input`` is
      refused before any work, with ``sample_input``'s NoSample message.
    reclaim_scratch: config -> bytes freed: delete what killed workers left in the source's scratch
      folder (a run stopped by Ctrl-C or SIGTERM calls it once its worker processes are gone).
    demo_args: () -> what ``python -m pipeline.demo`` adds to ``--source <name>`` (an input and
      settings; NoSample saying why when it cannot run here); None: a run on the sample world.
    mask_min_agreement: config -> the mask filter's threshold for this source's clips.
    sweepable: config keys of this source's filter thresholds (``pipeline.audit sweep``).
    group_of: unit -> the key of the units annotated together, in one worker, when inputs they
      share are cheaper read once (DriveTrack: a segment's cameras share its lidar); None: each
      unit alone.
    settings: the dataclass of the source's settings section (``--set <name>.<field>``), or None.
    bench: the module of the source's benchmark entry (``python -m benchmarks <name>``, see
      ``benchmarks/__init__.py``): a built-in source's ``pipeline/<name>/bench.py``.
    scene_of: unit -> its scene, what a benchmark clip of the same place and time shares with it
      (DriveTrack: the Waymo segment; ADT: the sequence's v1 name; Panoptic Studio: the sequence).
    clip_scene: a benchmark clip name (without ``.npz``) -> its scene, None when the name is not one
      of the source's. A training run (``--training``) drops every unit whose scene a clip of the
      benchmark's splits file comes from; a source without these two cannot make a training run.
    licence: the terms its data is used under, for a training run's dataset card; None: not stated.
    """

    name: str
    list_units: Callable[[str, RunConfig, frozenset[str] | None], UnitPlan[U]]
    annotate_group: Callable[[str, list[U], RunConfig, list[Wanted]], Iterable[UnitClips | Exception]]
    sample_input: Callable[[str], str]
    mask_min_agreement: Callable[[RunConfig], float]
    sweepable: tuple[str, ...] = ()
    group_of: Callable[[U], str] | None = None
    settings: type | None = None
    bench: str = ""
    has_sample: bool = True
    reclaim_scratch: Callable[[RunConfig], int] | None = None
    demo_args: Callable[[], list[str]] | None = None
    scene_of: Callable[[U], str] | None = None
    clip_scene: Callable[[str], str | None] | None = None
    licence: Licence | None = None

    @property
    def bench_module(self) -> str:
        """The benchmark entry's module; a source without one has none to benchmark."""
        if not self.bench:
            raise LookupError(f"source {self.name!r} names no benchmark entry (Source.bench)")
        return self.bench

    def group_key(self, unit: U) -> str:
        """The key ``pipeline.runner.graph`` groups ``unit`` under: its group's, else its own name."""
        return self.group_of(unit) if self.group_of else unit.name


def one_by_one(
    annotate: Callable[[str, U, RunConfig], list[ClipRecord]],
) -> Callable[[str, list[U], RunConfig, list[Wanted]], Iterator[UnitClips | Exception]]:
    """The ``annotate_group`` of a source that annotates each unit alone with ``annotate(input root,
    unit, config) -> its candidate clips``: per unit its clips, or the exception that failed it; a
    unit of which the run wants no clip is not annotated."""

    def annotate_each(
        input_root: str, units: list[U], config: RunConfig, wanted: list[Wanted]
    ) -> Iterator[UnitClips | Exception]:
        for unit, keep in zip(units, wanted, strict=True):
            if keep is not None and not keep:
                yield UnitClips(())
                continue
            try:
                yield UnitClips(tuple(annotate(input_root, unit, config)))
            except Exception as error:  # noqa: BLE001 - every failure becomes data
                yield error

    return annotate_each


def register(source: Source[Any]) -> Source[Any]:
    """Add (or replace) a source at run time, e.g. a plug-in or a test's toy source."""
    sections.register(source)
    return source


def get(name: str) -> Source[Any]:
    """The source called ``name``; KeyError listing the known names otherwise."""
    source = sections.registered(name)
    if source is not None:
        return source
    if name not in BUILT_IN:
        raise KeyError(f"unknown source {name!r}; known: {', '.join(names())}")
    return importlib.import_module(f"{BUILT_IN[name]}.source").SOURCE
