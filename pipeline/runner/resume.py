"""Resume: a rerun skips every unit that a previous run with the same settings finished.

Every unit ends with its checkpoint (``<out>/units/<source>/<unit>.json``, ``UnitCheckpoint``): the
unit's name, the fingerprint of the settings that decide its clips' bytes, the run that wrote (or
resumed) it, the clips it was asked for on a release run (``wanted``), its clips' reports, each clip
file's SHA-256 and size, its failures and, for the wanted clips it did not make, why. A rerun skips
the unit when the record has no failure, carries the rerun's fingerprint, accounts for every clip
the rerun wants of it, and every clip it lists is on disk with exactly those bytes (its size and
SHA-256; a clip is not decoded again) and has its audit table (and its depth, when exported).
Anything else re-annotates the unit. The checkpoint is written last, so a run killed at any moment
leaves each unit either finished or redone by the rerun, with the same bytes. ``UnitLedger``
(``pipeline/runner/ledger.py``) reads, checks, stamps and writes the checkpoints.

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
from collections.abc import Mapping
from typing import TYPE_CHECKING

import pipeline
from pipeline import sources
from pipeline.io.http import scrub
from pipeline.settings.fields import settings_items

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

    from pipeline.settings.run_config import RunConfig


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
    return hashlib.sha256(json.dumps(settings, sort_keys=True).encode()).hexdigest()
