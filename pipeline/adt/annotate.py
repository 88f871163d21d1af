"""Annotate ADT units: the chunks of one sequence together, the sequence opened once (and, for a
sequence of the download-URLs JSON, fetched into the scratch folder first and deleted after).

Per unit, as soon as it is made, its clip (``UnitClips``) or the exception that failed it; an
unreadable or unfetchable sequence fails every unit of the group, each error naming its unit.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import TYPE_CHECKING

from pipeline.adt.download import fetch_sequence, plan_download, read_url_file
from pipeline.adt.frames import OpenedSequence, close_sequence, open_sequence
from pipeline.adt.reader import required_files
from pipeline.adt.records import Chunk
from pipeline.adt.settings import AdtConfig
from pipeline.adt.tracks import candidate_clip
from pipeline.adt.units import (
    ALL_CHUNKS,
    SequenceChunk,
    chunk_beyond,
    chunk_count,
    clip_name,
    is_fetched,
    scratch_folder,
    sequence_name,
)
from pipeline.core.clip import ClipRecord
from pipeline.core.errors import InputError
from pipeline.core.outcomes import UnitClips
from pipeline.settings.run_config import HttpConfig
from pipeline.sources import RunChoices, Wanted

if TYPE_CHECKING:
    from pipeline.settings.run_config import RunConfig


def _named(error: InputError, sequence: str, name: str) -> InputError:
    """The error with its message prefixed by the unit's name (instead of the sequence's)."""
    message = str(error)
    for prefix in (f"{name}: ", f"{sequence_name(sequence)}: "):
        if message.startswith(prefix):
            message = message[len(prefix) :]
    return InputError(f"{name}: {message}")


def _unit_error(error: Exception, sequence: str, name: str) -> Exception:
    """A shared failure as one unit's: an InputError named for the unit, any other as it is."""
    return _named(error, sequence, name) if isinstance(error, InputError) else error


def annotate_opened(
    opened: OpenedSequence, chunk: int, settings: AdtConfig, choices: RunChoices
) -> list[ClipRecord]:
    """One chunk of an opened sequence -> its clip; InputError messages start with the unit's name."""
    sequence = opened.path
    name = SequenceChunk(sequence, chunk).name
    size = settings.chunk_frames
    stamps = opened.stamps[chunk * size : (chunk + 1) * size]
    if len(stamps) < settings.min_frames:
        raise InputError(f"{name}: {len(stamps)} frame(s), fewer than adt.min_frames={settings.min_frames}")
    frames = opened.frames
    record = Chunk(name=clip_name(sequence, chunk), unit=name, timestamps=stamps)
    try:
        return [candidate_clip(record, frames.frame, frames.jpeg, frames.instances, settings, choices)]
    except InputError as error:
        raise _named(error, sequence, name) from error


def chunk_clips(opened: OpenedSequence, chunk: int, settings: AdtConfig, choices: RunChoices) -> UnitClips:
    """One unit of an opened sequence: its chunk's clip; every chunk's for ``ALL_CHUNKS``; for a
    chunk past the sequence's end (a release run's name), why there is none."""
    frames = len(opened.stamps)
    count = chunk_count(frames, settings)
    if chunk == ALL_CHUNKS:
        return UnitClips(
            tuple(clip for k in range(count) for clip in annotate_opened(opened, k, settings, choices))
        )
    if chunk >= count:
        return UnitClips((), {clip_name(opened.path, chunk): chunk_beyond(chunk, frames, settings)})
    return UnitClips(tuple(annotate_opened(opened, chunk, settings, choices)))


def annotate_local(
    units: list[SequenceChunk], settings: AdtConfig, choices: RunChoices, wanted: list[Wanted]
) -> Iterator[UnitClips | Exception]:
    """Chunks of one local sequence: the sequence opened once (on the first chunk that makes a
    clip) and closed after the last (or when the caller stops early). A chunk whose clip is not
    wanted (``wanted``: a release run's, or not in ``--queries-from``) makes none; the run says why."""
    opened: OpenedSequence | Exception | None = None
    try:
        for unit, keep in zip(units, wanted, strict=True):
            sequence, chunk = unit.sequence, unit.chunk
            try:
                skipped = chunk != ALL_CHUNKS and not choices.wants(clip_name(sequence, chunk), keep)
            except Exception as error:  # noqa: BLE001 - this chunk's failure only (a bad --queries-from file)
                yield _unit_error(error, sequence, unit.name)
                continue
            if skipped:
                yield UnitClips(())
                continue
            if opened is None:
                try:
                    opened = open_sequence(sequence, settings)
                except Exception as error:  # noqa: BLE001 - becomes each unit's failure
                    opened = error
            if isinstance(opened, Exception):
                yield _unit_error(opened, sequence, unit.name)
                continue
            result: UnitClips | Exception
            try:
                result = chunk_clips(opened, chunk, settings, choices)
            except Exception as error:  # noqa: BLE001 - this chunk's failure only
                result = error
            yield result
    finally:
        if isinstance(opened, OpenedSequence):
            close_sequence(opened)


def annotate_fetched(
    input_root: str,
    units: list[SequenceChunk],
    settings: AdtConfig,
    choices: RunChoices,
    wanted: list[Wanted],
    http: HttpConfig,
) -> Iterator[UnitClips | Exception]:
    """Chunks of one sequence of the download-URLs JSON ``input_root``: the files the annotation
    reads fetched into the scratch folder, the chunks annotated, the folder deleted (also when the
    caller stops early or a download fails, which fails every unit of the sequence)."""
    name = sequence_name(units[0].sequence)
    with contextlib.ExitStack() as stack:
        try:
            download = plan_download(read_url_file(input_root), name, required_files(settings.with_skeleton))
            folder = stack.enter_context(fetch_sequence(download, scratch_folder(settings), http))
        except Exception as error:  # noqa: BLE001 - the sequence's failure, each unit's
            for unit in units:
                yield _unit_error(error, name, unit.name)
            return
        yield from annotate_local(
            [SequenceChunk(folder, unit.chunk) for unit in units], settings, choices, wanted
        )


def annotate_group(
    input_root: str, units: list[SequenceChunk], config: RunConfig, wanted: list[Wanted]
) -> Iterator[UnitClips | Exception]:
    """Chunks of one sequence annotated together (``Source.annotate_group``); per unit, as soon as
    it is made, its clip or the exception that failed it."""
    sequences = {unit.sequence for unit in units}
    if len(sequences) != 1:
        raise ValueError(f"annotate_group takes the chunks of one sequence, got {sorted(sequences)}")
    settings, choices = config.section(AdtConfig), RunChoices.of(config, "adt")
    if is_fetched(units[0].sequence):
        yield from annotate_fetched(input_root, units, settings, choices, wanted, config.http)
    else:
        yield from annotate_local(units, settings, choices, wanted)
