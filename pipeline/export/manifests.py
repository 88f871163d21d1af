"""The ``minival`` / ``full_test`` split manifests.

With an official splits file (``{"minival": {source: [files]}, "full_eval": {...}}``) whose
names match the clips, membership follows it; otherwise ``minival`` is a deterministic draw
of ``per_source`` clips per source (ordered by a hash of run seed and name) and
``full_test`` holds every other clip.
"""

from __future__ import annotations

import hashlib
import json
import logging

log = logging.getLogger(__name__)


def load_official_splits(text: str) -> tuple[dict[str, set[str]], dict[str, set[str]]]:
    """(minival, full_eval) membership per source from the release's splits JSON
    (``{"minival": {source: [file, ...]}, "full_eval": {...}}``); ValueError saying what is wrong."""
    data = json.loads(text)
    if not isinstance(data, dict) or "minival" not in data:
        raise ValueError("expected a JSON object with a 'minival' entry")
    splits = []
    for split in ("minival", "full_eval"):
        entry = data.get(split, {})
        valid = isinstance(entry, dict) and all(
            isinstance(names, list) and all(isinstance(name, str) for name in names)
            for names in entry.values()
        )
        if not valid:
            raise ValueError(f"'{split}' must map each source to a list of clip file names")
        splits.append({source: set(names) for source, names in entry.items()})
    return splits[0], splits[1]


def split_clips(
    clips: dict[str, list[str]],
    per_source: int,
    seed: int,
    official: tuple[dict[str, set[str]], dict[str, set[str]]] | None = None,
) -> tuple[list[str], list[str]]:
    """(minival, full_test) entries ``<source>/<clip>.npz``, each sorted.

    Args:
      clips: source -> clip file names (``<clip>.npz``).
    """
    minival, full_test = [], []
    for source in sorted(clips):
        names = sorted(clips[source])
        official_minival = official[0].get(source, set()) if official else set()
        official_all = official_minival | (official[1].get(source, set()) if official else set())
        matched = [name for name in names if name in official_all]
        if matched:
            chosen = {name for name in names if name in official_minival}
            if len(matched) < len(names):
                log.warning(
                    "%s: %d of %d clips are not in the official splits; they go to full_test",
                    source,
                    len(names) - len(matched),
                    len(names),
                )
        else:
            ranked = sorted(names, key=lambda n: hashlib.sha256(f"{seed}:{n}".encode()).hexdigest())
            chosen = set(ranked[:per_source])
        minival += [f"{source}/{name}" for name in names if name in chosen]
        full_test += [f"{source}/{name}" for name in names if name not in chosen]
    return minival, full_test
