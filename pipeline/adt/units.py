"""ADT's units: one 300-frame chunk of one sequence (``SequenceChunk``) and its clip name, listed
from local sequence folders or from the download-URLs JSON (sequences fetched when their group runs).

A local sequence is its folder's path; a sequence of the URLs JSON is written ``url:<name>`` in its
units (``FETCHED``) and its group is the whole sequence, fetched once. Its frames are counted only
once it is fetched, so without ``--release`` it is one unit making every chunk's clip
(``ALL_CHUNKS``); a release run lists the chunks it names.
"""

from __future__ import annotations

import dataclasses
import os
import re
import tempfile
from typing import TYPE_CHECKING

from pipeline.adt.download import is_url_file, plan_download, read_url_file, reclaim_scratch
from pipeline.adt.frames import open_reader
from pipeline.adt.reader import list_sequences, required_files, v1_name
from pipeline.adt.settings import AdtConfig
from pipeline.core.errors import InputError
from pipeline.core.progress import progress
from pipeline.core.sizes import format_bytes
from pipeline.sources import UnitPlan

if TYPE_CHECKING:
    from pipeline.settings.run_config import RunConfig

FETCHED = "url:"
ALL_CHUNKS = -1
# Chunks annotated together (0-2, 3-5, ...): a group opens its sequence and builds the re-rendering
# tables once (S^2 calls of projectaria-tools' projection); a sequence holds ~9 chunks, so its
# groups still spread over workers. A fetched sequence is one group: it is downloaded once.
CHUNKS_PER_GROUP = 3
# The device-serial suffix ADT v2 adds to a v1 sequence name (``_M1292``, ``_61283``, ...).
SERIAL_SUFFIX = re.compile(r"_[0-9A-Za-z]{4,}")
# A v1 sequence name ends in ``seq<number>``; a name that goes on after it with a serial suffix is
# a v2 name of that v1 sequence.
V2_NAME = re.compile(r"(.+_seq\d+)" + SERIAL_SUFFIX.pattern)


def is_fetched(sequence: str) -> bool:
    return sequence.startswith(FETCHED)


def sequence_name(sequence: str) -> str:
    """A unit's sequence as named in messages: the URLs JSON's name, or the folder's name."""
    return sequence[len(FETCHED) :] if is_fetched(sequence) else os.path.basename(os.path.normpath(sequence))


@dataclasses.dataclass(frozen=True, order=True)
class SequenceChunk:
    """An ADT unit: chunk ``chunk`` of a sequence (a folder's path, or ``url:<name>`` for one of
    the download-URLs JSON); ``ALL_CHUNKS``: every chunk of it. The chunks of a sequence are
    annotated in groups of ``CHUNKS_PER_GROUP`` (``group``; a fetched sequence is one group)."""

    sequence: str
    chunk: int

    @property
    def name(self) -> str:
        part = "all_chunks" if self.chunk == ALL_CHUNKS else f"chunk_{self.chunk}"
        return f"{sequence_name(self.sequence)}/{part}"

    @property
    def group(self) -> str:
        if is_fetched(self.sequence):
            return self.sequence
        return f"{self.sequence}/chunks_{self.chunk // CHUNKS_PER_GROUP}"


def clip_name(sequence: str, chunk: int) -> str:
    """The release's ADT clip name of a local sequence folder: ``<v1 sequence name>_<chunk index>``."""
    return f"{v1_name(sequence)}_{chunk}"


def chunk_count(frames: int, settings: AdtConfig) -> int:
    """Chunks of ``chunk_frames`` frames; the last one only if it has ``min_frames`` or more."""
    full, rest = divmod(frames, settings.chunk_frames)
    return full + (1 if rest and rest >= settings.min_frames else 0)


def chunk_beyond(chunk: int, frames: int, settings: AdtConfig) -> str:
    """Why chunk ``chunk`` of a sequence of ``frames`` annotated frames makes no clip."""
    start = chunk * settings.chunk_frames
    if start >= frames:
        return f"chunk {chunk} starts past the sequence's {frames:,} annotated frames"
    return f"chunk {chunk} has {frames - start} frame(s), fewer than adt.min_frames={settings.min_frames}"


def _chunk_of(name: str) -> tuple[str, int] | None:
    """(v1 sequence name, chunk index) of an ADT clip name, or None when it is not one."""
    sequence, sep, chunk = name.rpartition("_")
    return (sequence, int(chunk)) if sep and sequence and chunk.isdigit() else None


def clip_scene(name: str) -> str | None:
    """The scene of an ADT clip name ``<v1 sequence>_<chunk>``: its v1 sequence; None for another
    name."""
    parsed = _chunk_of(name)
    return parsed[0] if parsed else None


def scene_of(unit: SequenceChunk) -> str:
    """A unit's scene: its sequence's v1 name (every chunk of a sequence is one scene). A local
    folder's is read as ``v1_name`` reads it; a fetched sequence's, and a folder whose serial is not
    recorded, lose a serial suffix after their ``seq<number>`` (``V2_NAME``)."""
    name = sequence_name(unit.sequence) if is_fetched(unit.sequence) else v1_name(unit.sequence)
    v2 = V2_NAME.fullmatch(name)
    return v2[1] if v2 else name


def release_chunks(release: frozenset[str]) -> dict[str, set[int]]:
    """v1 sequence name -> the chunk indices the release names of it."""
    named: dict[str, set[int]] = {}
    for name in release:
        parsed = _chunk_of(name)
        if parsed:
            named.setdefault(parsed[0], set()).add(parsed[1])
    return named


def scratch_folder(settings: AdtConfig) -> str:
    """Where fetched sequences are unpacked: ``adt.scratch_dir``, or one under the system's
    temporary folder."""
    return settings.scratch_dir or os.path.join(tempfile.gettempdir(), "tapvid3d-adt-scratch")


def list_units(
    input_root: str, config: RunConfig, release: frozenset[str] | None = None
) -> UnitPlan[SequenceChunk]:
    """The chunks of every sequence of ``input_root`` (a sequence folder, a folder of them, or the
    download-URLs JSON); on a release run, only the chunks the release names."""
    settings = config.section(AdtConfig)
    if settings.chunk_frames < 1 or settings.min_frames < 1:
        raise InputError("adt.chunk_frames and adt.min_frames must be at least 1")
    named = release_chunks(release) if release is not None else None
    if is_url_file(input_root):
        plan = list_fetched(input_root, settings, named)
    else:
        plan = list_local(input_root, settings, named)
    if release is None:
        return plan
    invalid = {
        name: "not an ADT clip name (<sequence>_<chunk index>)" for name in release if not _chunk_of(name)
    }
    return UnitPlan(
        plan.units,
        plan.expected,
        {**plan.absent, **invalid},
        plan.not_made,
        plan.notes,
        plan.scratch_per_worker,
    )


def list_local(
    input_root: str, settings: AdtConfig, named: dict[str, set[int]] | None
) -> UnitPlan[SequenceChunk]:
    """The chunks of local sequence folders (each opened to count its frames). A sequence that
    cannot be read yields one unit (chunk 0; on a release run, each chunk named), which fails at
    annotate with the reason, so the other sequences still run and the failure is recorded."""
    units: list[SequenceChunk] = []
    not_made: dict[str, str] = {}
    found: set[str] = set()
    for sequence in list_sequences(input_root):
        v1 = v1_name(sequence)
        found.add(v1)
        if named is not None and v1 not in named:
            continue
        try:
            frames = len(open_reader(sequence, settings).frame_timestamps())
        except InputError:
            units += [SequenceChunk(sequence, k) for k in sorted(named[v1] if named is not None else {0})]
            continue
        chunks = chunk_count(frames, settings)
        if named is None:
            if not chunks:
                progress(
                    f"{os.path.basename(sequence)}: {frames} frame(s) in the ground-truth window, fewer "
                    f"than adt.min_frames={settings.min_frames}; skipped"
                )
            units += [SequenceChunk(sequence, k) for k in range(chunks)]
            continue
        for k in sorted(named[v1]):
            if k < chunks:
                units.append(SequenceChunk(sequence, k))
            else:
                not_made[f"{v1}_{k}"] = chunk_beyond(k, frames, settings)
    if named is None:
        return UnitPlan(units)
    absent = {
        f"{v1}_{k}": f"sequence {v1} is not in --input"
        for v1, chunks in named.items()
        if v1 not in found
        for k in chunks
    }
    expected = {unit.name: (clip_name(unit.sequence, unit.chunk),) for unit in units}
    return UnitPlan(sorted(units), expected=expected, absent=absent, not_made=not_made)


def release_name_of(name: str, named: dict[str, set[int]]) -> str | None:
    """The v1 name the release uses for the URLs JSON's sequence ``name`` (itself, or without its
    device-serial suffix), or None when the release names neither."""
    head, _, tail = name.rpartition("_")
    candidates = [name] + ([head] if head and SERIAL_SUFFIX.fullmatch(f"_{tail}") else [])
    return next((candidate for candidate in candidates if candidate in named), None)


def list_fetched(
    url_path: str, settings: AdtConfig, named: dict[str, set[int]] | None
) -> UnitPlan[SequenceChunk]:
    """The units of the sequences of a download-URLs JSON (on a release run, those it names),
    and what fetching them takes: their download size and a worker's peak scratch space."""
    url_file = read_url_file(url_path)
    needed = required_files(settings.with_skeleton)
    units: list[SequenceChunk] = []
    expected: dict[str, tuple[str, ...]] = {}
    matched: set[str] = set()
    downloads = []
    for name in url_file.sequences:
        v1 = release_name_of(name, named) if named is not None else name
        if v1 is None:
            continue
        matched.add(v1)
        try:
            downloads.append(plan_download(url_file, name, needed))
        except InputError:
            pass  # its units fail at annotate, with the reason
        chunks = sorted(named[v1]) if named is not None else [ALL_CHUNKS]
        for k in chunks:
            units.append(SequenceChunk(FETCHED + name, k))
            if named is not None:
                expected[units[-1].name] = (f"{v1}_{k}",)
    absent = {}
    if named is not None:
        absent = {
            f"{v1}_{k}": f"sequence {v1} is not in the download-URLs JSON"
            for v1, chunks in named.items()
            if v1 not in matched
            for k in chunks
        }
    peak = max((d.peak_bytes for d in downloads), default=0)
    total = sum(d.download_bytes for d in downloads)
    scratch = scratch_folder(settings)
    notes = [
        f"adt: {len({u.sequence for u in units})} sequence(s) to fetch from {url_path} "
        f"({format_bytes(total)}), "
        f"each into {scratch} and deleted after its chunks"
    ]
    reclaimed = reclaim_scratch(scratch) if os.path.isdir(scratch) else 0
    if reclaimed:
        notes.append(f"adt: reclaimed {format_bytes(reclaimed)} left in {scratch} by a killed run")
    return UnitPlan(units, expected=expected, absent=absent, notes=tuple(notes), scratch_per_worker=peak)
