"""What ``audit compare`` finds per benchmark clip, and the report made of it: one typed row per clip,
the means per source as tapnet's ``evaluate_model.py`` averages them, the report as JSON and as
markdown, and the rows an earlier report carries over where this compare found nothing.

A row's status says what became of its clip:

- ``scored``: both clips read and scored;
- ``zero``: the prediction is missing, unreadable, refused or of another shape: every metric 0, as
  tapnet counts it;
- ``not_made``: a release run made no clip of this name (its verdict says why; ``audit release``
  counts it): left out of the means, and the reference is not fetched;
- ``not_in_ref``: the reference holds no such clip (HTTP 404, or absent from a local REF): left out
  of the means;
- ``ref_error``: the reference's clip could not be read: left out of the means, and the command
  exits 1.

Every row says when it was found (``compared_at``). Where this compare met a ``ref_error`` and an
earlier report at the same prefix, against the same reference, holds a finding for the clip, that
finding is kept (``carried``: its own time), so a compare against a failing server never replaces
what an earlier one found.
"""

from __future__ import annotations

import dataclasses
import enum
import math
from collections.abc import Mapping
from typing import Any, ClassVar, TypeAlias

import numpy as np

from pipeline import sources as registry
from pipeline.audit.agreement import Agreement
from pipeline.audit.metrics import SCALINGS

TAPNET_KEYS = (*(f"{key}_{scaling}" for scaling in SCALINGS for key in ("aj", "apd")), "oa")
SUMMARY_KEYS = (*TAPNET_KEYS, "median_error_m")
AGREEMENT_KEYS = ("query_frames_equal", "visibility", "median_mm", "p95_mm")
COUNT_KEYS = ("clips", "zero", "not_made", "carried", "ref_errors", "not_in_ref", "agree", "fetched_bytes")
# The per-clip table's columns, before the metrics and the agreement; "why" comes last.
CLIP_COLUMNS = ("source", "clip", "status", "compared_at", "frames", "tracks", "fetched_bytes")


class Status(enum.Enum):
    """What became of a benchmark clip; the value names it in the report (the module says each)."""

    SCORED = "scored"
    ZERO = "zero"
    NOT_MADE = "not_made"
    NOT_IN_REF = "not_in_ref"
    REF_ERROR = "ref_error"

    @property
    def counted(self) -> bool:
        """Whether tapnet's means count the clip (scored, or counted 0)."""
        return self in (Status.SCORED, Status.ZERO)


@dataclasses.dataclass(frozen=True)
class Scores:
    """A clip's tapnet metrics, or their means: 3D-AJ and APD under each rescaling (``aj``, ``apd``:
    scaling of ``SCALINGS`` -> value) and OA; and the median 3D error in metres (not a tapnet metric;
    NaN where none was measured). ``note`` says when per-trajectory counted 0."""

    aj: Mapping[str, float]
    apd: Mapping[str, float]
    oa: float
    median_error_m: float
    note: str = ""

    def tapnet(self) -> dict[str, float]:
        """``TAPNET_KEYS`` -> value."""
        values: dict[str, float] = {}
        for scaling in SCALINGS:
            values |= {f"aj_{scaling}": self.aj[scaling], f"apd_{scaling}": self.apd[scaling]}
        return values | {"oa": self.oa}

    @classmethod
    def from_row(cls, row: Mapping[str, Any]) -> Scores:
        """The scores a report's clip row holds (None, JSON's NaN, as NaN); ValueError when one is
        missing or not a number."""

        def number(key: str) -> float:
            value = row.get(key, math.nan)
            if value is None:
                return math.nan
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ValueError(f"{key} is not a number")
            return float(value)

        aj = {scaling: number(f"aj_{scaling}") for scaling in SCALINGS}
        apd = {scaling: number(f"apd_{scaling}") for scaling in SCALINGS}
        return cls(aj, apd, number("oa"), number("median_error_m"))


# A clip counted as tapnet's ``evaluate_model.py`` counts one it cannot score: every metric 0.
ZERO_SCORES = Scores(dict.fromkeys(SCALINGS, 0.0), dict.fromkeys(SCALINGS, 0.0), 0.0, math.nan)


def _fetched(fetched_bytes: int | None) -> dict[str, int]:
    return {} if fetched_bytes is None else {"fetched_bytes": fetched_bytes}


@dataclasses.dataclass(frozen=True)
class RefUnread:
    """A benchmark clip left out of the means: REF cannot be read (``REF_ERROR``) or holds no such clip
    (``NOT_IN_REF``); ``error`` says why, ``fetched_bytes`` counts the bytes received over HTTP (None
    for a REF that is not); ``at``: when it was found."""

    source: str
    clip: str
    status: Status
    error: str
    at: str
    fetched_bytes: int | None = None

    def as_row(self) -> dict[str, Any]:
        """The clip's row of the report."""
        row = {"source": self.source, "clip": self.clip, "status": self.status.value, "compared_at": self.at}
        return row | {"error": self.error} | _fetched(self.fetched_bytes)


@dataclasses.dataclass(frozen=True)
class Zero:
    """A benchmark clip with no prediction to score: counted with every metric 0 (``ZERO_SCORES``) when
    its prediction is missing, unreadable, refused or of another shape (``ZERO``); left out of the
    means when a release run made no clip of its name (``NOT_MADE``: REF not read). ``error`` says
    why; ``frames``, ``tracks``: REF's T and N (0 when not read)."""

    source: str
    clip: str
    frames: int
    tracks: int
    error: str
    at: str
    fetched_bytes: int | None = None
    status: Status = Status.ZERO
    scores: ClassVar[Scores] = ZERO_SCORES

    def as_row(self) -> dict[str, Any]:
        """The clip's row of the report."""
        named = {"source": self.source, "clip": self.clip, "frames": self.frames, "tracks": self.tracks}
        found = {"status": self.status.value, "compared_at": self.at, "error": self.error}
        if not self.status.counted:
            return named | found
        scores = self.scores.tapnet() | {"median_error_m": self.scores.median_error_m}
        return named | _fetched(self.fetched_bytes) | found | scores


@dataclasses.dataclass(frozen=True)
class Scored:
    """A prediction scored against REF: its scores, its agreement with REF and whether that is full
    (within the report's agree_mm); ``camera_note`` says when REF's frame size or intrinsics came
    from NEW's clip. ``frames``, ``tracks``: REF's T and N; ``clip_sha256``: of NEW's file scored."""

    source: str
    clip: str
    frames: int
    tracks: int
    scores: Scores
    agreement: Agreement
    agrees: bool
    at: str
    camera_note: str = ""
    fetched_bytes: int | None = None
    clip_sha256: str = ""
    status: ClassVar[Status] = Status.SCORED

    @property
    def note(self) -> str:
        """The scores' note and the camera's, either, or none."""
        return "; ".join(text for text in (self.scores.note, self.camera_note) if text)

    def as_row(self) -> dict[str, Any]:
        """The clip's row of the report: the metrics per rescaling (OA after the median's), the median
        error, the agreement, ``agrees``, then a note when there is one."""
        row = {"source": self.source, "clip": self.clip, "frames": self.frames, "tracks": self.tracks}
        row |= _fetched(self.fetched_bytes) | {"status": self.status.value, "compared_at": self.at}
        for scaling in SCALINGS:
            row |= {f"aj_{scaling}": self.scores.aj[scaling], f"apd_{scaling}": self.scores.apd[scaling]}
            if scaling == "median":
                row["oa"] = self.scores.oa
        row["median_error_m"] = self.scores.median_error_m
        row |= {key: getattr(self.agreement, key) for key in AGREEMENT_KEYS}
        row |= {"agrees": self.agrees, "clip_sha256": self.clip_sha256}
        return row | ({"note": self.note} if self.note else {})


@dataclasses.dataclass(frozen=True)
class Carried:
    """An earlier report's finding on a clip this compare could not read from REF (its row as that
    report wrote it, with its own ``compared_at``): counted as it was then; ``error`` is this
    compare's."""

    source: str
    clip: str
    row: Mapping[str, Any]
    status: Status
    scores: Scores
    error: str

    @property
    def agrees(self) -> bool:
        return bool(self.row.get("agrees"))

    @property
    def fetched_bytes(self) -> int:
        return 0

    def as_row(self) -> dict[str, Any]:
        return dict(self.row) | {"carried": True, "error_now": self.error}


ClipRow: TypeAlias = RefUnread | Zero | Scored | Carried


def carried_row(row: Mapping[str, Any], error: str) -> Carried | None:
    """The ``Carried`` finding of an earlier report's clip row, None when the row holds none (an
    error of its own, or not a row this module wrote)."""
    try:
        status = Status(row.get("status"))
        if status is Status.REF_ERROR or not isinstance(row.get("compared_at"), str):
            return None
        scores = Scores.from_row(row) if status.counted else ZERO_SCORES
        return Carried(str(row["source"]), str(row["clip"]), dict(row), status, scores, error)
    except (ValueError, KeyError, TypeError):
        return None


@dataclasses.dataclass(frozen=True)
class SourceMeans:
    """One source's line of the report, or ``all``'s: the clips counted by tapnet (scored and counted
    0), those counted 0 (zero), those carried from an earlier report, those left out (not_made,
    ref_errors, not_in_ref), those that agree fully, the bytes fetched over HTTP, and the means of the
    counted clips' scores."""

    source: str
    clips: int
    zero: int
    not_made: int
    carried: int
    ref_errors: int
    not_in_ref: int
    agree: int
    fetched_bytes: int
    means: Scores

    def as_row(self) -> dict[str, Any]:
        """The source's row of the report."""
        counts = {key: getattr(self, key) for key in COUNT_KEYS}
        return {
            "source": self.source,
            **counts,
            **self.means.tapnet(),
            "median_error_m": self.means.median_error_m,
        }


def plain_mean(values: list[float]) -> float:
    """np.mean of ``values`` (a NaN propagates, as in tapnet's averages); NaN when empty."""
    return float(np.mean(values)) if values else math.nan


def mean_scores(counted: list[Scores], measured: list[Scores]) -> Scores:
    """Each tapnet metric's plain mean over ``counted``, the median error's over ``measured``."""
    return Scores(
        {scaling: plain_mean([scores.aj[scaling] for scores in counted]) for scaling in SCALINGS},
        {scaling: plain_mean([scores.apd[scaling] for scores in counted]) for scaling in SCALINGS},
        plain_mean([scores.oa for scores in counted]),
        plain_mean([scores.median_error_m for scores in measured]),
    )


def mean_row(rows: list[ClipRow], source: str) -> SourceMeans:
    """Means over the clips of ``rows`` counted by tapnet; the median error over the scored ones."""
    counted = [row for row in rows if row.status.counted]
    scored = [row for row in counted if row.status is Status.SCORED]
    return SourceMeans(
        source,
        clips=len(counted),
        zero=sum(row.status is Status.ZERO for row in rows),
        not_made=sum(row.status is Status.NOT_MADE for row in rows),
        carried=sum(isinstance(row, Carried) for row in rows),
        ref_errors=sum(row.status is Status.REF_ERROR for row in rows),
        not_in_ref=sum(row.status is Status.NOT_IN_REF for row in rows),
        agree=sum(isinstance(row, (Scored, Carried)) and row.agrees for row in scored),
        fetched_bytes=sum(row.fetched_bytes or 0 for row in rows),
        means=mean_scores([_scores(row) for row in counted], [_scores(row) for row in scored]),
    )


def _scores(row: ClipRow) -> Scores:
    return ZERO_SCORES if isinstance(row, RefUnread) else row.scores


def summarise(rows: list[ClipRow]) -> list[SourceMeans]:
    """One row per source (the registry's order, tapnet's for the built-in sources; then others
    sorted), then ``all``: the mean of the source means (as tapnet's ``main``) over the sources with a
    counted clip."""
    present = {row.source for row in rows}
    order = registry.names()
    names = [s for s in order if s in present] + sorted(present - set(order))
    per_source = [mean_row([row for row in rows if row.source == source], source) for source in names]
    counts = {key: sum(getattr(row, key) for row in per_source) for key in COUNT_KEYS}
    means = mean_scores(
        [row.means for row in per_source if row.clips],
        [row.means for row in per_source if row.clips > row.zero],
    )
    return [*per_source, SourceMeans("all", **counts, means=means)]


@dataclasses.dataclass(frozen=True)
class CompareReport:
    """NEW_DIR's clips against REF's: REF as shown, NEW_DIR, agree_mm, when, a row per benchmark clip
    (in the benchmark's order), a ``SourceMeans`` per source then ``all``'s, NEW's clips that REF
    does not hold (``only_in_new``; None when REF cannot be listed) and how many of NEW's clips
    ``--clips`` left out (``not_requested``); ``stopped`` says why the stop rule ended the scoring
    ("" when it did not; not part of the JSON)."""

    ref: str
    new: str
    agree_mm: float
    at: str
    clips: list[ClipRow]
    sources: list[SourceMeans]
    only_in_new: list[str] | None
    not_requested: int = 0
    stopped: str = ""

    def to_json(self) -> dict[str, Any]:
        """The report as ``PREFIX.json`` holds it (strict JSON: NaN as None)."""
        return json_ready(
            {
                "ref": self.ref,
                "new": self.new,
                "agree_mm": self.agree_mm,
                "compared_at": self.at,
                "clips": [row.as_row() for row in self.clips],
                "sources": [row.as_row() for row in self.sources],
                "only_in_new": self.only_in_new,
                "not_requested": self.not_requested,
            }
        )


def json_ready(value):
    """``value`` with every non-finite float replaced by None (strict JSON has no NaN)."""
    if isinstance(value, dict):
        return {key: json_ready(item) for key, item in value.items()}
    if isinstance(value, list):
        return [json_ready(item) for item in value]
    return None if isinstance(value, float) and not math.isfinite(value) else value


def _cell(value) -> str:
    if value is None:
        return ""
    return f"{value:.4f}" if isinstance(value, float) else str(value).replace("|", "\\|")


def _table(header: list[str], rows: list[list[object]]) -> list[str]:
    """A markdown table: the header, its separator (one cell per column) and the rows."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return lines + ["| " + " | ".join(_cell(cell) for cell in row) + " |" for row in rows]


def markdown(report: CompareReport) -> str:
    """The report as markdown: per-source table, per-clip table, clips only in NEW."""
    lines = [
        f"# TAPVid-3D metrics of `{report.new}` against `{report.ref}` ({report.at})",
        "",
        "aj/apd = 3D-AJ/APD under median, per-trajectory and no rescaling; oa = occlusion accuracy "
        "(= visibility agreement); means over clips as tapnet's evaluate_model.py, a clip whose "
        "prediction is missing or unreadable (zero) counting 0, one the run did not make (not_made: its "
        "verdict says why) left out; "
        "median_error_m = unscaled median 3D error over REF-visible points (not a tapnet metric; scored "
        "clips only). Agreement per clip: query_frames_equal and visibility are shares of equal query "
        "frames and visibility values, median_mm and p95_mm the track distance; agree: clips with all of "
        f"them equal and p95_mm <= {report.agree_mm:g} mm. carried: findings of an earlier compare kept "
        "where this one could not read REF. fetched_bytes: bytes received over HTTP.",
        "",
    ]
    sources = [row.as_row() for row in report.sources]
    lines += _table(
        ["source", *COUNT_KEYS, *SUMMARY_KEYS],
        [[row["source"], *(row[key] for key in (*COUNT_KEYS, *SUMMARY_KEYS))] for row in sources],
    )
    keys = (*CLIP_COLUMNS, *SUMMARY_KEYS, *AGREEMENT_KEYS, "agrees")
    cells = []
    for clip in report.clips:
        row = clip.as_row()
        why = row.get("error_now") or row.get("error") or row.get("note", "")
        cells.append([*(row.get(key, "") for key in keys), why])
    lines += ["", *_table([*keys, "why"], cells)]
    if report.only_in_new:
        lines += [
            "",
            f"only_in_new (not in REF, not scored): {len(report.only_in_new)} clip(s): "
            + ", ".join(report.only_in_new),
        ]
    if report.not_requested:
        lines += ["", f"not_requested: {report.not_requested} of NEW's clip(s) left out by --clips"]
    return "\n".join(lines) + "\n"
