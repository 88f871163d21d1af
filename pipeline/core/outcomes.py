"""What the stages of a run hand each other about a unit: typed, frozen records.

A unit's annotation is ``UnitClips`` (its candidate clips and, for clips it was asked for but did not
make, why); once written, a unit's ``UnitOutcome`` holds a ``ClipReport`` per clip and a ``Failure`` per
error. The unit's checkpoint on disk (``pipeline/runner/checkpoint.py``) is its outcome as JSON (``to_json`` /
``from_json``), so the main process finishes a run from the checkpoints alone, on any runner.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Mapping

from pipeline.core.clip import ClipRecord

FILTER_ORDER = ("never_visible", "flicker", "mask")
_NAMED = re.compile(r"\b(object id|object|sequence|segment|camera|unit) \S+?('s)?(?=[\s,;:)]|$)")
_NUMBER = re.compile(r"\d[\d,.]*\d|\d")


def reason_kind(reason: str) -> str:
    """A reason with its names and numbers folded (``object X``, ``N``), so alike reasons match."""
    return _NUMBER.sub("N", _NAMED.sub(lambda m: f"{m[1]} X{m[2] or ''}", reason))


_DETAIL = re.compile(r"\s*\([^()]*\)")


def failure_cause(error: str) -> str:
    """The cause of a failure's error line, for telling alike failures: its last part (after the
    last ``": "``, past the exception's name and the unit, file and group it names), without its
    parenthesised details (``connection refused (the host refused 3 s ago; ...)`` is ``connection
    refused``), names and numbers folded (``reason_kind``)."""
    return reason_kind(_DETAIL.sub("", error.rsplit(": ", 1)[-1]))


class FailureStreak:
    """Failures of one cause (``failure_cause``) in a row, of ``what`` (units, clips): ``gave_up`` says
    why once ``limit`` (0: no limit) of them came in a row, "" until then."""

    def __init__(self, limit: int, what: str):
        self.limit, self.what = limit, what
        self.cause, self.count, self.gave_up = "", 0, ""

    def succeeded(self) -> None:
        self.cause, self.count = "", 0

    def failed(self, error: str) -> str:
        """Count a failure whose error line is ``error``; ``gave_up``."""
        cause = failure_cause(error)
        self.count = self.count + 1 if cause == self.cause else 1
        self.cause = cause
        if self.limit and self.count >= self.limit and not self.gave_up:
            self.gave_up = (
                f"the last {self.count} {self.what} failed alike ({error}; "
                f"max_failures_in_a_row={self.limit})"
            )
        return self.gave_up


@dataclasses.dataclass(frozen=True)
class NotMade:
    """Why a source makes no clip of an object or view it considered (one sentence, for
    ``UnitClips.not_made``)."""

    reason: str


@dataclasses.dataclass(frozen=True)
class UnitClips:
    """What annotating one unit made.

    clips: its candidate clips.
    not_made: clip name -> why the unit made no clip of that name: for each name a release run asked
      for, and for each one the unit considered and left out (DriveTrack: every object of the
      segment), so that a later release run can resume the unit and still say why.
    """

    clips: tuple[ClipRecord, ...]
    not_made: Mapping[str, str] = dataclasses.field(default_factory=dict)


@dataclasses.dataclass(frozen=True)
class ClipReport:
    """One clip after the filter and write stages: its track counts (``dropped`` per filter, in
    FILTER_ORDER, each track counted against the first filter that rejects it)."""

    clip: str
    source: str
    unit: str
    frames: int
    candidates: int
    dropped: Mapping[str, int]
    passed: int
    written_tracks: int
    target_tracks: int

    @property
    def written(self) -> bool:
        return self.written_tracks > 0

    def to_json(self) -> dict:
        return dataclasses.asdict(self) | {"dropped": dict(self.dropped)}

    @classmethod
    def from_json(cls, value: object) -> ClipReport:
        """The report ``to_json`` wrote; ValueError when ``value`` is not shaped like one."""
        fields = _fields(cls, value)
        dropped = fields["dropped"]
        if set(dropped) != set(FILTER_ORDER) or not all(_is_int(n) for n in dropped.values()):
            raise ValueError(f"dropped must count {', '.join(FILTER_ORDER)}")
        return cls(**fields)


@dataclasses.dataclass(frozen=True)
class Failure:
    """One error of a unit (``stage`` annotate: the whole unit; clip: one clip, named in ``clip``;
    checkpoint: its checkpoint could not be written). ``where`` is the innermost frame of an unexpected
    error (not an InputError or OutputError), for debugging."""

    unit: str
    stage: str
    error: str
    clip: str = ""
    where: str = ""

    def to_json(self) -> dict:
        return {key: value for key, value in dataclasses.asdict(self).items() if value}

    @classmethod
    def from_json(cls, value: object) -> Failure:
        if not isinstance(value, dict):
            raise ValueError("a failure must be an object")
        return cls(**_fields(cls, {"clip": "", "where": ""} | value))


@dataclasses.dataclass(frozen=True)
class UnitOutcome:
    """What became of one unit in a run.

    reports: one per clip it made (written or not), sorted by clip name.
    failures: its errors; a unit with any is redone by the next run.
    not_made: clip name -> why no clip (``UnitClips.not_made``; on a release run, its names only).
    resumed: an earlier run had finished it with the same settings; nothing was redone.
    seconds: wall time of its annotation, filtering and writing (0 when resumed).
    notes: what its annotation could not do as asked, one line each (``core.progress.note``).
    """

    name: str
    reports: tuple[ClipReport, ...] = ()
    failures: tuple[Failure, ...] = ()
    not_made: Mapping[str, str] = dataclasses.field(default_factory=dict)
    resumed: bool = False
    seconds: float = 0.0
    notes: tuple[str, ...] = ()

    @property
    def failed(self) -> bool:
        return bool(self.failures)

    @property
    def tracks_written(self) -> int:
        return sum(report.written_tracks for report in self.reports)

    @property
    def clips_written(self) -> int:
        return sum(report.written for report in self.reports)


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _fields(kind: type, value: object) -> dict:
    """``value``'s entries for the fields of dataclass ``kind``, each of the declared type."""
    if not isinstance(value, dict):
        raise ValueError(f"a {kind.__name__} must be an object")
    expected: dict[str, type | tuple[type, ...]] = {
        "str": str,
        "int": int,
        "float": (int, float),
        "Mapping[str, int]": dict,
    }
    fields = {}
    for field in dataclasses.fields(kind):
        item = value.get(field.name)
        want = expected[str(field.type)]
        if not isinstance(item, want) or isinstance(item, bool):
            raise ValueError(f"{kind.__name__}.{field.name} must be {str(field.type)}")
        fields[field.name] = item
    return fields
