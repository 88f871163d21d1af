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
import time

from apache_beam.io.filesystems import FileSystems

import pipeline
from pipeline.core.config import RunConfig
from pipeline.export.files import read_bytes, write_atomic
from pipeline.export.layout import audit_path, clip_path, depth_path, unit_record_path
from pipeline.export.validator import check_clip_bytes


def sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def run_fingerprint(source: str, config: RunConfig) -> str:
    """Digest of everything that decides a unit's output bytes."""
    settings = {"version": pipeline.__version__, "source": source, "config": config.to_dict()}
    return sha256(json.dumps(settings, sort_keys=True).encode())


def read_unit_record(output: str, source: str, unit: str) -> dict | None:
    """The unit's record, or None when there is none or it cannot be read."""
    try:
        record = json.loads(read_bytes(unit_record_path(output, source, unit)))
    except (OSError, ValueError):
        return None
    return record if isinstance(record, dict) and record.get("unit") == unit else None


def _clip_is_intact(output: str, source: str, clip: str, digest: str, export_depth: bool) -> bool:
    companions = [audit_path(output, source, clip)]
    if export_depth:
        companions.append(depth_path(output, source, clip))
    if not all(FileSystems.exists(path) for path in companions):
        return False
    try:
        data = read_bytes(clip_path(output, source, clip))
    except OSError:
        return False
    return sha256(data) == digest and not check_clip_bytes(data, source)


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
    object that no longer qualifies under new settings); returns their names."""
    stale = sorted({report["clip"] for report in record["reports"]} - current) if record else []
    for clip in stale:
        paths = (path(output, source, clip) for path in (clip_path, audit_path, depth_path))
        existing = [path for path in paths if FileSystems.exists(path)]
        if existing:
            FileSystems.delete(existing)
    return stale


def write_unit_record(
    output: str, source: str, unit: str, fingerprint: str, reports: list[dict], digests: dict[str, str]
) -> None:
    record = {"unit": unit, "fingerprint": fingerprint, "reports": reports, "clips": digests}
    text = json.dumps(record, indent=1, sort_keys=True)
    write_atomic(unit_record_path(output, source, unit), text.encode())


def remove_partial_files(output: str, source: str, grace_seconds: float = 300.0) -> int:
    """Delete the hidden ``.<name>.partial-*`` files a killed run left (pipeline/export/files.py).
    This source's folders and records are cleared outright; the manifests, shared with runs of
    other sources, only of partial files older than ``grace_seconds``. Returns how many went."""
    own = [
        f"{output}/{source}/.*.partial*",
        f"{output}/audit/{source}/.*.partial*",
        f"{output}/depth/{source}/.*.partial*",
        f"{output}/units/{source}/.*.partial*",
        f"{output}/.run_{source}.json.partial*",
        f"{output}/.failures_{source}.jsonl.partial*",
    ]
    shared = [f"{output}/manifests/.*.partial*"]
    now = time.time()
    doomed = [m.path for result in FileSystems.match(own) for m in result.metadata_list]
    doomed += [
        m.path
        for result in FileSystems.match(shared)
        for m in result.metadata_list
        if now - m.last_updated_in_seconds > grace_seconds
    ]
    if doomed:
        FileSystems.delete(doomed)
    return len(doomed)
