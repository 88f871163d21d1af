"""A release run's verdict rows (``<out>/release_<source>.jsonl``) as the audit commands read them,
and as ``audit compare`` amends them: the release clips to score when the reference cannot be
listed, and each clip's agreement with the reference, added to its row and summed up per split.

A row's agreement is the finding of the last compare that scored its clip (its reference, time and
the SHA-256 of the clip file it scored): a compare that could not read the clip from the reference
leaves it as it was, and a rerun of the run keeps it while the clip's file is the one scored."""

from __future__ import annotations

import dataclasses
import json
import os
from collections.abc import Mapping
from typing import Any

from pipeline import sources
from pipeline.core.outcomes import FILTER_ORDER
from pipeline.export.layout import release_verdicts_path
from pipeline.io.file_set import settle
from pipeline.io.files import read_bytes
from pipeline.runner.splits import SPLIT_ALIASES, SPLITS
from pipeline.runner.verdicts import MAX_VERDICT_BYTES, STATUSES, Verdict, verdict_lines

# The fields of a verdict row (``pipeline.runner.verdicts.Verdict``) the audit commands read.
ROW_FIELDS = ("clip", "split", "status", "tracks", "reason", "candidates", "dropped", "passed")
# What a verdict row's ``agreement`` holds of a compare row, when the compare scored the clip.
AGREEMENT_FIELDS = ("query_frames_equal", "visibility", "median_mm", "p95_mm", "agrees", "aj_median", "oa")


@dataclasses.dataclass(frozen=True)
class ClipAgreement:
    """A verdict row's ``agreement``, from ``audit compare``: the clip's compare status (scored; zero
    and not_made: no clip of ours to score; not_in_ref; ref_error), agree_mm, the reference (as
    shown), when, and the SHA-256 of the clip file scored; when scored, the agreement's measures (None
    where NaN), whether it agrees fully, and two of tapnet's metrics (aj_median, oa); else ``error``:
    why not."""

    status: str
    agree_mm: float
    error: str = ""
    ref: str = ""
    compared_at: str = ""
    clip_sha256: str = ""
    query_frames_equal: float | None = None
    visibility: float | None = None
    median_mm: float | None = None
    p95_mm: float | None = None
    agrees: bool = False
    aj_median: float | None = None
    oa: float | None = None

    @property
    def scored(self) -> bool:
        return self.status == "scored"

    @property
    def definitive(self) -> bool:
        """Whether the entry is a finding (anything but a reference that could not be read)."""
        return self.status != "ref_error"

    def to_json(self) -> dict[str, Any]:
        """The entry as a verdict row holds it: the measures when scored, else the error."""
        entry = {
            "status": self.status,
            "agree_mm": self.agree_mm,
            "ref": self.ref,
            "compared_at": self.compared_at,
        }
        if self.scored:
            return (
                entry
                | {"clip_sha256": self.clip_sha256}
                | {key: getattr(self, key) for key in AGREEMENT_FIELDS}
            )
        return entry | {"error": self.error}

    @classmethod
    def from_json(cls, entry: Mapping[str, Any]) -> ClipAgreement:
        """The entry a verdict row holds (``to_json``'s)."""
        measures = {key: entry.get(key) for key in AGREEMENT_FIELDS if key != "agrees"}
        return cls(
            entry["status"],
            entry["agree_mm"],
            str(entry.get("error", "")),
            str(entry.get("ref", "")),
            str(entry.get("compared_at", "")),
            str(entry.get("clip_sha256", "")),
            agrees=bool(entry.get("agrees")),
            **measures,
        )

    def kept_over(self, earlier: ClipAgreement | None) -> ClipAgreement:
        """This compare's entry, or ``earlier`` when this one found nothing (the reference could not be
        read) and ``earlier`` is a finding."""
        return earlier if earlier is not None and earlier.definitive and not self.definitive else self


@dataclasses.dataclass(frozen=True)
class VerdictRow:
    """One line of ``release_<source>.jsonl``: the run's verdict on a release clip and, once ``audit
    compare`` has added it, the clip's agreement with the reference."""

    verdict: Verdict
    agreement: ClipAgreement | None = None

    def to_json(self) -> dict[str, Any]:
        agreement = {} if self.agreement is None else {"agreement": self.agreement.to_json()}
        return self.verdict.to_json() | agreement


def read_verdicts(output: str, source: str) -> list[VerdictRow] | None:
    """The verdict rows of ``source`` in ``output``, None when the run wrote none (a commit a killed
    command left is completed first: ``pipeline.io.file_set``)."""
    settle(output)
    path = release_verdicts_path(output, source)
    if not os.path.exists(path) and "://" not in output:
        return None
    rows = []
    for number, line in enumerate(read_bytes(path, MAX_VERDICT_BYTES).decode().splitlines(), 1):
        try:
            row = json.loads(line)
            row["split"] = SPLIT_ALIASES.get(row["split"], row["split"])  # an older run's full_eval
            if row["status"] not in STATUSES or row["split"] not in SPLITS:
                raise ValueError(f"status {row['status']!r}, split {row['split']!r}")
            missing = [key for key in ROW_FIELDS if key not in row] + [
                f"dropped {name}" for name in FILTER_ORDER if name not in row["dropped"]
            ]
            if missing:
                raise ValueError(f"no {', '.join(missing)}")
            agreement = ClipAgreement.from_json(row["agreement"]) if "agreement" in row else None
        except (ValueError, KeyError, TypeError) as error:
            raise ValueError(f"{path} line {number}: not a release verdict ({error})") from None
        rows.append(VerdictRow(Verdict(**{key: row[key] for key in ROW_FIELDS}), agreement))
    return rows


def release_clip_keys(output: str) -> list[str] | None:
    """``<source>/<clip>.npz`` of every release clip a run in ``output`` has a verdict on (sources in
    the registry's order, clips as sorted in each file); None when it has none."""
    keys, found = [], False
    for source in sources.names():
        rows = read_verdicts(output, source)
        if rows is not None:
            found = True
            keys += [f"{source}/{row.verdict.clip}.npz" for row in rows]
    return keys if found else None


def amended_verdicts(output: str, agreements: Mapping[str, ClipAgreement]) -> dict[str, bytes]:
    """source -> its verdict file's new bytes, for each source with verdicts in ``output``: each row
    of a clip in ``agreements`` (``<source>/<clip>.npz`` -> what this compare found) takes it, unless
    the compare found nothing and the row holds a finding (``ClipAgreement.kept_over``); every other
    row is kept as it is."""
    amended = {}
    for source in sources.names():
        verdicts = read_verdicts(output, source)
        if verdicts is None:
            continue
        rows = []
        for row in verdicts:
            found = agreements.get(f"{source}/{row.verdict.clip}.npz")
            rows.append(row if found is None else VerdictRow(row.verdict, found.kept_over(row.agreement)))
        agreements_now = {row.verdict.clip: row.agreement.to_json() for row in rows if row.agreement}
        amended[source] = verdict_lines([row.verdict for row in rows], agreements_now)
    return amended


LEAST_SHOWN = 5
LEAST_FIELDS = ("query_frames_equal", "visibility", "median_mm", "p95_mm")


@dataclasses.dataclass(frozen=True)
class SplitAgreement:
    """Of one split's (or ``all``'s) release clips: how many, those scored against the reference,
    those that agree fully, those the reference does not hold, those the run did not make."""

    split: str
    clips: int
    scored: int
    agree: int
    not_in_ref: int
    not_made: int


@dataclasses.dataclass(frozen=True)
class LeastAgreeing:
    """A scored clip that does not agree fully, with its measures (``LEAST_FIELDS``, None where NaN)."""

    clip: str
    split: str
    query_frames_equal: float | None
    visibility: float | None
    median_mm: float | None
    p95_mm: float | None


@dataclasses.dataclass(frozen=True)
class AgreementSummary:
    """A release run's agreement with the reference: agree_mm, a ``SplitAgreement`` per split then
    ``all``, the ``LEAST_SHOWN`` least-agreeing scored clips, the last compare (its reference and
    time) and how many clips keep the finding of an earlier one."""

    agree_mm: float
    splits: tuple[SplitAgreement, ...]
    least: tuple[LeastAgreeing, ...]
    last_ref: str = ""
    last_at: str = ""
    earlier: int = 0

    def to_json(self) -> dict[str, Any]:
        return {
            "agree_mm": self.agree_mm,
            "splits": [dataclasses.asdict(row) for row in self.splits],
            "least": [dataclasses.asdict(row) for row in self.least],
            "last_ref": self.last_ref,
            "last_at": self.last_at,
            "earlier": self.earlier,
        }


def agreement_summary(rows: list[VerdictRow]) -> AgreementSummary | None:
    """Per split (and ``all``): release clips, clips scored against the reference, those that agree
    fully, those the reference does not hold; and the ``LEAST_SHOWN`` least-agreeing scored clips
    (lowest visibility agreement, then largest p95 distance). None when no row has an agreement
    (``audit compare`` has not run on this run)."""
    compared = [(row.verdict, row.agreement) for row in rows if row.agreement is not None]
    if not compared:
        return None
    per_split = []
    for split in (*SPLITS, "all"):
        chosen = [row for row in rows if split in ("all", row.verdict.split)]
        entries = [row.agreement for row in chosen if row.agreement is not None]
        per_split.append(
            SplitAgreement(
                split,
                len(chosen),
                sum(entry.scored for entry in entries),
                sum(entry.agrees for entry in entries),
                sum(entry.status == "not_in_ref" for entry in entries),
                sum(entry.status == "not_made" for entry in entries),
            )
        )
    short = [(verdict, entry) for verdict, entry in compared if entry.scored and not entry.agrees]
    short.sort(key=lambda pair: (_number(pair[1].visibility), -_number(pair[1].p95_mm)))
    least = tuple(
        LeastAgreeing(verdict.clip, verdict.split, *(getattr(entry, key) for key in LEAST_FIELDS))
        for verdict, entry in short[:LEAST_SHOWN]
    )
    last = max((entry for _, entry in compared), key=lambda entry: entry.compared_at)
    earlier = sum(entry.compared_at != last.compared_at for _, entry in compared)
    return AgreementSummary(last.agree_mm, tuple(per_split), least, last.ref, last.compared_at, earlier)


def _number(value: float | None) -> float:
    return float("nan") if value is None else float(value)


def agreement_lines(summary: AgreementSummary) -> list[str]:
    """``agreement_summary`` as the lines ``audit release`` prints."""
    lines = [
        f"  agreement with the reference (audit compare; agree fully: the same query frames and "
        f"visibility, tracks within {summary.agree_mm:g} mm at p95):",
        f"  last compare: {summary.last_ref or 'a reference'} at {summary.last_at or 'an unknown time'}"
        + (f"; {summary.earlier} clip(s) keep an earlier compare's finding" if summary.earlier else ""),
        f"  {'split':<10}{'clips':>7}{'scored':>8}{'agree fully':>13}{'not in reference':>18}"
        f"{'not made':>10}",
    ]
    for row in summary.splits:
        counts = f"{row.clips:>7}{row.scored:>8}{row.agree:>13}{row.not_in_ref:>18}{row.not_made:>10}"
        lines.append(f"  {row.split:<10}{counts}")
    if summary.least:
        lines.append("  least agreeing (query frames equal, visibility, median mm, p95 mm):")
        for clip in summary.least:
            measures = (getattr(clip, key) for key in LEAST_FIELDS)
            values = ", ".join("-" if value is None else f"{value:.4g}" for value in measures)
            lines.append(f"    {clip.clip} ({clip.split}): {values}")
    return lines
