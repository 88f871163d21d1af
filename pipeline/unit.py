"""One unit of work, in plain Python: resume check -> annotate -> filter -> write -> record.

The Beam graph (``pipeline.graph``) runs these stages as its named steps, the benchmarks call
``run_group`` for the same work without Beam, and resume is the first stage. Units of one group
(``Source.group_of``) are annotated together, each keeping its own outcome. A unit's record is
written only when every one of its clips was written, so a unit with a failed clip is redone by
a rerun. Failures never escape a stage: they become ``failure`` records (the run goes on).
"""

from __future__ import annotations

import dataclasses
import time
import traceback
from collections.abc import Iterator

from pipeline.core.clip import ClipRecord
from pipeline.core.config import RunConfig
from pipeline.core.errors import InputError, OutputError, root_cause
from pipeline.core.progress import progress
from pipeline.export.audit_table import encode_parquet, outcome_table
from pipeline.export.depth_export import encode_depth
from pipeline.export.files import remove_quietly, write_atomic
from pipeline.export.layout import audit_path, check_clip_name, clip_path, depth_path
from pipeline.export.npz_writer import clip_members, encode_npz
from pipeline.filters.select import FilterOutcome, apply_filters
from pipeline.resume import (
    finished_reports,
    read_unit_record,
    remove_stale_clips,
    run_fingerprint,
    sha256,
    write_unit_record,
)
from pipeline.sources import Source

# What ``annotate_units`` says of a unit.
CLIPS, FAILURE, RESUMED = "clips", "failure", "resumed"


@dataclasses.dataclass(frozen=True)
class UnitJob:
    """What every stage of one run needs besides the unit: the source, where its input and output
    are, the settings, and whether finished units are skipped."""

    source: Source
    input_root: str
    config: RunConfig
    output: str
    resume: bool = True

    @property
    def fingerprint(self) -> str:
        return run_fingerprint(self.source.name, self.config)


@dataclasses.dataclass
class UnitOutcome:
    """What became of one unit: its clips' reports, its failures, and whether an earlier run had
    finished it (then nothing was redone)."""

    name: str
    reports: list[dict] = dataclasses.field(default_factory=list)
    failures: list[dict] = dataclasses.field(default_factory=list)
    resumed: bool = False


def failure(unit: str, stage: str, error: BaseException) -> dict:
    """A failures_<source>.jsonl record; unexpected errors keep their innermost frame for debugging.
    An error whose innermost cause is a Ctrl-C raises that KeyboardInterrupt: the run stops, the
    unit has not failed (numba has reported a Ctrl-C taken during a kernel's call as a
    SystemError, "returned a result with an exception set", caused by the KeyboardInterrupt)."""
    if isinstance(cause := root_cause(error), KeyboardInterrupt):
        raise cause
    record = {"unit": unit, "stage": stage, "error": f"{type(error).__name__}: {error}"}
    if not isinstance(error, (InputError, OutputError)):
        frame = traceback.extract_tb(error.__traceback__)[-1]
        record["where"] = f"{frame.filename}:{frame.lineno}"
    return record


def finished_earlier(job: UnitJob, name: str) -> list[dict] | None:
    """The clip reports of the unit when an earlier run with these settings finished it (its clips
    intact on disk), else None."""
    if not job.resume:
        return None
    record = read_unit_record(job.output, job.source.name, name)
    reports = finished_reports(record, job.output, job.source.name, job.fingerprint, job.config.export_depth)
    if reports is not None:
        progress(f"unit {name}: finished by an earlier run with these settings; skipped")
    return reports


def annotate(job: UnitJob, unit) -> list[ClipRecord]:
    """The unit's candidate clips (raises on bad input; ``run_unit`` and the graph record it)."""
    started = time.monotonic()
    clips = job.source.annotate(job.input_root, unit, job.config)
    progress(f"unit {job.source.unit_name(unit)}: {len(clips)} clip(s) in {time.monotonic() - started:.1f} s")
    return clips


def annotate_group(job: UnitJob, units: list) -> Iterator[list[ClipRecord] | Exception]:
    """The candidate clips of units annotated together (``Source.annotate_group``), or per unit the
    exception that failed it, handed on unit by unit as the source makes them (so a unit is written
    while its group's next is annotated); a source without groups annotates each through
    ``annotate``."""
    if not units:
        return  # every unit of the group finished earlier
    if job.source.annotate_group is None:
        for item in units:
            try:
                result = annotate(job, item)
            except Exception as error:  # noqa: BLE001 - every failure becomes data
                result = error
            yield result
        return
    started = time.monotonic()
    made = job.source.annotate_group(job.input_root, units, job.config)
    for item, result in zip(units, made, strict=True):
        if not isinstance(result, Exception):
            progress(
                f"unit {job.source.unit_name(item)}: {len(result)} clip(s) in "
                f"{time.monotonic() - started:.1f} s (annotated with its group of {len(units)})"
            )
        yield result
        started = time.monotonic()


def filter_clip(job: UnitJob, clip: ClipRecord) -> tuple[ClipRecord, FilterOutcome]:
    """The filter stage with this source's thresholds: the kept clip and every verdict."""
    return apply_filters(clip, job.config, job.source.mask_min_agreement(job.config))


def _write(path: str, data: bytes) -> None:
    try:
        write_atomic(path, data)
    except OSError as error:
        raise OutputError(f"cannot write {path}: {error}") from error


def write_clip(output: str, kept: ClipRecord, outcome: FilterOutcome) -> tuple[dict, str | None]:
    """Write a filtered clip's audit table, its exported depth if any, then its .npz (each
    atomically, in that order, so an existing .npz always has its companions). Returns the clip's
    report and the SHA-256 of its .npz (None when no track survived: then no .npz of that name
    is left in the folder)."""
    source, name = kept.source, check_clip_name(kept.name)
    _write(audit_path(output, source, name), encode_parquet(outcome_table(outcome)))
    digest = None
    if kept.num_tracks:
        if kept.depth_export is not None:
            _write(depth_path(output, source, name), encode_depth(kept.depth_export))
        data = encode_npz(clip_members(kept))
        _write(clip_path(output, source, name), data)
        digest = sha256(data)
        progress(f"clip {name}: {kept.num_tracks} of {outcome.candidates} candidate tracks written")
    else:
        # an earlier run's clip of this name, under other settings
        remove_quietly([clip_path(output, source, name), depth_path(output, source, name)])
        progress(f"clip {name}: no track survived the filters; not written")
    report = {
        "clip": name,
        "source": source,
        "unit": kept.unit,
        "frames": kept.num_frames,
        "candidates": outcome.candidates,
        "dropped": outcome.dropped_by(),
        "passed": outcome.passed,
        "written_tracks": kept.num_tracks,
        "target_tracks": kept.target_tracks,
    }
    return report, digest


def record_unit(job: UnitJob, name: str, reports: list[dict], digests: dict[str, str]) -> list[dict]:
    """After all of a unit's clips were written: remove the files of clips an earlier record listed
    that this run no longer makes, then write the unit's record. Returns failures (none, or one
    when the record cannot be written)."""
    try:
        previous = read_unit_record(job.output, job.source.name, name)
        remove_stale_clips(previous, job.output, job.source.name, {r["clip"] for r in reports})
        write_unit_record(job.output, job.source.name, name, job.fingerprint, reports, digests)
    except OSError as error:
        return [failure(name, "record", OutputError(f"cannot record the finished unit: {error}"))]
    return []


def filter_unit(job: UnitJob, name: str, clips: list[ClipRecord]) -> list:
    """Each clip filtered: (kept clip, outcome), or a failure record when its filter stage fails."""
    filtered = []
    for clip in clips:
        try:
            filtered.append(filter_clip(job, clip))
        except Exception as error:  # noqa: BLE001 - every failure becomes data
            filtered.append(failure(f"{name} ({clip.name})", "clip", error))
            progress(f"clip {clip.name} FAILED: {error}")
    return filtered


def write_unit(job: UnitJob, name: str, filtered: list, on_written=None) -> UnitOutcome:
    """Write a unit's filtered clips (``filter_unit``), then its record when every clip was written
    (the unit's commit point). ``on_written(kept, outcome, digest)`` is called per written clip."""
    outcome, digests = UnitOutcome(name), {}
    outcome.failures = [item for item in filtered if isinstance(item, dict)]
    for kept, verdicts in (item for item in filtered if not isinstance(item, dict)):
        try:
            report, digest = write_clip(job.output, kept, verdicts)
        except Exception as error:  # noqa: BLE001
            outcome.failures.append(failure(f"{name} ({kept.name})", "clip", error))
            progress(f"clip {kept.name} FAILED: {error}")
            continue
        if on_written is not None:
            on_written(kept, verdicts, digest)
        outcome.reports.append(report)
        if digest:
            digests[report["clip"]] = digest
    outcome.reports.sort(key=lambda report: report["clip"])
    if not outcome.failures:
        outcome.failures = record_unit(job, name, outcome.reports, digests)
    return outcome


def annotate_units(job: UnitJob, units: list) -> Iterator[tuple[str, str, object]]:
    """The resume check and the annotate stage of units of one group: per unit, (name, RESUMED,
    its reports) when an earlier run finished it, then, as the others are annotated together,
    (name, CLIPS, its candidate clips) or (name, FAILURE, its failure record)."""
    todo = []
    for item in units:
        name = job.source.unit_name(item)
        reports = finished_earlier(job, name)
        if reports is not None:
            yield name, RESUMED, reports
        else:
            todo.append(item)
    for item, result in zip(todo, annotate_group(job, todo), strict=True):
        name = job.source.unit_name(item)
        if isinstance(result, Exception):
            record = failure(name, "annotate", result)
            progress(f"unit {name} FAILED: {result}")
            yield name, FAILURE, record
        else:
            yield name, CLIPS, result


def run_group(job: UnitJob, units: list) -> list[UnitOutcome]:
    """Every stage of units of one group in this process, as the graph's steps run them."""
    outcomes: dict[str, UnitOutcome] = {}
    for name, kind, value in annotate_units(job, units):
        if kind == RESUMED:
            outcomes[name] = UnitOutcome(name, value, resumed=True)
        elif kind == FAILURE:
            outcomes[name] = UnitOutcome(name, failures=[value])
        else:
            outcomes[name] = write_unit(job, name, filter_unit(job, name, value))
    return [outcomes[job.source.unit_name(item)] for item in units]


def run_unit(job: UnitJob, unit) -> UnitOutcome:
    """Every stage of one unit in this process (``run_group`` of that unit alone)."""
    return run_group(job, [unit])[0]
