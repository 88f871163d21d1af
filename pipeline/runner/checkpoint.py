"""A unit's checkpoint (``<out>/units/<source>/<unit>.json``) as a record: its fields, its JSON form,
and what it says about resuming the unit. Reading, checking and writing it on disk:
``pipeline/runner/ledger.py``."""

from __future__ import annotations

import dataclasses
import hashlib
from collections.abc import Mapping
from typing import TYPE_CHECKING

from pipeline.core.outcomes import ClipReport, Failure, UnitOutcome
from pipeline.export.layout import is_clip_name
from pipeline.runner.verdicts import unmade_reason

if TYPE_CHECKING:
    from pipeline.sources import Wanted


@dataclasses.dataclass(frozen=True)
class ClipFile:
    """A clip's ``.npz`` as its unit's checkpoint records it: SHA-256 and size in bytes."""

    sha256: str
    size: int

    @classmethod
    def of(cls, data: bytes) -> ClipFile:
        return cls(hashlib.sha256(data).hexdigest(), len(data))


@dataclasses.dataclass(frozen=True)
class UnitCheckpoint:
    """What a unit leaves when it ends.

    unit: its name; fingerprint: of the settings that decide its clips' bytes (``run_fingerprint``);
    run: the run that wrote it or resumed the unit; resumed: whether that run skipped the unit;
    seconds: the unit's work; wanted: the clips a release run asked it for (None: every clip it
    makes); reports: its clips' reports; clips: clip -> SHA-256 of its ``.npz``; sizes: clip -> size
    of its ``.npz`` in bytes (absent from the checkpoints of earlier versions); failures: its errors;
    not_made: clip -> why the unit made none of that name; notes: what its annotation could not do
    as asked.
    """

    unit: str
    fingerprint: str
    run: str
    resumed: bool = False
    seconds: float = 0.0
    wanted: tuple[str, ...] | None = None
    reports: tuple[ClipReport, ...] = ()
    clips: Mapping[str, str] = dataclasses.field(default_factory=dict)
    sizes: Mapping[str, int] = dataclasses.field(default_factory=dict)
    failures: tuple[Failure, ...] = ()
    not_made: Mapping[str, str] = dataclasses.field(default_factory=dict)
    notes: tuple[str, ...] = ()

    @property
    def outcome(self) -> UnitOutcome:
        return UnitOutcome(
            self.unit,
            self.reports,
            self.failures,
            dict(self.not_made),
            self.resumed,
            self.seconds,
            self.notes,
        )

    def resumes(self, fingerprint: str, wanted: Wanted) -> bool:
        """Whether the record alone lets a run with ``fingerprint`` resume the unit: no failure, the
        same fingerprint, and every clip the run wants of it (``wanted``; None: every clip it makes)
        accounted for, made or with the reason it was not. Its files are the ledger's to check."""
        if self.fingerprint != fingerprint or self.failures:
            return False
        if self.wanted is None:
            return True
        made = {report.clip for report in self.reports}
        return wanted is not None and wanted <= made | set(self.not_made)

    def resumed_outcome(self, wanted: Wanted) -> UnitOutcome:
        """The unit's outcome in a run that resumes it: on a release run (``wanted``) only the wanted
        clips' reports, and a wanted clip the record neither made nor explains is one the unit does
        not make."""
        outcome = dataclasses.replace(self.outcome, resumed=True, seconds=0.0, notes=())
        if wanted is None:
            return outcome
        unexplained = wanted - {report.clip for report in outcome.reports} - set(outcome.not_made)
        return dataclasses.replace(
            outcome,
            reports=tuple(report for report in outcome.reports if report.clip in wanted),
            not_made={
                **{name: why for name, why in outcome.not_made.items() if name in wanted},
                **{name: unmade_reason(outcome.name)(name) for name in unexplained},
            },
        )

    def to_json(self) -> dict:
        return {
            "unit": self.unit,
            "fingerprint": self.fingerprint,
            "run": self.run,
            "resumed": self.resumed,
            "seconds": round(self.seconds, 3),
            "wanted": None if self.wanted is None else sorted(self.wanted),
            "reports": [report.to_json() for report in self.reports],
            "clips": dict(self.clips),
            "sizes": dict(self.sizes),
            "failures": [item.to_json() for item in self.failures],
            "not_made": dict(self.not_made),
            "notes": list(self.notes),
        }

    @classmethod
    def from_json(cls, value: object) -> UnitCheckpoint:
        """The checkpoint ``to_json`` wrote; ValueError when ``value`` is not shaped like one (every
        clip name plain, every report and failure complete, every size a count of bytes)."""
        if not isinstance(value, dict) or not isinstance(value.get("unit"), str):
            raise ValueError("not a unit checkpoint")
        for key, kind in (("fingerprint", str), ("run", str), ("reports", list), ("failures", list)):
            if not isinstance(value.get(key), kind):
                raise ValueError(f"{key} must be a {kind.__name__}")
        for key in ("clips", "not_made"):
            entry = value.get(key)
            if not isinstance(entry, dict) or not all(isinstance(v, str) for v in entry.values()):
                raise ValueError(f"{key} must map names to strings")
        sizes = value.get("sizes", {})
        if not isinstance(sizes, dict) or not all(_is_size(size) for size in sizes.values()):
            raise ValueError("sizes must map names to sizes in bytes")
        wanted = value.get("wanted")
        if wanted is not None and not (isinstance(wanted, list) and all(isinstance(w, str) for w in wanted)):
            raise ValueError("wanted must be a list of clip names or null")
        reports = tuple(ClipReport.from_json(report) for report in value["reports"])
        if not all(is_clip_name(report.clip) for report in reports):
            raise ValueError("a report's clip is not a plain clip name")
        seconds = value.get("seconds", 0.0)
        notes = value.get("notes", [])
        if not (isinstance(notes, list) and all(isinstance(text, str) for text in notes)):
            raise ValueError("notes must be a list of lines")
        return cls(
            unit=value["unit"],
            fingerprint=value["fingerprint"],
            run=value["run"],
            resumed=bool(value.get("resumed")),
            seconds=float(seconds) if isinstance(seconds, (int, float)) else 0.0,
            wanted=None if wanted is None else tuple(wanted),
            reports=reports,
            clips=dict(value["clips"]),
            sizes=dict(sizes),
            failures=tuple(Failure.from_json(item) for item in value["failures"]),
            not_made=dict(value["not_made"]),
            notes=tuple(notes),
        )


def _is_size(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0
