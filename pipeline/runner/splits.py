"""The release's own clips: its splits JSON, read and checked.

The TAPVid-3D release lists its clips in a splits JSON (``{"minival": {source: [file, ...]},
"full_eval": {...}}``; ``full_test`` is accepted for ``full_eval``). ``--release FILE`` restricts a
run to those clips (``ReleasePlan``), and each gets a verdict after it (``runner/verdicts.py``);
``--set splits_file=FILE`` only gives the manifests its membership.
"""

from __future__ import annotations

import dataclasses
import importlib.resources
import json
from collections.abc import Mapping

from pipeline import sources
from pipeline.commandline import closest
from pipeline.core.errors import InputError
from pipeline.io.files import read_bytes

# The release's split names, in its file; ``full_test`` is what our manifests call ``full_eval``.
SPLITS = ("minival", "full_eval")
SPLIT_ALIASES = {"full_test": "full_eval"}
MAX_RELEASE_BYTES = 64 << 20
# A splits file of the sample worlds' clips, shipped with the package: every clip the samples make,
# and a few they cannot (an object of another camera, absent segments and sequences, a camera the
# sequence lacks, a chunk past the ADT excerpt's end), so that a release run on the samples shows
# every status with its reason (``make demo`` runs it).
SAMPLE_RELEASE = str(importlib.resources.files("pipeline.samples") / "sample_splits.json")


@dataclasses.dataclass(frozen=True)
class Release:
    """The release a run follows, from prepare to finish.

    path: its splits JSON.
    clips: source -> clip name (without ``.npz``) -> split.
    restricts_run: the run makes only these clips and gives each a verdict (``--release``); else
      the file only sets the manifests' membership (``splits_file``).
    """

    path: str
    clips: Mapping[str, Mapping[str, str]]
    restricts_run: bool = False

    def names(self, source: str) -> frozenset[str]:
        return frozenset(self.clips.get(source, {}))


class UnknownSource(ValueError):
    """A splits JSON naming a source that is not registered (a typo: ``drivetrak``)."""


def parse_release(text: str, path: str = "") -> Release:
    """The Release of a splits JSON's text; ValueError saying what is wrong with it (UnknownSource
    for a source that is not registered)."""
    try:
        data = json.loads(text)
    except ValueError as error:
        raise ValueError(f"not JSON ({error})") from None
    if not isinstance(data, dict):
        raise ValueError("expected a JSON object")
    keys = {SPLIT_ALIASES.get(key, key): key for key in data}
    if set(keys) - set(SPLITS) or "minival" not in keys:
        raise ValueError(f"expected the keys minival and full_eval (or full_test), found {sorted(data)}")
    clips: dict[str, dict[str, str]] = {}
    for split in SPLITS:
        entry = data.get(keys.get(split, split), {})
        if not isinstance(entry, dict) or not all(
            isinstance(names, list) and all(isinstance(name, str) for name in names)
            for names in entry.values()
        ):
            raise ValueError(f"'{keys.get(split, split)}' must map each source to a list of clip file names")
        for source in entry:
            if source not in sources.names():
                near = closest(source, sources.names())
                hint = f"did you mean {near}?" if near else f"the sources are {', '.join(sources.names())}"
                where = keys.get(split, split)
                raise UnknownSource(f"'{where}' names source {source!r}, not a source; {hint}")
        for source, names in entry.items():
            for name in names:
                clip = name[: -len(".npz")] if name.endswith(".npz") else name
                other = clips.setdefault(source, {}).setdefault(clip, split)
                if other != split:
                    raise ValueError(f"{source} clip {name} is in both minival and full_eval")
    return Release(path, clips)


def read_release(path: str, given: str = "") -> Release:
    """``parse_release`` of the file at ``path``; InputError naming it as the user gave it (``given``,
    e.g. ``--set splits_file=FILE``; default ``--release PATH``) and the problem."""
    given = given or f"--release {path}"
    try:
        return parse_release(read_bytes(path, MAX_RELEASE_BYTES).decode(), path)
    except UnknownSource as error:
        raise InputError(f"{given}: {error}") from error
    except (OSError, UnicodeDecodeError, ValueError) as error:
        raise InputError(f"{given}: not the release's splits JSON ({error})") from error
