"""The release's own clips: its splits JSON, read and checked.

The TAPVid-3D release lists its clips in a splits JSON (``{"minival": {source: [file, ...]},
"full_eval": {...}}``). This project calls ``full_eval`` ``full_test`` in every output (manifests,
verdicts, audits); a file may use either name. ``--release FILE`` restricts a
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

# The splits, as every output names them; the release's file calls full_test ``full_eval``.
SPLITS = ("minival", "full_test")
SPLIT_ALIASES = {"full_eval": "full_test"}
MAX_RELEASE_BYTES = 64 << 20
# A splits file of the sample worlds' clips, shipped with the package: every clip the samples make,
# and a few they cannot (an object of another camera, absent segments and sequences, a camera the
# sequence lacks, a chunk past the ADT excerpt's end), so that a release run on the samples shows
# every status with its reason (``make demo`` runs it).
SAMPLE_RELEASE = str(importlib.resources.files("pipeline.runner") / "sample_splits.json")


@dataclasses.dataclass(frozen=True)
class Release:
    """The release a run follows, from prepare to finish.

    path: its splits JSON.
    clips: source -> clip name (without ``.npz``) -> split (``SPLITS``).
    restricts_run: the run makes only these clips and gives each a verdict (``--release``); else
      the file only sets the manifests' membership (``splits_file``).
    full_test_as: what the file calls full_test (the release's file: ``full_eval``).
    """

    path: str
    clips: Mapping[str, Mapping[str, str]]
    restricts_run: bool = False
    full_test_as: str = "full_test"

    def alias_line(self) -> str:
        """The one line that says the file's other name for full_test, or "" when it uses ours."""
        if self.full_test_as == "full_test":
            return ""
        return f"splits: {self.full_test_as} in {self.path} is full_test here (manifests, verdicts, audits)"

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
    if len(keys) < len(data):
        raise ValueError("full_eval and full_test are one split (full_test here); give one of them")
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
                    raise ValueError(f"{source} clip {name} is in both minival and {keys.get(split, split)}")
    return Release(path, clips, full_test_as=keys.get("full_test", "full_test"))


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
