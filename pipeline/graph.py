"""The Beam shell: one composite transform per run, its steps named like the data flow.

    Units -> ByGroup -> Group -> Annotate -> Filter -> Write -> Gather -> Finalize

Each step calls the plain stage of ``pipeline.unit`` (the benchmarks call the same stages through
``unit.run_group``). Group hands each worker the units of one group (``Source.group_of``: a
DriveTrack segment's cameras, which share one read of its lidar; else each unit alone), and
spreads the groups over the workers. After Annotate an element is one unit's
``(name, (kind, value))`` in one PCollection, the only shape every runner executes alike (Beam's
Dask runner has no multi-output ParDo): Annotate skips a unit an earlier run finished or emits
all its clips, Filter decides their tracks, Write
writes them and then the unit's record (its commit point: a unit is never split across workers,
and a killed run loses only the units in flight), and Finalize writes the failures, the
manifests (over every source in the output folder) and the run record. Failures of any unit or
clip become records; the run goes on.

Counters (``apache_beam.metrics``, namespace ``tapvid3d``): units_read, units_resumed,
units_failed, clips_annotated, clips_written, tracks_written, tracks_dropped_<filter>.
"""

from __future__ import annotations

import json

import apache_beam as beam
from apache_beam.metrics import Metrics
from apache_beam.options.pipeline_options import PipelineOptions

from pipeline import sources, storage, unit
from pipeline.export.files import list_files, write_atomic
from pipeline.export.layout import clip_folder, failures_path, manifest_path, run_record_path
from pipeline.export.manifests import split_clips
from pipeline.filters.select import FILTER_ORDER

METRICS_NAMESPACE = "tapvid3d"
COUNTERS = (
    "units_read",
    "units_resumed",
    "units_failed",
    "clips_annotated",
    "clips_written",
    "tracks_written",
    *(f"tracks_dropped_{name}" for name in FILTER_ORDER),
)
# Kinds of the (kind, value) pairs steps emit (Annotate's are ``pipeline.unit``'s).
CLIPS, FAILURE, RESUMED = unit.CLIPS, unit.FAILURE, unit.RESUMED
FILTERED, REPORT, START = "filtered", "report", "start"


def counter(name: str):
    return Metrics.counter(METRICS_NAMESPACE, name)


class _JobStep(beam.DoFn):
    """A step that needs the run's job and, on each worker, the run's filesystem options."""

    def __init__(self, job: unit.UnitJob, options: PipelineOptions | None):
        self.job = job
        self.options = options

    def setup(self):
        storage.use_options(self.options)  # Beam's Dask runner gives its workers no filesystem options


class Annotate(_JobStep):
    """(group key, units) -> per unit: (name, (RESUMED, reports)) when an earlier run finished it,
    (name, (CLIPS, [clip])) with its candidate clips, or (name, (FAILURE, record)) on bad input."""

    def process(self, group):
        _, units = group
        for name, kind, value in unit.annotate_units(self.job, sorted(units, key=self.job.source.unit_name)):
            counter("units_read").inc()
            if kind == CLIPS:
                counter("clips_annotated").inc(len(value))
            else:
                counter("units_resumed" if kind == RESUMED else "units_failed").inc()
            yield name, (kind, value)


class Filter(_JobStep):
    """(name, (CLIPS, clips)) -> (name, (FILTERED, [(kept clip, outcome) or failure record]));
    other kinds pass."""

    def process(self, element):
        name, (kind, clips) = element
        if kind != CLIPS:
            yield element
            return
        yield name, (FILTERED, unit.filter_unit(self.job, name, clips))


class Write(_JobStep):
    """(name, (FILTERED, items)) -> each clip written, then the unit's record when all were (the
    unit's commit point); emits the unit's (REPORT, report), (FAILURE, record) and (RESUMED,
    name) outcomes for Finalize."""

    def process(self, element):
        name, (kind, value) = element
        if kind == RESUMED:
            yield RESUMED, name
            yield from ((REPORT, report) for report in value)
            return
        if kind == FAILURE:
            yield FAILURE, value
            return
        outcome = unit.write_unit(self.job, name, value, count_written)
        yield from ((FAILURE, failure) for failure in outcome.failures)
        yield from ((REPORT, report) for report in outcome.reports)


def count_written(kept, outcome, digest) -> None:
    """The Write step's counters for one written clip."""
    counter("clips_written").inc(digest is not None)
    counter("tracks_written").inc(kept.num_tracks)
    for filter_name, count in outcome.dropped_by().items():
        counter(f"tracks_dropped_{filter_name}").inc(count)


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
        provenance: dict,
        official: tuple[dict, dict] | None,
        options: PipelineOptions | None,
    ):
        self.output = output.rstrip("/")
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
        source, config = self.provenance["source"], self.provenance["config"]
        write_atomic(failures_path(self.output, source), lines.encode())
        clips = {
            name: [p.rsplit("/", 1)[-1] for p in list_files(f"{clip_folder(self.output, name)}/*.npz")]
            for name in sources.names()
        }
        clips = {name: files for name, files in clips.items() if files}
        minival, full_test = split_clips(clips, config["minival_per_source"], config["seed"], self.official)
        for split, entries in (("minival", minival), ("full_test", full_test)):
            write_atomic(
                manifest_path(self.output, split), "".join(entry + "\n" for entry in entries).encode()
            )
        summary = summarize(reports, failures, len(self.provenance["units"]), resumed)
        summary["manifests"] = {"minival": len(minival), "full_test": len(full_test)}
        record = dict(self.provenance, summary=summary)
        write_atomic(
            run_record_path(self.output, source), json.dumps(record, indent=2, sort_keys=True).encode()
        )
        yield summary


def keyed_by_group(item, source: sources.Source) -> tuple[str, object]:
    return source.group_key(item), item


def under_one_key(outcome: tuple[str, object]) -> tuple[None, tuple[str, object]]:
    return None, outcome


class RegenerateClips(beam.PTransform):
    """The whole run on a pipeline: units in, clips, records, manifests and the run record out.
    Finalize sees every unit's outcome through one GroupByKey (plus a start marker, so it runs
    even when no unit emits anything)."""

    def __init__(
        self,
        job: unit.UnitJob,
        units: list,
        provenance: dict,
        official: tuple[dict, dict] | None = None,
        options: PipelineOptions | None = None,
    ):
        super().__init__()
        self.job, self.units, self.provenance = job, units, provenance
        self.official, self.options = official, options

    def expand(self, pipeline):
        step = (self.job, self.options)
        outcomes = (
            pipeline
            | "Units" >> beam.Create(self.units)
            | "ByGroup" >> beam.Map(keyed_by_group, self.job.source)
            | "Group" >> beam.GroupByKey()
            | "Annotate" >> beam.ParDo(Annotate(*step))
            | "Filter" >> beam.ParDo(Filter(*step))
            | "Write" >> beam.ParDo(Write(*step))
        )
        start = pipeline | "Start" >> beam.Create([(START, None)])
        finalize = Finalize(self.job.output, self.provenance, self.official, self.options)
        return (
            (outcomes, start)
            | "AllOutcomes" >> beam.Flatten()
            | "UnderOneKey" >> beam.Map(under_one_key)
            | "Gather" >> beam.GroupByKey()
            | "Finalize" >> beam.ParDo(finalize)
        )
