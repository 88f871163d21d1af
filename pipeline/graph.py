"""The Beam graph every source shares:

list units -> Reshuffle -> process each unit -> gather under one key -> finalize

Processing a unit does all of its work in one step: skip it when an earlier run with the same
settings finished it (pipeline/resume.py), else annotate it (per source), filter each clip's
tracks, write the clips, then the unit's record. One step per unit keeps the graph to
transforms every Beam runner executes alike (including the Dask runner, which has no
multi-output ParDo), and makes the unit record a true commit point.

Failures of any unit or clip become records, written to ``failures_<source>.jsonl``; the rest
of the run goes on. Finalize writes the manifests (over every source in the output folder),
``failures_<source>.jsonl`` and ``run_<source>.json``, so the three sources can share one
output folder without overwriting each other's records.
"""

from __future__ import annotations

import json
import sys
import time
import traceback

import apache_beam as beam
from apache_beam.options.pipeline_options import PipelineOptions

from pipeline import storage
from pipeline.core.clip import ClipRecord
from pipeline.core.config import RunConfig
from pipeline.core.errors import InputError, OutputError
from pipeline.export.audit_table import encode_parquet, outcome_table
from pipeline.export.depth_export import encode_depth
from pipeline.export.files import list_files, remove_quietly, write_atomic
from pipeline.export.layout import audit_path, check_clip_name, clip_path, depth_path
from pipeline.export.manifests import split_clips
from pipeline.export.npz_writer import clip_arrays, encode_npz
from pipeline.filters.select import FILTER_ORDER, FilterOutcome, apply_filters
from pipeline.resume import (
    finished_reports,
    read_unit_record,
    remove_stale_clips,
    run_fingerprint,
    sha256,
    write_unit_record,
)

SOURCES = ("adt", "drivetrack", "pstudio")
# Kinds of the (kind, value) pairs a unit emits.
REPORT, FAILURE, RESUMED, START = "report", "failure", "resumed", "start"


def progress(message: str) -> None:
    """One progress line on stderr, from whichever worker process runs the step (Beam's worker
    log forwarding would hide logging records on some runners)."""
    print(f"{time.strftime('%H:%M:%S')} {message}", file=sys.stderr, flush=True)


def failure(unit: str, stage: str, error: BaseException) -> dict:
    """A failures_<source>.jsonl record; unexpected errors keep their innermost frame for debugging."""
    record = {"unit": unit, "stage": stage, "error": f"{type(error).__name__}: {error}"}
    if not isinstance(error, (InputError, OutputError)):
        frame = traceback.extract_tb(error.__traceback__)[-1]
        record["where"] = f"{frame.filename}:{frame.lineno}"
    return record


class Annotator:
    """Base of each source's annotator: a unit in, its clips out (raising InputError on bad input)."""

    def __init__(self, input_root: str, config: RunConfig):
        self.input_root = input_root
        self.config = config

    @staticmethod
    def unit_name(unit) -> str:
        raise NotImplementedError

    def annotate(self, unit) -> list[ClipRecord]:
        raise NotImplementedError


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
        data = encode_npz(clip_arrays(kept))
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


class ProcessUnit(beam.DoFn):
    """One unit, whole. Emits ("resumed", unit) when an earlier run finished it, a ("report", dict)
    per clip, and a ("failure", dict) per failed unit or clip. A unit's record is written only
    when every clip of it was written, so a unit with a failed clip is redone by a rerun."""

    def __init__(
        self,
        annotator: Annotator,
        source: str,
        output: str,
        resume: bool,
        options: PipelineOptions | None = None,
    ):
        self.annotator = annotator
        self.source = source
        self.output = output.rstrip("/")
        self.resume = resume
        self.options = options

    def setup(self):
        storage.use_options(self.options)  # Beam's Dask runner gives its workers no filesystem options

    def process(self, unit):
        name, source, config = self.annotator.unit_name(unit), self.source, self.annotator.config
        fingerprint = run_fingerprint(source, config)
        record = read_unit_record(self.output, source, name)
        if self.resume:
            reports = finished_reports(record, self.output, source, fingerprint, config.export_depth)
            if reports is not None:
                progress(f"unit {name}: finished by an earlier run with these settings; skipped")
                yield RESUMED, name
                yield from ((REPORT, report) for report in reports)
                return
        started = time.monotonic()
        try:
            clips = self.annotator.annotate(unit)
        except Exception as error:  # noqa: BLE001 - every failure becomes data
            progress(f"unit {name} FAILED: {error}")
            yield FAILURE, failure(name, "annotate", error)
            return
        progress(f"unit {name}: {len(clips)} clip(s) in {time.monotonic() - started:.1f} s")
        reports, digests = [], {}
        for clip in clips:
            try:
                report, digest = write_clip(self.output, *apply_filters(clip, config))
            except Exception as error:  # noqa: BLE001
                progress(f"clip {clip.name} FAILED: {error}")
                yield FAILURE, failure(f"{name} ({clip.name})", "clip", error)
                continue
            reports.append(report)
            if digest:
                digests[report["clip"]] = digest
        if len(reports) == len(clips):
            try:
                remove_stale_clips(record, self.output, source, {r["clip"] for r in reports})
                write_unit_record(self.output, source, name, fingerprint, reports, digests)
            except OSError as error:
                unrecorded = OutputError(f"cannot record the finished unit: {error}")
                yield FAILURE, failure(name, "record", unrecorded)
        yield from ((REPORT, report) for report in reports)


def summarize(reports: list[dict], failures: list[dict], units: int, resumed: int) -> dict:
    """Run totals: units, clips, tracks kept and dropped by each filter, failures."""
    written = [r for r in reports if r["written_tracks"] > 0]
    return {
        "units": units,
        "units_resumed": resumed,
        "units_failed": len({f["unit"] for f in failures if f["stage"] == "annotate"}),
        "clips_annotated": len(reports),
        "clips_written": len(written),
        "clips_below_target": sum(r["written_tracks"] < r["target_tracks"] for r in written),
        "candidate_tracks": sum(r["candidates"] for r in reports),
        "dropped_by_filter": {name: sum(r["dropped"][name] for r in reports) for name in FILTER_ORDER},
        "tracks_passing_filters": sum(r["passed"] for r in reports),
        "tracks_written": sum(r["written_tracks"] for r in reports),
        "failures": len(failures),
    }


class Finalize(beam.DoFn):
    """Runs once, on every unit's (kind, value) pairs: failures, manifests, provenance."""

    def __init__(
        self,
        output: str,
        config: RunConfig,
        provenance: dict,
        official: tuple[dict, dict] | None,
        options: PipelineOptions | None = None,
    ):
        self.output = output.rstrip("/")
        self.config = config
        self.provenance = provenance
        self.official = official
        self.options = options

    def setup(self):
        storage.use_options(self.options)

    def process(self, keyed):
        _, outcomes = keyed
        outcomes = list(outcomes)
        reports = sorted((value for kind, value in outcomes if kind == REPORT), key=lambda r: r["clip"])
        failures = sorted(
            (value for kind, value in outcomes if kind == FAILURE),
            key=lambda f: (f["unit"], f["stage"], f["error"]),
        )
        resumed = sum(kind == RESUMED for kind, _ in outcomes)
        lines = "".join(json.dumps(f, sort_keys=True) + "\n" for f in failures)
        source = self.provenance["source"]
        write_atomic(f"{self.output}/failures_{source}.jsonl", lines.encode())
        clips = {
            source: [p.rsplit("/", 1)[-1] for p in list_files(f"{self.output}/{source}/*.npz")]
            for source in SOURCES
        }
        clips = {source: names for source, names in clips.items() if names}
        minival, full_test = split_clips(
            clips, self.config.minival_per_source, self.config.seed, self.official
        )
        for name, entries in (("minival", minival), ("full_test", full_test)):
            text = "".join(entry + "\n" for entry in entries)
            write_atomic(f"{self.output}/manifests/{name}.txt", text.encode())
        summary = summarize(reports, failures, len(self.provenance["units"]), resumed)
        summary["manifests"] = {"minival": len(minival), "full_test": len(full_test)}
        record = dict(self.provenance, summary=summary)
        write_atomic(
            f"{self.output}/run_{source}.json", json.dumps(record, indent=2, sort_keys=True).encode()
        )
        yield summary


def under_one_key(outcome: tuple[str, object]) -> tuple[None, tuple[str, object]]:
    return None, outcome


def build(
    pipeline: beam.Pipeline,
    units: list,
    process_unit: ProcessUnit,
    config: RunConfig,
    provenance: dict,
    official: tuple[dict, dict] | None = None,
) -> None:
    """Attach the whole run to ``pipeline``. Finalize sees the outcome of every unit through one
    GroupByKey (plus a start marker, so it runs even when no unit emits anything)."""
    outcomes = (
        pipeline
        | "ListUnits" >> beam.Create(units)
        | "Reshuffle" >> beam.Reshuffle()
        | "ProcessUnits" >> beam.ParDo(process_unit)
    )
    start = pipeline | "Start" >> beam.Create([(START, None)])
    finalize = Finalize(process_unit.output, config, provenance, official, process_unit.options)
    _ = (
        (outcomes, start)
        | "AllOutcomes" >> beam.Flatten()
        | "UnderOneKey" >> beam.Map(under_one_key)
        | "Gather" >> beam.GroupByKey()
        | "Finalize" >> beam.ParDo(finalize)
    )
