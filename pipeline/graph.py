"""The Beam graph every source shares:

list units -> Reshuffle -> annotate (per source) -> filter tracks -> write clips -> finalize

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

from pipeline.core.clip import ClipRecord
from pipeline.core.config import RunConfig
from pipeline.core.errors import InputError
from pipeline.export.audit_table import encode_parquet, outcome_table
from pipeline.export.depth_export import encode_depth
from pipeline.export.files import list_files, read_bytes, write_atomic
from pipeline.export.manifests import load_official_splits, split_clips
from pipeline.export.npz_writer import clip_arrays, encode_npz
from pipeline.filters.select import FILTER_ORDER, FilterOutcome, apply_filters

FAILURES = "failures"
SOURCES = ("adt", "drivetrack", "pstudio")


def progress(message: str) -> None:
    """One progress line on stderr, from whichever worker process runs the step (Beam's worker
    log forwarding would hide logging records on some runners)."""
    print(f"{time.strftime('%H:%M:%S')} {message}", file=sys.stderr, flush=True)


def failure(unit: str, stage: str, error: BaseException) -> dict:
    """A failures_<source>.jsonl record; unexpected errors keep their innermost frame for debugging."""
    record = {"unit": unit, "stage": stage, "error": f"{type(error).__name__}: {error}"}
    if not isinstance(error, InputError):
        frame = traceback.extract_tb(error.__traceback__)[-1]
        record["where"] = f"{frame.filename}:{frame.lineno}"
    return record


class AnnotateDoFn(beam.DoFn):
    """Base of each source's annotate stage: a unit in, its clips out, or one failure record.

    A unit's clips are emitted only after the whole unit succeeded, so a unit that fails
    half-way contributes nothing but its failure line.
    """

    def __init__(self, input_root: str, config: RunConfig):
        self.input_root = input_root
        self.config = config

    @staticmethod
    def unit_name(unit) -> str:
        raise NotImplementedError

    def annotate(self, unit) -> list[ClipRecord]:
        raise NotImplementedError

    def process(self, unit):
        name = self.unit_name(unit)
        started = time.monotonic()
        try:
            clips = self.annotate(unit)
        except Exception as error:  # noqa: BLE001 - every failure becomes data
            progress(f"unit {name} FAILED: {error}")
            yield beam.pvalue.TaggedOutput(FAILURES, failure(name, "annotate", error))
            return
        progress(f"unit {name}: {len(clips)} clip(s) in {time.monotonic() - started:.1f} s")
        yield from clips


class WriteClip(beam.DoFn):
    """Write a filtered clip's audit table, its exported depth if any, then its .npz (atomically,
    in that order, so an existing .npz always has its companions). Emits a small report dict."""

    def __init__(self, output: str):
        self.output = output.rstrip("/")

    def process(self, element: tuple[ClipRecord, FilterOutcome]):
        kept, outcome = element
        try:
            write_atomic(
                f"{self.output}/audit/{kept.source}/{kept.name}.parquet",
                encode_parquet(outcome_table(outcome)),
            )
            if kept.num_tracks and kept.depth_export is not None:
                write_atomic(
                    f"{self.output}/depth/{kept.source}/{kept.name}.npz", encode_depth(kept.depth_export)
                )
            if kept.num_tracks:
                write_atomic(f"{self.output}/{kept.source}/{kept.name}.npz", encode_npz(clip_arrays(kept)))
            else:
                progress(f"clip {kept.name}: no track survived the filters; not written")
        except Exception as error:  # noqa: BLE001
            progress(f"clip {kept.name} FAILED: {error}")
            unit = f"{kept.unit} ({kept.name})"
            yield beam.pvalue.TaggedOutput(FAILURES, failure(unit, "write", error))
            return
        progress(f"clip {kept.name}: {kept.num_tracks} of {outcome.candidates} candidate tracks written")
        yield {
            "clip": kept.name,
            "source": kept.source,
            "unit": kept.unit,
            "frames": kept.num_frames,
            "candidates": outcome.candidates,
            "dropped": outcome.dropped_by(),
            "passed": outcome.passed,
            "written_tracks": kept.num_tracks,
            "target_tracks": kept.target_tracks,
        }


def summarize(reports: list[dict], failures: list[dict], units: int) -> dict:
    """Run totals: units, clips, tracks kept and dropped by each filter, failures."""
    written = [r for r in reports if r["written_tracks"] > 0]
    return {
        "units": units,
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
    """Runs once after every clip is written: failures, manifests, provenance."""

    def __init__(self, output: str, config: RunConfig, provenance: dict):
        self.output = output.rstrip("/")
        self.config = config
        self.provenance = provenance

    def process(self, _, reports, failures):
        failures = sorted(failures, key=lambda f: (f["unit"], f["stage"], f["error"]))
        lines = "".join(json.dumps(f, sort_keys=True) + "\n" for f in failures)
        source = self.provenance["source"]
        write_atomic(f"{self.output}/failures_{source}.jsonl", lines.encode())
        clips = {
            source: [p.rsplit("/", 1)[-1] for p in list_files(f"{self.output}/{source}/*.npz")]
            for source in SOURCES
        }
        clips = {source: names for source, names in clips.items() if names}
        official = None
        if self.config.splits_file:
            official = load_official_splits(read_bytes(self.config.splits_file).decode())
        minival, full_test = split_clips(clips, self.config.minival_per_source, self.config.seed, official)
        for name, entries in (("minival", minival), ("full_test", full_test)):
            text = "".join(entry + "\n" for entry in entries)
            write_atomic(f"{self.output}/manifests/{name}.txt", text.encode())
        summary = summarize(sorted(reports, key=lambda r: r["clip"]), failures, len(self.provenance["units"]))
        summary["manifests"] = {"minival": len(minival), "full_test": len(full_test)}
        record = dict(self.provenance, summary=summary)
        write_atomic(
            f"{self.output}/run_{source}.json", json.dumps(record, indent=2, sort_keys=True).encode()
        )
        yield summary


def build(
    pipeline: beam.Pipeline,
    units: list,
    annotate: AnnotateDoFn,
    output: str,
    config: RunConfig,
    provenance: dict,
) -> None:
    """Attach the whole run to ``pipeline``."""
    annotated = (
        pipeline
        | "ListUnits" >> beam.Create(units)
        | "Reshuffle" >> beam.Reshuffle()
        | "Annotate" >> beam.ParDo(annotate).with_outputs(FAILURES, main="clips")
    )
    written = (
        annotated.clips
        | "FilterTracks" >> beam.Map(apply_filters, config)
        | "WriteClips" >> beam.ParDo(WriteClip(output)).with_outputs(FAILURES, main="reports")
    )
    failures = (annotated[FAILURES], written[FAILURES]) | "AllFailures" >> beam.Flatten()
    _ = (
        pipeline
        | "Once" >> beam.Create([None])
        | "Finalize"
        >> beam.ParDo(
            Finalize(output, config, provenance),
            reports=beam.pvalue.AsList(written.reports),
            failures=beam.pvalue.AsList(failures),
        )
    )
