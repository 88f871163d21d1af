"""One unit of work, in plain Python: resume check -> annotate -> filter -> write -> checkpoint.

The Beam graph (``pipeline.runner.graph``) runs these stages as its named steps, the benchmarks call
``run_group`` for the same work without Beam, and resume is the first stage. Units of one group
(``Source.group_of``) are annotated together, each keeping its own outcome. Every unit ends with its
checkpoint (``pipeline/runner/ledger.py``): written after all its clips, also when it failed, so the
main process finishes the run (``pipeline.runner.finish``) from the checkpoints alone. A unit with a
failure is redone by the next run. Failures never escape a stage: they become ``Failure`` records
(the run goes on).
"""

from __future__ import annotations

import dataclasses
import functools
import time
import traceback
from collections.abc import Callable, Iterator, Mapping
from typing import TYPE_CHECKING

from pipeline.core.clip import ClipRecord
from pipeline.core.errors import InputError, OutputError, interruption
from pipeline.core.memory import release_freed_memory
from pipeline.core.outcomes import ClipReport, Failure, UnitClips, UnitOutcome
from pipeline.core.progress import progress, take_notes
from pipeline.export.audit_table import encode_parquet, outcome_table
from pipeline.export.depth_export import encode_depth
from pipeline.export.layout import audit_path, check_clip_name, clip_path, depth_path
from pipeline.export.npz_writer import clip_members, encode_npz
from pipeline.filters.select import FilterOutcome, apply_filters
from pipeline.io.files import remove_quietly, write_atomic
from pipeline.runner.checkpoint import ClipFile
from pipeline.runner.ledger import UnitLedger
from pipeline.runner.resume import run_fingerprint
from pipeline.runner.verdicts import unmade_reason
from pipeline.sources import RunChoices, Source, Unit, Wanted

if TYPE_CHECKING:
    from pipeline.settings.run_config import RunConfig


@dataclasses.dataclass(frozen=True)
class UnitJob:
    """What every stage of one run needs besides the unit: the source, where its input and output
    are, the settings, whether finished units are skipped, the run's id (in each checkpoint it writes)
    and, on a release run, the clips each unit is to make (unit name -> clip names)."""

    source: Source
    input_root: str
    config: RunConfig
    output: str
    resume: bool = True
    run_id: str = ""
    expected: Mapping[str, tuple[str, ...]] | None = None

    @functools.cached_property
    def ledger(self) -> UnitLedger:
        """The checkpoints of this run's units."""
        config, fingerprint = self.config, run_fingerprint(self.source.name, self.config)
        return UnitLedger(
            self.output, self.source.name, fingerprint, self.run_id, config.export_depth, config.resume_decode
        )

    def wanted(self, name: str) -> Wanted:
        """The clips unit ``name`` is to make on a release run; None: every clip it can make."""
        return None if self.expected is None else frozenset(self.expected.get(name, ()))


@dataclasses.dataclass(frozen=True)
class Annotated:
    """A unit's candidate clips on their way to the filter and write stages (``started``: when its
    annotation began, ``time.time()``; ``notes``: what its annotation could not do as asked)."""

    name: str
    made: UnitClips
    started: float
    notes: tuple[str, ...] = ()


@dataclasses.dataclass(frozen=True)
class Kept:
    """A clip through the filter stage: the clip with the tracks it keeps, and every verdict."""

    clip: ClipRecord
    outcome: FilterOutcome


@dataclasses.dataclass(frozen=True)
class Filtered:
    """A unit's clips after the filter stage: per clip, its ``Kept`` or its Failure."""

    name: str
    items: tuple[Kept | Failure, ...]
    not_made: Mapping[str, str]
    started: float
    notes: tuple[str, ...] = ()


def failure(unit: str, stage: str, error: BaseException, clip: str = "") -> Failure:
    """The Failure of an error; unexpected errors keep their innermost frame for debugging.
    An error with a Ctrl-C in its chain raises that KeyboardInterrupt: the run stops, the unit has
    not failed (numba has reported a Ctrl-C taken during a kernel's call as a SystemError,
    "returned a result with an exception set", caused by the KeyboardInterrupt)."""
    if (interrupted := interruption(error)) is not None:
        raise interrupted
    where = ""
    if not isinstance(error, (InputError, OutputError)):
        frame = traceback.extract_tb(error.__traceback__)[-1]
        where = f"{frame.filename}:{frame.lineno}"
    return Failure(unit, stage, f"{type(error).__name__}: {error}", clip, where)


def finished_earlier(job: UnitJob, name: str) -> UnitOutcome | None:
    """The outcome of the unit when an earlier run with these settings finished it (its clips intact
    on disk, every wanted clip accounted for), else None. Its checkpoint is stamped with this run."""
    if not job.resume:
        return None
    outcome = job.ledger.resume(name, job.wanted(name))
    if outcome is not None:
        progress(f"unit {name}: finished by an earlier run with these settings; skipped")
    return outcome


def annotate_group(job: UnitJob, units: list[Unit]) -> Iterator[UnitClips | Exception]:
    """The candidate clips of units annotated together (``Source.annotate_group``), or per unit the
    exception that failed it, handed on unit by unit as the source makes them (so a unit is written
    while its group's next is annotated)."""
    if not units:
        return  # every unit of the group finished earlier
    wanted = [job.wanted(unit.name) for unit in units]
    given = RunChoices.of(job.config, job.source.name).given
    made = job.source.annotate_group(job.input_root, units, job.config, wanted)
    for unit, result, keep in zip(units, made, wanted, strict=True):
        if isinstance(result, UnitClips) and keep is not None:
            result = only_wanted(result, keep, unmade_reason(unit.name, given))
        yield result


def only_wanted(made: UnitClips, wanted: frozenset[str], reason: Callable[[str], str]) -> UnitClips:
    """A unit's clips of the names ``wanted``; each wanted name it neither made nor explained gets
    ``reason(name)``, the same words whatever the source."""
    names = {clip.name for clip in made.clips} | set(made.not_made)
    return UnitClips(
        tuple(clip for clip in made.clips if clip.name in wanted),
        {
            **{name: why for name, why in made.not_made.items() if name in wanted},
            **{name: reason(name) for name in sorted(wanted - names)},
        },
    )


def filter_clip(job: UnitJob, clip: ClipRecord) -> Kept:
    """The filter stage with this source's thresholds: the kept clip and every verdict."""
    return Kept(*apply_filters(clip, job.config, job.source.mask_min_agreement(job.config)))


def write_clip(output: str, kept: ClipRecord, outcome: FilterOutcome) -> tuple[ClipReport, ClipFile | None]:
    """Write a filtered clip's audit table, its exported depth if any, then its .npz (each
    atomically, in that order, so an existing .npz always has its companions). Returns the clip's
    report and its .npz's file (None when no track was kept: then no .npz of that name is left in
    the folder)."""
    source, name = kept.source, check_clip_name(kept.name)
    files = {audit_path(output, source, name): encode_parquet(outcome_table(outcome))}
    written = None
    if kept.num_tracks:
        if kept.depth_export is not None:
            files[depth_path(output, source, name)] = encode_depth(kept.depth_export)
        data = encode_npz(clip_members(kept))
        files[clip_path(output, source, name)] = data
        written = ClipFile.of(data)
    for path, content in files.items():
        try:
            write_atomic(path, content)
        except OSError as error:
            raise OutputError(f"cannot write {path}: {error}") from error
    if not kept.num_tracks:  # an earlier run's clip of this name, under other settings
        remove_quietly([clip_path(output, source, name), depth_path(output, source, name)])
    report = ClipReport(
        clip=name,
        source=source,
        unit=kept.unit,
        frames=kept.num_frames,
        candidates=outcome.candidates,
        dropped=outcome.dropped_by(),
        passed=outcome.passed,
        written_tracks=kept.num_tracks,
        target_tracks=kept.target_tracks,
    )
    return report, written


def checkpoint(job: UnitJob, outcome: UnitOutcome, files: Mapping[str, ClipFile]) -> UnitOutcome:
    """Commit the unit: its checkpoint, after all its clips (``UnitLedger.commit``; ``files``: each
    written clip's file). Returns the outcome, with a ``checkpoint`` Failure when the checkpoint
    cannot be written."""
    try:
        job.ledger.commit(outcome, files, job.wanted(outcome.name))
    except OSError as error:
        problem = failure(
            outcome.name, "checkpoint", OutputError(f"cannot write the unit's checkpoint: {error}")
        )
        progress(f"unit {outcome.name} FAILED: {problem.error}")
        return dataclasses.replace(outcome, failures=(*outcome.failures, problem))
    return outcome


def filter_unit(job: UnitJob, annotated: Annotated) -> Filtered:
    """Each clip filtered: its ``Kept``, or a Failure when its filter stage fails."""
    items: list[Kept | Failure] = []
    for clip in annotated.made.clips:
        try:
            items.append(filter_clip(job, clip))
        except Exception as error:  # noqa: BLE001 - every failure becomes data
            items.append(failure(annotated.name, "clip", error, clip.name))
            progress(f"clip {clip.name} FAILED: {error}")
    return Filtered(annotated.name, tuple(items), annotated.made.not_made, annotated.started, annotated.notes)


def write_unit(job: UnitJob, filtered: Filtered, on_written=None) -> UnitOutcome:
    """Write a unit's filtered clips, then its checkpoint (the unit's commit point). ``on_written(kept,
    outcome, file)`` is called per clip written (``file``: its .npz's, None when it kept no track)."""
    failures = [item for item in filtered.items if isinstance(item, Failure)]
    reports, files = [], {}
    for item in filtered.items:
        if isinstance(item, Failure):
            continue
        kept, verdicts = item.clip, item.outcome
        try:
            report, written = write_clip(job.output, kept, verdicts)
        except Exception as error:  # noqa: BLE001
            failures.append(failure(filtered.name, "clip", error, kept.name))
            progress(f"clip {kept.name} FAILED: {error}")
            continue
        if on_written is not None:
            on_written(kept, verdicts, written)
        reports.append(report)
        if written is not None:
            files[report.clip] = written
    outcome = UnitOutcome(
        filtered.name,
        tuple(sorted(reports, key=lambda report: report.clip)),
        tuple(failures),
        dict(filtered.not_made),
        seconds=time.time() - filtered.started,
        notes=filtered.notes,
    )
    return checkpoint(job, outcome, files)


def annotate_units(job: UnitJob, units: list[Unit]) -> Iterator[UnitOutcome | Annotated]:
    """The resume check and the annotate stage of units of one group: per unit, its UnitOutcome
    when an earlier run finished it, then, as the others are annotated together, their candidate
    clips (``Annotated``) or, for a unit that failed, its checkpointed UnitOutcome."""
    todo: list[Unit] = []
    for item in units:
        name = item.name
        outcome = finished_earlier(job, name)
        if outcome is not None:
            yield outcome
        else:
            todo.append(item)
    started = time.time()
    for item, result in zip(todo, annotate_group(job, todo), strict=True):
        name, notes = item.name, take_notes()
        if isinstance(result, Exception):
            problem = failure(name, "annotate", result)
            progress(f"unit {name} FAILED: {result}")
            failed = UnitOutcome(name, failures=(problem,), seconds=time.time() - started, notes=notes)
            yield checkpoint(job, failed, {})
        else:
            yield Annotated(name, result, started, notes)
        started = time.time()


def run_group(job: UnitJob, units: list[Unit]) -> list[UnitOutcome]:
    """Every stage of units of one group in this process, as the graph's steps run them (the heap
    their arrays were freed from given back at the end, as a worker does)."""
    outcomes: dict[str, UnitOutcome] = {}
    for item in annotate_units(job, units):
        if isinstance(item, Annotated):
            outcomes[item.name] = write_unit(job, filter_unit(job, item))
        else:
            outcomes[item.name] = item
    release_freed_memory()
    return [outcomes[unit.name] for unit in units]
