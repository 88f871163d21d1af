"""Resume: a rerun skips every unit that a previous run with the same settings finished.

Every unit ends with its checkpoint (``<out>/units/<source>/<unit>.json``): the unit's name, the
fingerprint of the settings that decide its clips' bytes, the run that wrote (or resumed) it, the
clips it was asked for on a release run (``wanted``), its clips' reports, each clip file's SHA-256,
its failures and, for the wanted clips it did not make, why. A rerun skips the unit when the record
has no failure, carries the rerun's fingerprint, accounts for every clip the rerun wants of it, and
every clip it lists is on disk with exactly those bytes, validates, and has its audit table (and its
depth, when exported). Anything else re-annotates the unit. The checkpoint is written last, so a run
killed at any moment leaves each unit either finished or redone by the rerun, with the same bytes.

The fingerprint covers exactly what changes a unit's clip bytes: the package version, the source,
and every setting but those marked ``clip_bytes=False`` (the manifests', the scratch folder's,
whether depth is exported: its files are checked on their own) and the other sources' sections. So
a change of ``splits_file``, ``minival_per_source`` or ``--release`` membership resumes every unit
and only rewrites the manifests and the run's records.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import time
from collections.abc import Mapping
from typing import TYPE_CHECKING

import pipeline
from pipeline import sources
from pipeline.core.outcomes import ClipReport, Failure, UnitOutcome
from pipeline.export.invariants import check_clip_bytes
from pipeline.export.layout import (
    audit_path,
    checkpoint_path,
    clip_path,
    depth_path,
    is_clip_name,
    temporary_patterns,
)
from pipeline.io.clip_reader import DEFAULT_LIMITS
from pipeline.io.files import (
    PARTIAL,
    exists,
    filesystems,
    is_abandoned,
    read_bytes,
    remove_quietly,
    write_atomic,
    writer_pid,
)
from pipeline.io.http import scrub
from pipeline.settings.fields import settings_items

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

    from pipeline.settings.run_config import RunConfig


def sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def clip_settings(config: DataclassInstance, source: str) -> dict[str, object]:
    """The settings that decide the bytes of ``source``'s clips: every setting of ``config`` but those
    marked ``not_in_clips`` and the sections named after other sources; a URL without its query
    string and user-info (a rotated token names the same files)."""
    others = set(sources.names()) - {source}
    fields = dataclasses.fields(config)
    marked: dict[str, Mapping[str, object]] = {field.name: field.metadata for field in fields}
    settings: dict[str, object] = {}
    for name, value, _ in settings_items(config):
        if marked.get(name, {}).get("clip_bytes", True) is False or name in others:
            continue
        is_section = dataclasses.is_dataclass(value) and not isinstance(value, type)
        if is_section:
            settings[name] = clip_settings(value, source)
        else:
            settings[name] = scrub(value) if isinstance(value, str) else value
    return settings


def run_fingerprint(source: str, config: RunConfig) -> str:
    """Digest of everything that decides a unit's clip bytes (``clip_settings``)."""
    settings = {"version": pipeline.__version__, "source": source, "config": clip_settings(config, source)}
    return sha256(json.dumps(settings, sort_keys=True).encode())


# A checkpoint larger than this is not one of ours (a unit's is a few KB per clip).
MAX_CHECKPOINT_BYTES = 64 << 20


@dataclasses.dataclass(frozen=True)
class UnitCheckpoint:
    """What a unit leaves when it ends (``<out>/units/<source>/<unit>.json``), written and read here
    alone.

    unit: its name; fingerprint: of the settings that decide its clips' bytes (``run_fingerprint``);
    run: the run that wrote it or resumed the unit; resumed: whether that run skipped the unit;
    seconds: the unit's work; wanted: the clips a release run asked it for (None: every clip it
    makes); reports: its clips' reports; clips: clip -> SHA-256 of its ``.npz``; failures: its
    errors; not_made: clip -> why the unit made none of that name; notes: what its annotation could
    not do as asked.
    """

    unit: str
    fingerprint: str
    run: str
    resumed: bool = False
    seconds: float = 0.0
    wanted: tuple[str, ...] | None = None
    reports: tuple[ClipReport, ...] = ()
    clips: Mapping[str, str] = dataclasses.field(default_factory=dict)
    failures: tuple[Failure, ...] = ()
    not_made: Mapping[str, str] = dataclasses.field(default_factory=dict)
    notes: tuple[str, ...] = ()

    @property
    def outcome(self) -> UnitOutcome:
        return UnitOutcome(
            self.unit,
            self.reports,
            self.failures,
            dict(self.not_made),
            self.resumed,
            self.seconds,
            self.notes,
        )

    def to_json(self) -> dict:
        return {
            "unit": self.unit,
            "fingerprint": self.fingerprint,
            "run": self.run,
            "resumed": self.resumed,
            "seconds": round(self.seconds, 3),
            "wanted": None if self.wanted is None else sorted(self.wanted),
            "reports": [report.to_json() for report in self.reports],
            "clips": dict(self.clips),
            "failures": [item.to_json() for item in self.failures],
            "not_made": dict(self.not_made),
            "notes": list(self.notes),
        }

    @classmethod
    def from_json(cls, value: object) -> UnitCheckpoint:
        """The checkpoint ``to_json`` wrote; ValueError when ``value`` is not shaped like one (every
        clip name plain, every report and failure complete)."""
        if not isinstance(value, dict) or not isinstance(value.get("unit"), str):
            raise ValueError("not a unit checkpoint")
        for key, kind in (("fingerprint", str), ("run", str), ("reports", list), ("failures", list)):
            if not isinstance(value.get(key), kind):
                raise ValueError(f"{key} must be a {kind.__name__}")
        for key in ("clips", "not_made"):
            entry = value.get(key)
            if not isinstance(entry, dict) or not all(isinstance(v, str) for v in entry.values()):
                raise ValueError(f"{key} must map names to strings")
        wanted = value.get("wanted")
        if wanted is not None and not (isinstance(wanted, list) and all(isinstance(w, str) for w in wanted)):
            raise ValueError("wanted must be a list of clip names or null")
        reports = tuple(ClipReport.from_json(report) for report in value["reports"])
        if not all(is_clip_name(report.clip) for report in reports):
            raise ValueError("a report's clip is not a plain clip name")
        seconds = value.get("seconds", 0.0)
        notes = value.get("notes", [])
        if not (isinstance(notes, list) and all(isinstance(text, str) for text in notes)):
            raise ValueError("notes must be a list of lines")
        return cls(
            unit=value["unit"],
            fingerprint=value["fingerprint"],
            run=value["run"],
            resumed=bool(value.get("resumed")),
            seconds=float(seconds) if isinstance(seconds, (int, float)) else 0.0,
            wanted=None if wanted is None else tuple(wanted),
            reports=reports,
            clips=dict(value["clips"]),
            failures=tuple(Failure.from_json(item) for item in value["failures"]),
            not_made=dict(value["not_made"]),
            notes=tuple(notes),
        )


def read_checkpoint(output: str, source: str, unit: str) -> UnitCheckpoint | None:
    """The unit's checkpoint, or None when there is none, it cannot be read, it is not shaped as
    ``UnitCheckpoint.to_json`` writes one, or it names another unit."""
    try:
        found = UnitCheckpoint.from_json(
            json.loads(read_bytes(checkpoint_path(output, source, unit), MAX_CHECKPOINT_BYTES))
        )
    except (OSError, ValueError):
        return None
    return found if found.unit == unit else None


def write_checkpoint(output: str, source: str, checkpoint: UnitCheckpoint) -> None:
    """Write a unit's checkpoint atomically."""
    text = json.dumps(checkpoint.to_json(), indent=1, sort_keys=True)
    write_atomic(checkpoint_path(output, source, checkpoint.unit), text.encode())


def _clip_is_intact(output: str, source: str, clip: str, digest: str, export_depth: bool) -> bool:
    companions = [audit_path(output, source, clip)]
    if export_depth:
        companions.append(depth_path(output, source, clip))
    if not all(exists(path) for path in companions):
        return False
    try:
        data = read_bytes(clip_path(output, source, clip), DEFAULT_LIMITS.max_file_bytes)
    except OSError:
        return False
    return sha256(data) == digest and not check_clip_bytes(data)


def finished_outcome(
    checkpoint: UnitCheckpoint | None,
    output: str,
    source: str,
    fingerprint: str,
    export_depth: bool,
    wanted: frozenset[str] | None,
) -> UnitOutcome | None:
    """The outcome of a unit a previous run finished with these settings, resumed; else None.

    wanted: the clips this run wants of the unit (None: every clip it makes). A checkpoint of every
    clip the unit makes resumes any run; one made for some clips only (a release run's) resumes a
    run whose wanted clips it all accounts for, made or with the reason they were not. On a release
    run only the wanted clips' reports are kept, and a wanted clip a complete checkpoint neither made
    nor explains is one the unit does not make.
    """
    if checkpoint is None or checkpoint.fingerprint != fingerprint or checkpoint.failures:
        return None
    outcome = checkpoint.outcome
    made = {report.clip for report in outcome.reports}
    complete = checkpoint.wanted is None
    if wanted is None and not complete:
        return None
    if wanted is not None and not complete and not wanted <= made | set(outcome.not_made):
        return None
    for report in outcome.reports:
        if report.written and not _clip_is_intact(
            output, source, report.clip, checkpoint.clips.get(report.clip, ""), export_depth
        ):
            return None
    if wanted is None:
        return dataclasses.replace(outcome, resumed=True, seconds=0.0, notes=())
    unexplained = wanted - made - set(outcome.not_made)
    return dataclasses.replace(
        outcome,
        reports=tuple(report for report in outcome.reports if report.clip in wanted),
        not_made={
            **{name: why for name, why in outcome.not_made.items() if name in wanted},
            **dict.fromkeys(unexplained, f"unit {outcome.name} makes no clip of this name"),
        },
        resumed=True,
        seconds=0.0,
        notes=(),
    )


def remove_stale_clips(
    previous: UnitCheckpoint | None,
    output: str,
    source: str,
    current: set[str],
    wanted: frozenset[str] | None = None,
) -> list[str]:
    """Delete the files of clips a previous checkpoint lists that this run no longer produces (e.g.
    an object that no longer qualifies under new settings); returns their names. On a release run
    (``wanted``, the clips it was asked for) only those clips are this run's to remove. A name that
    is not a plain clip name (a forged checkpoint) is never turned into a path."""
    listed = {report.clip for report in previous.reports} if previous else set()
    if wanted is not None:
        listed &= wanted
    stale = sorted(name for name in listed - current if is_clip_name(name))
    remove_quietly(
        [path(output, source, clip) for clip in stale for path in (clip_path, audit_path, depth_path)]
    )
    return stale


def remove_partial_files(output: str, source: str, include_own: bool = False) -> int:
    """Delete the hidden ``.<name>.partial-*`` temporaries (pipeline/io/files.py) that runs which
    are gone left in this source's folders and the shared manifests folder; a concurrent run's live
    temporaries stay. ``include_own`` also deletes this process's (it is stopping). Returns how many
    went."""
    patterns = temporary_patterns(output, source, PARTIAL)
    now = time.time()
    doomed = [
        match.path
        for result in filesystems().match(patterns)
        for match in result.metadata_list
        if is_abandoned(match.path, match.last_updated_in_seconds, now)
        or (include_own and writer_pid(match.path) == os.getpid())
    ]
    return remove_quietly(doomed)
