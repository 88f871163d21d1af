"""Finishing a run, in the main process, once: from the checkpoints its units left
(``pipeline/runner/ledger.py``), the failures file, the release verdicts, the manifests and the run's
provenance file (``pipeline/export/provenance.py``).

Every unit of a run ends with its checkpoint, written or stamped by this run (a resumed unit's is
stamped with the run's id), on whatever runner and workers did the work; ``finish_run`` reads the
checkpoints of the run's planned units, so it works alike on the DirectRunner, a Dask cluster or
Dataflow. A planned unit without a checkpoint of this run (it could not be written) counts as failed.
"""

from __future__ import annotations

import collections
import dataclasses
import json
from collections.abc import Iterable, Mapping

from pipeline import sources
from pipeline.core.outcomes import FILTER_ORDER, Failure, UnitOutcome, failure_cause
from pipeline.export.layout import (
    clip_folder,
    failures_path,
    manifest_path,
    provenance_path,
    release_verdicts_path,
)
from pipeline.export.manifests import split_clips
from pipeline.export.provenance import Provenance, provenance_file
from pipeline.io.file_set import output_lock, write_together
from pipeline.io.files import exists, list_files, read_bytes
from pipeline.runner.prepare import PreparedRun
from pipeline.runner.splits import Release
from pipeline.runner.stages import UnitJob
from pipeline.runner.verdicts import (
    MAX_VERDICT_BYTES,
    kept_agreements,
    summary_line,
    tally,
    verdict_lines,
    verdicts,
)
from pipeline.settings.run_config import RunConfig
from pipeline.sources import UnitPlan


@dataclasses.dataclass(frozen=True)
class RunSummary:
    """A run's totals over every planned unit, finished earlier ones included: units (resumed, failed),
    clips (annotated, written, written below their target track count), tracks (candidates, dropped
    per filter, passing every filter, written), failures (with an example of the most common cause,
    ``failure_cause``, and how many have it), the notes its units made (each once), the manifests'
    entries per split and, on a release run, the verdict counts (``release.tally``)."""

    units: int
    units_resumed: int
    units_failed: int
    clips_annotated: int
    clips_written: int
    clips_below_target: int
    candidate_tracks: int
    dropped_by_filter: Mapping[str, int]
    tracks_passing_filters: int
    tracks_written: int
    failures: int
    common_failure: str = ""
    common_failures: int = 0
    notes: tuple[str, ...] = ()
    manifests: Mapping[str, int] = dataclasses.field(default_factory=dict)  # ``manifest_counts``
    release: Mapping[str, int] | None = None

    def to_json(self) -> dict:
        summary = dataclasses.asdict(self) | {
            "dropped_by_filter": dict(self.dropped_by_filter),
            "notes": list(self.notes),
        }
        if self.release is None:
            del summary["release"]
        else:
            summary["release"] = {**self.release, "line": summary_line(self.release)}
        return summary


def finish_run(
    prepared: PreparedRun, job: UnitJob, plan: UnitPlan, metrics: dict[str, int] | None
) -> RunSummary:
    """Write the failures, the release verdicts (a release run), the manifests and the run's
    provenance, together (``pipeline.io.file_set``): a run killed meanwhile leaves the earlier set.

    metrics: the run's Beam counters, None when the runner reports none (recorded as saying so).
    """
    origin = provenance(prepared, job.input_root, plan)
    source, output = job.source.name, job.output
    outcomes, digests = unit_outcomes(job, [unit.name for unit in plan.units])
    failures = all_failures(outcomes)
    files = {failures_path(output, source): json_lines(failure.to_json() for failure in failures)}
    with output_lock(output):
        counts = None
        if prepared.restricted_to is not None:
            path = release_verdicts_path(output, source)
            files[path], counts = release_verdicts(path, job, plan, prepared.restricted_to, outcomes, digests)
        entries = manifests(output, job.config, prepared.release)
        for split, listed in entries.items():
            files[manifest_path(output, split)] = "".join(entry + "\n" for entry in listed).encode()
        summary = dataclasses.replace(
            summarize(outcomes, failures), manifests=manifest_counts(entries, source), release=counts
        )
        files[provenance_path(output, source)] = provenance_file(origin, summary.to_json(), metrics)
        write_together(files, output)
    return summary


def provenance(prepared: PreparedRun, input_root: str, plan: UnitPlan) -> Provenance:
    """Where the run came from (``pipeline.export.provenance``), stamped now: the run's end."""
    restricted = prepared.restricted_to
    return Provenance(
        source=prepared.source.name,
        input=input_root,
        output=prepared.output,
        config=prepared.config,
        rules=prepared.rules,
        release=restricted.path if restricted is not None else None,
        units=tuple(unit.name for unit in plan.units),
        beam_options=tuple(prepared.beam_args),
    )


def unit_outcomes(job: UnitJob, names: list[str]) -> tuple[dict[str, UnitOutcome | None], dict[str, str]]:
    """Each planned unit's outcome in this run (from its checkpoint), None when it left none; and the
    SHA-256 of every clip file those checkpoints list (clip -> digest)."""
    outcomes: dict[str, UnitOutcome | None] = {}
    digests: dict[str, str] = {}
    for name in names:
        found = job.ledger.read(name)
        outcomes[name] = None
        if found is not None and found.run == job.run_id:
            outcomes[name] = found.outcome
            digests |= found.clips
    return outcomes, digests


def all_failures(outcomes: dict[str, UnitOutcome | None]) -> list[Failure]:
    """Every failure of the run, sorted; a unit without a checkpoint of this run is one."""
    found = []
    for name, outcome in outcomes.items():
        if outcome is None:
            found.append(
                Failure(name, "checkpoint", "OutputError: the unit's checkpoint was not written by this run")
            )
        else:
            found += outcome.failures
    return sorted(found, key=lambda f: (f.unit, f.stage, f.clip, f.error))


def json_lines(records: Iterable[dict]) -> bytes:
    """One JSON object a line, keys sorted."""
    return "".join(json.dumps(record, sort_keys=True) + "\n" for record in records).encode()


def release_verdicts(
    path: str,
    job: UnitJob,
    plan: UnitPlan,
    release: Release,
    outcomes: dict[str, UnitOutcome | None],
    digests: dict[str, str],
) -> tuple[bytes, dict[str, int]]:
    """The new bytes of a release run's verdict file ``path`` (each verdict keeping the agreement an
    ``audit compare`` added while the clip's file is the one it scored), and its counts (``tally``)."""
    rows = verdicts(
        release.clips.get(job.source.name, {}),
        plan.absent,
        plan.not_made,
        plan.expected,
        outcomes,
        job.config.min_tracks,
    )
    earlier = kept_agreements(read_bytes(path, MAX_VERDICT_BYTES), digests) if exists(path) else {}
    return verdict_lines(rows, earlier), tally(rows)


def manifests(output: str, config: RunConfig, release: Release | None) -> dict[str, list[str]]:
    """split -> the manifest's entries (``<source>/<clip>.npz``), over every source's clips in the
    output folder."""
    clips = {
        name: [p.rsplit("/", 1)[-1] for p in list_files(f"{clip_folder(output, name)}/*.npz")]
        for name in sources.names()
    }
    clips = {name: files for name, files in clips.items() if files}
    membership = release.clips if release is not None else None
    only_named = release is not None and release.restricts_run
    minival, full_test = split_clips(clips, config.minival_per_source, config.seed, membership, only_named)
    return {"minival": minival, "full_test": full_test}


def manifest_counts(entries: Mapping[str, list[str]], source: str) -> dict[str, int]:
    """Per split: the source's entries, and every source's (``<split>_all``)."""
    counts = {
        split: sum(entry.startswith(f"{source}/") for entry in listed) for split, listed in entries.items()
    }
    return counts | {f"{split}_all": len(listed) for split, listed in entries.items()}


def summarize(outcomes: dict[str, UnitOutcome | None], failures: list[Failure]) -> RunSummary:
    """Run totals: units, clips, tracks kept and dropped by each filter, failures."""
    done = [outcome for outcome in outcomes.values() if outcome is not None]
    reports = [report for outcome in done for report in outcome.reports]
    written = [r for r in reports if r.written]
    causes = collections.Counter(failure_cause(failure.error) for failure in failures).most_common(1)
    common = ("", 0)
    if causes:
        cause, count = causes[0]
        common = (next(f.error for f in failures if failure_cause(f.error) == cause), count)
    return RunSummary(
        units=len(outcomes),
        units_resumed=sum(outcome.resumed for outcome in done),
        units_failed=sum(outcome is None or outcome.failed for outcome in outcomes.values()),
        clips_annotated=len(reports),
        clips_written=len(written),
        clips_below_target=sum(r.written_tracks < r.target_tracks for r in written),
        candidate_tracks=sum(r.candidates for r in reports),
        dropped_by_filter={name: sum(r.dropped[name] for r in reports) for name in FILTER_ORDER},
        tracks_passing_filters=sum(r.passed for r in reports),
        tracks_written=sum(r.written_tracks for r in reports),
        failures=len(failures),
        common_failure=common[0],
        common_failures=common[1],
        notes=tuple(dict.fromkeys(text for outcome in done for text in outcome.notes)),
    )
