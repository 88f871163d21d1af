"""A training run's end, once its records are written (``runner/finish.py``): the clips of its units
written as Parquet shards in ``<out>/train/<source>/`` (``pipeline.export.shards``, a Beam pipeline
on the run's runner), and its source's section of the dataset card (``pipeline.export.card``), made
from the run's records: its summary, its units' checkpoints and its exclusions."""

from __future__ import annotations

import dataclasses

from pipeline import sources
from pipeline.core.outcomes import ClipReport
from pipeline.export.card import card_files, earlier_sections
from pipeline.export.layout import card_path, clip_path, exclusions_path, provenance_path, shard_folder
from pipeline.export.provenance import scrubbed, utc_now
from pipeline.export.shard_set import shard_paths
from pipeline.io.file_set import output_lock, write_together
from pipeline.io.files import remove_quietly
from pipeline.io.http import scrub
from pipeline.runner.finish import RunSummary, unit_outcomes
from pipeline.runner.prepare import PreparedRun
from pipeline.runner.stages import UnitJob
from pipeline.runner.training import Exclusion
from pipeline.settings.fields import as_set_value, flat_settings
from pipeline.settings.run_config import RunConfig
from pipeline.sources import Unit, UnitPlan


@dataclasses.dataclass(frozen=True)
class TrainingClip:
    """A clip a training run's unit wrote: the unit, its scene, and the clip's report."""

    unit: str
    scene: str
    report: ClipReport


def finish_training(
    prepared: PreparedRun, job: UnitJob, plan: UnitPlan, summary: RunSummary, dropped: list[Exclusion]
) -> list[str]:
    """Write the shards of the run's clips and its section of the dataset card; the lines to say."""
    assert prepared.training is not None
    clips = written_clips(job, plan)
    shards = write_shard_files(prepared, clips)
    section = card_section(prepared, job.input_root, summary, clips, dropped, len(shards))
    with output_lock(prepared.output):
        write_together(card_files(prepared.output, prepared.source.name, section), prepared.output)
    folder = shard_folder(prepared.output, prepared.source.name)
    return [
        f"shards: {len(clips)} clip(s) in {len(shards)} Parquet file(s) in {folder}/ (about "
        f"{prepared.config.training.shard_mb} MiB each)",
        f"dataset card: {card_path(prepared.output, 'md')} ({prepared.source.name}'s section)",
    ]


def withdraw_training_output(prepared: PreparedRun) -> list[str]:
    """After a training run that wrote no clip: the source's earlier shards removed and its section of
    the dataset card with them (what is left of neither would be this run's data); the line to say,
    when there were any."""
    from pipeline.export.shards import SHARD_PREFIX

    source, output = prepared.source.name, prepared.output
    earlier = shard_paths(shard_folder(output, source), SHARD_PREFIX)
    if not earlier and source not in earlier_sections(output):
        return []
    remove_quietly(earlier)
    with output_lock(output):
        write_together(card_files(output, source, None), output)
    return [
        f"training: removed {len(earlier)} earlier shard(s) of {source} and its section of the dataset card"
    ]


def written_clips(job: UnitJob, plan: UnitPlan) -> dict[str, TrainingClip]:
    """Every clip the run's units wrote (finished earlier ones included), by name, in name order."""
    scene_of = job.source.scene_of
    assert scene_of is not None
    units: dict[str, Unit] = {unit.name: unit for unit in plan.units}
    outcomes, _ = unit_outcomes(job, list(units))
    clips = {
        report.clip: TrainingClip(name, scene_of(units[name]), report)
        for name, outcome in outcomes.items()
        if outcome is not None
        for report in outcome.reports
        if report.written
    }
    return dict(sorted(clips.items()))


def write_shard_files(prepared: PreparedRun, clips: dict[str, TrainingClip]) -> list[str]:
    """The clips written as Parquet shards of about ``training.shard_mb`` MiB, on the run's own
    runner; the shards' paths. Imported here: only a training run needs Parquet's writer."""
    from pipeline.export.shards import write_shards

    source, output = prepared.source.name, prepared.output
    return write_shards(
        [clip_path(output, source, clip) for clip in clips],
        folder=shard_folder(output, source),
        source=source,
        scenes={clip: found.scene for clip, found in clips.items()},
        units={clip: found.unit for clip, found in clips.items()},
        shard_bytes=prepared.config.training.shard_mb * 2**20,
        pipeline_args=list(prepared.beam_args),
    )


def card_section(
    prepared: PreparedRun,
    input_root: str,
    summary: RunSummary,
    clips: dict[str, TrainingClip],
    dropped: list[Exclusion],
    shards: int,
) -> dict:
    """The source's section of the dataset card, from the run's records (``pipeline.export.card``
    shows it)."""
    source, output, config, training = prepared.source, prepared.output, prepared.config, prepared.training
    assert training is not None
    licence = source.licence
    return {
        "licence": None if licence is None else {"terms": licence.terms, "links": list(licence.links)},
        "counts": {
            "units": summary.units,
            "units_failed": summary.units_failed,
            "clips": summary.clips_written,
            "tracks": summary.tracks_written,
            "frames": sum(clip.report.frames for clip in clips.values()),
        },
        "filters": {
            "candidate_tracks": summary.candidate_tracks,
            "dropped": dict(summary.dropped_by_filter),
            "passed": summary.tracks_passing_filters,
            "clips_below_target": summary.clips_below_target,
        },
        "exclusions": {
            "units": len(dropped),
            "scenes": len({item.scene for item in dropped}),
            "file": file_name(exclusions_path(output, source.name)),
            "splits_file": scrub(training.splits_file),
        },
        "shards": {"folder": f"{source.name}/", "files": shards, "shard_mb": config.training.shard_mb},
        "command": training.command,
        "input": scrub(input_root),
        "rules": config.rules,
        "settings": scrubbed(own_settings(config, source.name)),
        "settings_changed": changed_settings(config, source.name),
        "provenance": f"../{file_name(provenance_path(output, source.name))}",
        "finished": utc_now(),
    }


def file_name(path: str) -> str:
    return path.rpartition("/")[2]


def own_settings(config: RunConfig, source: str) -> dict:
    """The run's settings, run-wide and the source's own section (not the other sources')."""
    others = set(sources.names()) - {source}
    return {key: value for key, value in config.to_dict().items() if key not in others}


def changed_settings(config: RunConfig, source: str) -> dict[str, str]:
    """The run's settings (run-wide and the source's own) whose values differ from the defaults, each
    as ``--set`` writes it."""
    others = set(sources.names()) - {source}
    defaults = flat_settings(RunConfig())
    return {
        key: as_set_value(value)
        for key, value in flat_settings(config).items()
        if key.split(".", 1)[0] not in others and defaults.get(key) != value
    }
