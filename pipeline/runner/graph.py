"""The Beam shell: one composite transform per run, its steps named like the data flow.

    Units -> ByGroup -> Group -> Annotate -> Filter -> Write

Each step calls the plain stage of ``pipeline.runner.stages`` (the benchmarks call the same stages through
``unit.run_group``). Group hands each worker the units of one group (``Source.group_of``: a
DriveTrack segment's cameras, which share one read of its lidar; else each unit alone), and
spreads the groups over the workers. After Annotate an element is one unit's typed record in one
PCollection, the only shape every runner executes alike (Beam's Dask runner has no multi-output
ParDo): a ``UnitOutcome`` for a unit an earlier run finished or one that failed (already recorded),
else its ``Annotated`` clips, which Filter turns into ``Filtered`` ones and Write writes, then the
unit's record (its commit point: a unit is never split across workers, and a killed run loses only
the units in flight). The run is finished from those records by the main process
(``pipeline.runner.finish``), whatever the runner.

Counters (``apache_beam.metrics``, namespace ``tapvid3d``): units_read, units_resumed,
units_failed, clips_annotated, clips_written, tracks_written, tracks_dropped_<filter>.
"""

from __future__ import annotations

import operator
import typing

import apache_beam as beam
from apache_beam.metrics import Metrics
from apache_beam.options.pipeline_options import PipelineOptions

from pipeline import sources
from pipeline.core.memory import release_freed_memory
from pipeline.core.outcomes import FILTER_ORDER, UnitOutcome
from pipeline.core.progress import quiet_worker_logs
from pipeline.io import storage
from pipeline.runner import stages as unit

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


def counter(name: str):
    return Metrics.counter(METRICS_NAMESPACE, name)


class _JobStep(beam.DoFn):
    """A step that needs the run's job and, on each worker, the run's filesystem options and its
    logging (quiet unless ``--verbose``)."""

    def __init__(self, job: unit.UnitJob, options: PipelineOptions | None):
        self.job = job
        self.options = options

    def setup(self):
        quiet_worker_logs()
        storage.use_options(self.options)  # Beam's Dask runner gives its workers no filesystem options


class Annotate(_JobStep):
    """(group key, units) -> per unit: its UnitOutcome when an earlier run finished it or it failed,
    else its ``Annotated`` candidate clips."""

    def process(self, group):
        _, units = group
        for item in unit.annotate_units(self.job, sorted(units, key=operator.attrgetter("name"))):
            counter("units_read").inc()
            if isinstance(item, unit.Annotated):
                counter("clips_annotated").inc(len(item.made.clips))
            else:
                counter("units_resumed" if item.resumed else "units_failed").inc()
            yield item  # a fused Filter and Write run on it before the next is made
        release_freed_memory()  # the group's arrays are gone: the worker gives their heap back


class Filter(_JobStep):
    """``Annotated`` -> ``Filtered`` (each clip's verdicts); a UnitOutcome passes."""

    def process(self, item):
        yield unit.filter_unit(self.job, item) if isinstance(item, unit.Annotated) else item


class Write(_JobStep):
    """``Filtered`` -> each clip written, then the unit's checkpoint: its UnitOutcome; a UnitOutcome
    passes."""

    def process(self, item):
        if isinstance(item, UnitOutcome):
            yield item
            return
        outcome = unit.write_unit(self.job, item, count_written)
        counter("units_failed").inc(outcome.failed)
        yield outcome


def count_written(kept, outcome, written) -> None:
    """The Write step's counters for one written clip."""
    counter("clips_written").inc(written is not None)
    counter("tracks_written").inc(kept.num_tracks)
    for filter_name, count in outcome.dropped_by().items():
        counter(f"tracks_dropped_{filter_name}").inc(count)


def keyed_by_group(item, source: sources.Source) -> tuple[str, object]:
    return source.group_key(item), item


class RegenerateClips(beam.PTransform):
    """The whole run on a pipeline: units in, clips and each unit's record out."""

    def __init__(self, job: unit.UnitJob, units: list[sources.Unit], options: PipelineOptions | None = None):
        super().__init__()
        self.job, self.units, self.options = job, units, options

    def expand(self, pipeline):
        step = (self.job, self.options)
        # Output types declared Any (what Beam infers for these steps anyway): Beam then skips inferring
        # them from the steps' bytecode, which took about a second of every run's start.
        return (
            pipeline
            | "Units" >> beam.Create(self.units)
            | "ByGroup" >> beam.Map(keyed_by_group, self.job.source)
            | "Group" >> beam.GroupByKey()
            | "Annotate" >> beam.ParDo(Annotate(*step)).with_output_types(typing.Any)
            | "Filter" >> beam.ParDo(Filter(*step)).with_output_types(typing.Any)
            | "Write" >> beam.ParDo(Write(*step)).with_output_types(typing.Any)
        )
