"""The unit ledger: the one owner of the checkpoints of a source's units in an output folder.

``commit`` writes a unit's checkpoint after all its clips, atomically: the unit's commit point.
``resume`` trusts a finished unit's clips as its checkpoint recorded them: every clip file of the
recorded size and SHA-256 (read once, not decoded) beside its audit table and, when depth is
exported, its depth file. A checkpoint of an earlier version records no sizes: its clips are checked
by their SHA-256 alone and the stamp adds their sizes. ``deep`` also decodes every clip and checks it
against the released schema, as ``pipeline.validate`` does.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping
from typing import TYPE_CHECKING

from pipeline.core.outcomes import UnitOutcome
from pipeline.export.invariants import check_clip_bytes
from pipeline.export.layout import audit_path, checkpoint_path, clip_path, depth_path, is_clip_name
from pipeline.io.clip_reader import DEFAULT_LIMITS
from pipeline.io.files import exists, file_size, read_bytes, remove_quietly, write_atomic
from pipeline.runner.checkpoint import ClipFile, UnitCheckpoint

if TYPE_CHECKING:
    from pipeline.sources import Wanted

# A checkpoint larger than this is not one of ours (a unit's is a few KB per clip).
MAX_CHECKPOINT_BYTES = 64 << 20


@dataclasses.dataclass(frozen=True)
class UnitLedger:
    """The checkpoints of ``source``'s units under ``output``, as the run ``run``, whose settings have
    the fingerprint ``fingerprint`` (``run_fingerprint``), reads and writes them. export_depth: a
    finished clip has its depth file; deep: resuming a unit also decodes and checks its clips."""

    output: str
    source: str
    fingerprint: str = ""
    run: str = ""
    export_depth: bool = False
    deep: bool = False

    def read(self, unit: str) -> UnitCheckpoint | None:
        """The unit's checkpoint, or None when there is none, it cannot be read, it is not shaped as
        ``UnitCheckpoint.to_json`` writes one, or it names another unit."""
        path = checkpoint_path(self.output, self.source, unit)
        try:
            found = UnitCheckpoint.from_json(json.loads(read_bytes(path, MAX_CHECKPOINT_BYTES)))
        except (OSError, ValueError):
            return None
        return found if found.unit == unit else None

    def resume(self, unit: str, wanted: Wanted) -> UnitOutcome | None:
        """The unit's outcome when an earlier run with these settings finished it
        (``UnitCheckpoint.resumes``) and its clip files are as recorded, its checkpoint stamped with
        this run (and the sizes it lacked); else None. wanted: the clips this run wants of the unit
        (None: every clip it makes)."""
        previous = self.read(unit)
        if previous is None or not previous.resumes(self.fingerprint, wanted):
            return None
        sizes = self._sizes_if_intact(previous)
        if sizes is None:
            return None
        self._write(dataclasses.replace(previous, run=self.run, resumed=True, sizes=sizes))
        return previous.resumed_outcome(wanted)

    def commit(self, outcome: UnitOutcome, files: Mapping[str, ClipFile], wanted: Wanted) -> None:
        """Write the unit's checkpoint, after all its clips (``files``: each written clip's file). A
        unit without failures first removes the files of the clips an earlier checkpoint lists that it
        no longer makes; on a release run (``wanted``) only the clips it was asked for are its to
        remove. OSError when a file cannot be removed or the checkpoint written."""
        if not outcome.failed:
            self._remove_stale(self.read(outcome.name), {report.clip for report in outcome.reports}, wanted)
        self._write(
            UnitCheckpoint(
                unit=outcome.name,
                fingerprint=self.fingerprint,
                run=self.run,
                seconds=outcome.seconds,
                wanted=None if wanted is None else tuple(sorted(wanted)),
                reports=outcome.reports,
                clips={clip: file.sha256 for clip, file in files.items()},
                sizes={clip: file.size for clip, file in files.items()},
                failures=outcome.failures,
                not_made=dict(outcome.not_made),
                notes=outcome.notes,
            )
        )

    def _sizes_if_intact(self, checkpoint: UnitCheckpoint) -> dict[str, int] | None:
        """Each written clip's file size when every one is intact (``_size_if_intact``), else None."""
        sizes = {}
        for report in checkpoint.reports:
            if report.written:
                digest, recorded = checkpoint.clips.get(report.clip, ""), checkpoint.sizes.get(report.clip)
                size = self._size_if_intact(report.clip, digest, recorded)
                if size is None:
                    return None
                sizes[report.clip] = size
        return sizes

    def _size_if_intact(self, clip: str, digest: str, size: int | None) -> int | None:
        """The size of the clip's file when it has its companions, the recorded size (None: not
        recorded) and SHA-256 and, when ``deep``, no invariant violated; else None."""
        path = clip_path(self.output, self.source, clip)
        companions = [audit_path(self.output, self.source, clip)]
        if self.export_depth:
            companions.append(depth_path(self.output, self.source, clip))
        if not all(exists(companion) for companion in companions):
            return None
        if size is not None and file_size(path) != size:
            return None
        try:
            data = read_bytes(path, DEFAULT_LIMITS.max_file_bytes if size is None else size)
        except OSError:
            return None
        if ClipFile.of(data).sha256 != digest or (self.deep and check_clip_bytes(data)):
            return None
        return len(data)

    def _remove_stale(self, previous: UnitCheckpoint | None, current: set[str], wanted: Wanted) -> None:
        listed = {report.clip for report in previous.reports} if previous else set()
        if wanted is not None:
            listed &= wanted
        stale = sorted(name for name in listed - current if is_clip_name(name))  # never a forged path
        kinds = (clip_path, audit_path, depth_path)
        remove_quietly([path(self.output, self.source, clip) for clip in stale for path in kinds])

    def _write(self, checkpoint: UnitCheckpoint) -> None:
        path = checkpoint_path(self.output, self.source, checkpoint.unit)
        write_atomic(path, json.dumps(checkpoint.to_json(), indent=1, sort_keys=True).encode())
