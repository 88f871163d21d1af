"""The ``minival`` / ``full_test`` split manifests (``full_test``, every clip not in minival, is what
the release's splits JSON calls ``full_eval``).

With the release's membership (its splits JSON) and clip names that match it, membership follows
it; otherwise ``minival`` is a deterministic draw of ``per_source`` clips per source (ordered by a
hash of run seed and name) and ``full_test`` holds every other clip. A release run lists only the
clips the release names.
"""

from __future__ import annotations

import hashlib
import logging
from collections.abc import Mapping

log = logging.getLogger(__name__)


def split_clips(
    clips: dict[str, list[str]],
    per_source: int,
    seed: int,
    membership: Mapping[str, Mapping[str, str]] | None = None,
    only_named: bool = False,
) -> tuple[list[str], list[str]]:
    """(minival, full_test) entries ``<source>/<clip>.npz``, each sorted.

    Args:
      clips: source -> clip file names (``<clip>.npz``).
      membership: source -> clip name (no ``.npz``) -> ``minival`` or ``full_test``, the release's.
      only_named: list only the clips ``membership`` names (a release run).
    """
    minival, full_test = [], []
    for source in sorted(clips):
        names = sorted(clips[source])
        named = membership.get(source, {}) if membership else {}
        matched = [name for name in names if name[: -len(".npz")] in named]
        if only_named:
            names = matched
        if matched:
            chosen = {name for name in matched if named[name[: -len(".npz")]] == "minival"}
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
