"""A verdict for every clip the release names, after a ``--release`` run.

Each clip the splits file names (``runner/splits.py``) gets one ``Verdict``: ``written``,
``not_produced`` (the run made no clip of that name, or the filters left too few tracks: the reason
says which), ``input_absent`` (``--input`` holds nothing this clip is made from) or ``failed`` (its
unit or the clip itself failed: the error's line), with its track counts.
"""

from __future__ import annotations

import dataclasses
import json
from collections import Counter
from collections.abc import Callable, Iterable, Mapping
from typing import TYPE_CHECKING

from pipeline.core.errors import InputError
from pipeline.core.outcomes import FILTER_ORDER, ClipReport, UnitOutcome

if TYPE_CHECKING:
    from pipeline.io.given_queries import GivenQueries

STATUSES = ("written", "not_produced", "input_absent", "failed")
# A verdict file larger than this is not one a run wrote (a release's is about 1 KB a clip).
MAX_VERDICT_BYTES = 256 << 20


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


def unmade_reason(unit: str, given: GivenQueries | None = None) -> Callable[[str], str]:
    """Why unit ``unit`` made no clip of a name the run asked for when its source said nothing: the
    same words for every source (``--queries-from`` holds none of that name, or the unit made none)."""

    def reason(clip: str) -> str:
        try:
            held = given is None or given.admits(clip)
        except (InputError, OSError) as error:  # its file cannot be read: say so, the run goes on
            return f"--queries-from's clip of this name cannot be read ({error})"
        if not held:
            return "--queries-from holds no clip of this name"
        return f"unit {unit} made no clip of this name"

    return reason


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
    outcomes: unit name -> its outcome, None when the run left no checkpoint of it.
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
        return Verdict(
            clip, split, "failed", 0, f"unit {unit} left no checkpoint (the run stopped before it)"
        )
    report = next((r for r in outcome.reports if r.clip == clip), None)
    failure = next((f for f in outcome.failures if f.clip in ("", clip) and f.stage != "checkpoint"), None)
    if report is not None and failure is None:
        return _from_report(clip, split, report, min_tracks)
    if failure is not None:
        return Verdict(clip, split, "failed", 0, failure.error)
    reason = outcome.not_made.get(clip) or unmade_reason(unit)(clip)
    return Verdict(clip, split, "not_produced", 0, reason)


def tally(rows: Iterable[Verdict]) -> dict[str, int]:
    """Clips named and per status."""
    counts = Counter(row.status for row in rows)
    return {"named": sum(counts.values()), **{status: counts.get(status, 0) for status in STATUSES}}


def summary_line(counts: Mapping[str, int]) -> str:
    return (
        f"release clips: {counts['named']} named, {counts['written']} written, {counts['not_produced']} "
        f"not produced, {counts['input_absent']} input absent, {counts['failed']} failed"
    )


def verdict_lines(rows: Iterable[Verdict], agreements: Mapping[str, dict] | None = None) -> bytes:
    """The rows as JSON lines (``release_<source>.jsonl``), each with its clip's entry of
    ``agreements`` (clip -> the ``agreement`` an ``audit compare`` added) when it has one."""
    kept = agreements or {}
    lines = []
    for row in rows:
        entry = row.to_json() | ({"agreement": kept[row.clip]} if row.clip in kept else {})
        lines.append(json.dumps(entry, sort_keys=True) + "\n")
    return "".join(lines).encode()


def kept_agreements(text: bytes, digests: Mapping[str, str]) -> dict[str, dict]:
    """clip -> its ``agreement`` in an earlier verdict file's ``text``, for each clip whose file is
    still the one that compare scored (its SHA-256 in ``digests``, clip -> SHA-256 of the clip file
    on disk now) or that the reference lacks (``not_in_ref``: a finding about the release, kept until
    a compare replaces it). Lines that are not verdicts are skipped."""
    kept = {}
    for line in text.decode("utf-8", errors="replace").splitlines():
        try:
            row = json.loads(line)
            clip, entry = row["clip"], row["agreement"]
            scored = entry["status"] == "scored"
        except (ValueError, KeyError, TypeError):
            continue
        if not isinstance(clip, str) or not isinstance(entry, dict):
            continue
        if (scored and entry.get("clip_sha256") == digests.get(clip)) or entry["status"] == "not_in_ref":
            kept[clip] = entry
    return kept
