"""The release's own clips: its splits JSON, and a verdict for every clip it names.

The TAPVid-3D release lists its clips in a splits JSON (``{"minival": {source: [file, ...]},
"full_eval": {...}}``; ``full_test`` is accepted for ``full_eval``). ``--release FILE`` restricts a
run to those clips; after it, each clip the file names gets one ``Verdict``: ``written``,
``not_produced`` (the run made no clip of that name, or the filters left too few tracks: the reason
says which), ``input_absent`` (``--input`` holds nothing this clip is made from) or ``failed`` (its
unit or the clip itself failed: the error's line), with its track counts.
"""

from __future__ import annotations

import dataclasses
import importlib.resources
import json
from collections import Counter
from collections.abc import Iterable, Mapping

from pipeline import sources
from pipeline.commandline import closest
from pipeline.core.errors import InputError
from pipeline.core.outcomes import FILTER_ORDER, ClipReport, UnitOutcome
from pipeline.io.files import read_bytes

# The release's split names, in its file; ``full_test`` is what our manifests call ``full_eval``.
SPLITS = ("minival", "full_eval")
SPLIT_ALIASES = {"full_test": "full_eval"}
STATUSES = ("written", "not_produced", "input_absent", "failed")
MAX_RELEASE_BYTES = 64 << 20
# A splits file of the sample worlds' clips, shipped with the package: every clip the samples make,
# and a few they cannot (an object of another camera, absent segments and sequences, a camera the
# sequence lacks, a chunk past the ADT excerpt's end), so that a release run on the samples shows
# every status with its reason (``make demo`` runs it).
SAMPLE_RELEASE = str(importlib.resources.files("pipeline.samples") / "sample_splits.json")


@dataclasses.dataclass(frozen=True)
class Release:
    """The clips a splits JSON names: source -> clip name (without ``.npz``) -> split."""

    path: str
    clips: Mapping[str, Mapping[str, str]]

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


@dataclasses.dataclass(frozen=True)
class Verdict:
    """One release clip after a run: ``status`` in STATUSES, ``tracks`` written (0 unless written),
    ``reason`` a sentence, and the filter stage's counts when its unit made the clip."""

    clip: str
    split: str
    status: str
    tracks: int
    reason: str
    candidates: int = 0
    dropped: Mapping[str, int] = dataclasses.field(default_factory=lambda: dict.fromkeys(FILTER_ORDER, 0))
    passed: int = 0

    def to_json(self) -> dict:
        return dataclasses.asdict(self) | {"dropped": dict(self.dropped)}


def _count(n: int) -> str:
    return f"{n:,}"


def report_reason(report: ClipReport, min_tracks: int) -> str:
    """Why a clip was or was not written, from its report."""
    if report.written:
        below = report.written_tracks < report.target_tracks
        return f"{_count(report.written_tracks)} tracks written" + (
            f", below the target of {_count(report.target_tracks)}" if below else ""
        )
    if not report.candidates:
        return "no candidate track"
    if not report.passed:
        dropped = ", ".join(f"{name} {_count(n)}" for name, n in report.dropped.items() if n)
        return f"all {_count(report.candidates)} candidates dropped: {dropped}"
    return f"{_count(report.passed)} tracks passed the filters, below min_tracks {min_tracks}"


def _from_report(clip: str, split: str, report: ClipReport, min_tracks: int) -> Verdict:
    return Verdict(
        clip,
        split,
        "written" if report.written else "not_produced",
        report.written_tracks,
        report_reason(report, min_tracks),
        report.candidates,
        dict(report.dropped),
        report.passed,
    )


def verdicts(
    named: Mapping[str, str],
    absent: Mapping[str, str],
    not_made: Mapping[str, str],
    expected: Mapping[str, Iterable[str]],
    outcomes: Mapping[str, UnitOutcome | None],
    min_tracks: int,
) -> list[Verdict]:
    """A verdict for every clip of ``named`` (clip -> split), sorted by clip name.

    absent: clip -> why ``--input`` holds nothing it is made from (the source's listing).
    not_made: clip -> why the input makes no clip of that name (the source's listing).
    expected: unit name -> the clips it is to make.
    outcomes: unit name -> its outcome, None when the run left no record of it.
    """
    unit_of = {clip: unit for unit, clips in expected.items() for clip in clips}
    rows = []
    for clip, split in sorted(named.items()):
        if clip in absent:
            rows.append(Verdict(clip, split, "input_absent", 0, absent[clip]))
            continue
        if clip in not_made:
            rows.append(Verdict(clip, split, "not_produced", 0, not_made[clip]))
            continue
        unit = unit_of.get(clip)
        outcome = outcomes.get(unit) if unit is not None else None
        rows.append(_from_outcome(clip, split, unit, outcome, min_tracks))
    return rows


def _from_outcome(clip: str, split: str, unit: str | None, outcome: UnitOutcome | None, min_tracks: int):
    if unit is None:
        return Verdict(clip, split, "input_absent", 0, "no unit of the input makes this clip")
    if outcome is None:
        return Verdict(clip, split, "failed", 0, f"unit {unit} left no record (the run stopped before it)")
    report = next((r for r in outcome.reports if r.clip == clip), None)
    failure = next((f for f in outcome.failures if f.clip in ("", clip) and f.stage != "record"), None)
    if report is not None and failure is None:
        return _from_report(clip, split, report, min_tracks)
    if failure is not None:
        return Verdict(clip, split, "failed", 0, failure.error)
    if clip in outcome.not_made:
        return Verdict(clip, split, "not_produced", 0, outcome.not_made[clip])
    return Verdict(clip, split, "not_produced", 0, f"unit {unit} made no clip of this name")


def tally(rows: Iterable[Verdict]) -> dict[str, int]:
    """Clips named and per status."""
    counts = Counter(row.status for row in rows)
    return {"named": sum(counts.values()), **{status: counts.get(status, 0) for status in STATUSES}}


def summary_line(counts: Mapping[str, int]) -> str:
    return (
        f"release clips: {counts['named']} named, {counts['written']} written, {counts['not_produced']} "
        f"not produced, {counts['input_absent']} input absent, {counts['failed']} failed"
    )


def verdict_lines(rows: Iterable[Verdict]) -> bytes:
    """The rows as JSON lines (``release_<source>.jsonl``)."""
    return "".join(json.dumps(row.to_json(), sort_keys=True) + "\n" for row in rows).encode()
