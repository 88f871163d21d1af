"""Resume: a rerun skips every unit that a previous run with the same settings finished.

When all clips of a unit are written, its record (``<out>/units/<source>/<unit>.json``) follows:
the unit's name, the run's fingerprint (package version, source, whole config), its clips'
reports and each clip file's SHA-256. A rerun skips the unit when the record carries the
rerun's fingerprint and every clip it lists is on disk with exactly those bytes, validates, and
has its audit table (and its depth, when exported). Anything else re-annotates the unit. The
record is written last, so a run killed at any moment leaves each unit either finished or redone
by the rerun, with the same bytes.
"""

from __future__ import annotations

import hashlib
import json
import os
import time

from apache_beam.io.filesystems import FileSystems

import pipeline
from pipeline.core.config import RunConfig
from pipeline.export.clip_reader import DEFAULT_LIMITS
from pipeline.export.files import PARTIAL, is_abandoned, read_bytes, remove_quietly, write_atomic, writer_pid
from pipeline.export.layout import (
    audit_path,
    clip_path,
    depth_path,
    is_clip_name,
    temporary_patterns,
    unit_record_path,
)
from pipeline.export.validator import check_clip_bytes
from pipeline.filters.select import FILTER_ORDER


def sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def run_fingerprint(source: str, config: RunConfig) -> str:
    """Digest of everything that decides a unit's output bytes."""
    settings = {"version": pipeline.__version__, "source": source, "config": config.to_dict()}
    return sha256(json.dumps(settings, sort_keys=True).encode())


# A clip report's fields and their types, as write_clip makes them (pipeline/graph.py).
REPORT_FIELDS = {
    "clip": str,
    "source": str,
    "unit": str,
    "frames": int,
    "candidates": int,
    "dropped": dict,
    "passed": int,
    "written_tracks": int,
    "target_tracks": int,
}
# A record larger than this is not one of ours (a unit's record is a few KB per clip).
MAX_RECORD_BYTES = 64 << 20


def read_unit_record(output: str, source: str, unit: str) -> dict | None:
    """The unit's record, or None when there is none, it cannot be read, or it is not shaped as
    ``write_unit_record`` writes it (every clip name plain, every report complete)."""
    try:
        record = json.loads(read_bytes(unit_record_path(output, source, unit), MAX_RECORD_BYTES))
    except (OSError, ValueError):
        return None
    return record if _well_formed(record, unit) else None


def _well_formed(record, unit: str) -> bool:
    if not isinstance(record, dict) or record.get("unit") != unit:
        return False
    reports, digests = record.get("reports"), record.get("clips")
    if not isinstance(record.get("fingerprint"), str) or not isinstance(reports, list):
        return False
    if not isinstance(digests, dict) or not all(isinstance(v, str) for v in digests.values()):
        return False
    for report in reports:
        if not isinstance(report, dict) or not all(
            isinstance(report.get(key), kind) and not isinstance(report.get(key), bool)
            for key, kind in REPORT_FIELDS.items()
        ):
            return False
        dropped = report["dropped"]
        if not is_clip_name(report["clip"]) or set(dropped) != set(FILTER_ORDER):
            return False
        if not all(isinstance(count, int) for count in dropped.values()):
            return False
    return True


def _clip_is_intact(output: str, source: str, clip: str, digest: str, export_depth: bool) -> bool:
    companions = [audit_path(output, source, clip)]
    if export_depth:
        companions.append(depth_path(output, source, clip))
    if not all(FileSystems.exists(path) for path in companions):
        return False
    try:
        data = read_bytes(clip_path(output, source, clip), DEFAULT_LIMITS.max_file_bytes)
    except OSError:
        return False
    return sha256(data) == digest and not check_clip_bytes(data)


def finished_reports(
    record: dict | None, output: str, source: str, fingerprint: str, export_depth: bool
) -> list[dict] | None:
    """The clip reports of a unit a previous run finished with these settings, else None."""
    if record is None or record.get("fingerprint") != fingerprint:
        return None
    for report in record["reports"]:
        if report["written_tracks"] and not _clip_is_intact(
            output, source, report["clip"], record["clips"].get(report["clip"], ""), export_depth
        ):
            return None
    return record["reports"]


def remove_stale_clips(record: dict | None, output: str, source: str, current: set[str]) -> list[str]:
    """Delete the files of clips a previous record lists that this run no longer produces (e.g. an
    object that no longer qualifies under new settings); returns their names. A name that is not a
    plain clip name (a forged record) is never turned into a path."""
    listed = {report["clip"] for report in record["reports"]} if record else set()
    stale = sorted(name for name in listed - current if is_clip_name(name))
    remove_quietly(
        [path(output, source, clip) for clip in stale for path in (clip_path, audit_path, depth_path)]
    )
    return stale


def write_unit_record(
    output: str, source: str, unit: str, fingerprint: str, reports: list[dict], digests: dict[str, str]
) -> None:
    record = {"unit": unit, "fingerprint": fingerprint, "reports": reports, "clips": digests}
    text = json.dumps(record, indent=1, sort_keys=True)
    write_atomic(unit_record_path(output, source, unit), text.encode())


def remove_partial_files(output: str, source: str, include_own: bool = False) -> int:
    """Delete the hidden ``.<name>.partial-*`` temporaries (pipeline/export/files.py) that runs which
    are gone left in this source's folders and the shared manifests folder; a concurrent run's live
    temporaries stay. ``include_own`` also deletes this process's (it is stopping). Returns how many
    went."""
    patterns = temporary_patterns(output, source, PARTIAL)
    now = time.time()
    doomed = [
        match.path
        for result in FileSystems.match(patterns)
        for match in result.metadata_list
        if is_abandoned(match.path, match.last_updated_in_seconds, now)
        or (include_own and writer_pid(match.path) == os.getpid())
    ]
    return remove_quietly(doomed)
