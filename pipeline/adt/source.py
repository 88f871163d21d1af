"""Aria Digital Twin as a Source: (sequence, 300-frame chunk) units, one clip each; a sequence's
chunks are annotated in groups of ``CHUNKS_PER_GROUP`` (one opening of the sequence per group)."""

from __future__ import annotations

import dataclasses
import operator
import os
from collections.abc import Iterator

import cv2
import numpy as np

from pipeline.adt.annotate import Chunk, Frame, Instances, annotate_chunk
from pipeline.adt.reader import SequenceReader, list_sequences, v1_name
from pipeline.adt.rectify import Rectifier, stored_cam_from_world
from pipeline.core.clip import ClipRecord
from pipeline.core.config import RunConfig
from pipeline.core.errors import InputError
from pipeline.core.outcomes import UnitClips
from pipeline.core.progress import progress
from pipeline.export.given_queries import given_queries
from pipeline.sources import NoSample, Source, UnitPlan, Wanted

JPEG_QUALITY = 95
# The real ADT excerpt shared beside the repository (relative to its root; read in place) and the
# settings its two frames need. Tests, the Makefile's ADT_EXCERPT and the benchmarks use these.
SHARED_EXCERPT = "../shared/data/adt_sample/aria_digital_twin_test_data"
EXCERPT_SETTINGS = ("adt.chunk_frames=2", "adt.min_frames=2", "adt.max_gt_offset_ms=40")
_REPOSITORY = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
# Chunks annotated together (0-2, 3-5, ...): a group opens its sequence and builds the re-rendering
# tables once (about 0.6 s: S^2 calls of projectaria-tools' projection), for ~4 s of work per
# chunk; a sequence holds ~9 chunks, so its groups still spread over workers.
CHUNKS_PER_GROUP = 3


def excerpt_path() -> str | None:
    """The ADT excerpt's folder: ``$ADT_EXCERPT`` when set, else ``SHARED_EXCERPT`` beside the
    repository; None when that folder does not exist."""
    path = os.environ.get("ADT_EXCERPT") or os.path.join(_REPOSITORY, SHARED_EXCERPT)
    path = os.path.normpath(os.path.abspath(path))
    return path if os.path.isdir(path) else None


def open_reader(sequence: str, config: RunConfig) -> SequenceReader:
    return SequenceReader(sequence, config.adt.with_skeleton, int(config.adt.max_gt_offset_ms * 1e6))


def chunk_count(frames: int, config: RunConfig) -> int:
    """Chunks of ``chunk_frames`` frames; the last one only if it has ``min_frames`` or more."""
    size = config.adt.chunk_frames
    full, rest = divmod(frames, size)
    return full + (1 if rest and rest >= config.adt.min_frames else 0)


def list_units(input_root: str, config: RunConfig, release: frozenset[str] | None = None) -> UnitPlan:
    """(sequence folder, chunk index) for every chunk of every sequence under ``input_root``; on a
    release run, only the chunks the release names.

    A sequence that cannot be read yields one unit (chunk 0; on a release run, each chunk named),
    which fails at annotate with the reason, so the other sequences still run and the failure is
    recorded.
    """
    if config.adt.chunk_frames < 1 or config.adt.min_frames < 1:
        raise InputError("adt.chunk_frames and adt.min_frames must be at least 1")
    named = release_chunks(release) if release is not None else {}
    units, not_made, found = [], {}, set()
    for sequence in list_sequences(input_root):
        v1 = v1_name(sequence)
        found.add(v1)
        if release is not None and v1 not in named:
            continue
        try:
            frames = len(open_reader(sequence, config).frame_timestamps())
        except InputError:
            units += [(sequence, k) for k in sorted(named.get(v1, {0}))]
            continue
        chunks = chunk_count(frames, config)
        if release is None:
            if not chunks:
                progress(
                    f"{os.path.basename(sequence)}: {frames} frame(s) in the ground-truth window, fewer "
                    f"than adt.min_frames={config.adt.min_frames}; skipped"
                )
            units += [(sequence, k) for k in range(chunks)]
            continue
        for k in sorted(named[v1]):
            if k < chunks:
                units.append((sequence, k))
            else:
                not_made[clip_name(sequence, k)] = chunk_beyond(k, frames, config)
    if release is None:
        return UnitPlan(units)
    absent = {
        f"{v1}_{k}": f"sequence {v1} is not in --input"
        for v1, chunks in named.items()
        if v1 not in found
        for k in chunks
    }
    absent.update(
        (name, "not an ADT clip name (<sequence>_<chunk index>)") for name in release if not _chunk_of(name)
    )
    expected = {unit_name(unit): (clip_name(*unit),) for unit in units}
    return UnitPlan(sorted(units), expected=expected, absent=absent, not_made=not_made)


def _chunk_of(name: str) -> tuple[str, int] | None:
    """(v1 sequence name, chunk index) of an ADT clip name, or None when it is not one."""
    sequence, sep, chunk = name.rpartition("_")
    return (sequence, int(chunk)) if sep and sequence and chunk.isdigit() else None


def release_chunks(release: frozenset[str]) -> dict[str, set[int]]:
    """v1 sequence name -> the chunk indices the release names of it."""
    named: dict[str, set[int]] = {}
    for name in release:
        parsed = _chunk_of(name)
        if parsed:
            named.setdefault(parsed[0], set()).add(parsed[1])
    return named


def chunk_beyond(chunk: int, frames: int, config: RunConfig) -> str:
    """Why chunk ``chunk`` of a sequence of ``frames`` annotated frames makes no clip."""
    start = chunk * config.adt.chunk_frames
    if start >= frames:
        return f"chunk {chunk} starts past the sequence's {frames:,} annotated frames"
    return f"chunk {chunk} has {frames - start} frame(s), fewer than adt.min_frames={config.adt.min_frames}"


def unit_name(unit: tuple[str, int]) -> str:
    return f"{os.path.basename(os.path.normpath(unit[0]))}/chunk_{unit[1]}"


def clip_name(sequence: str, chunk: int) -> str:
    """The release's ADT clip name: ``<v1 sequence name>_<chunk index>``."""
    return f"{v1_name(sequence)}_{chunk}"


def encode_jpeg(image_rgb: np.ndarray) -> bytes:
    """RGB [H, W, 3] uint8 -> JPEG bytes (OpenCV, deterministic for a given build). The channels are
    swapped by ``cvtColor`` (a reversed view, ``[..., ::-1]``, is copied pixel by pixel by OpenCV's
    binding: 1.6 ms more per 512x512 frame; same bytes)."""
    bgr = cv2.cvtColor(image_rgb, cv2.COLOR_RGB2BGR)
    ok, data = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    return data.tobytes()


class SequenceFrames:
    """A sequence's frames in the stored camera, read one at a time (the callables annotate uses);
    the re-rendering tables are built on construction (once per calibration per process)."""

    def __init__(self, reader: SequenceReader, config: RunConfig):
        self.reader = reader
        self.rectifier = Rectifier(reader.calibration, config.adt.image_size, config.adt.focal)

    def frame(self, timestamp: int) -> Frame:
        return Frame(
            depth_mm=self.rectifier.depth_mm(self.reader.depth_mm(timestamp)),
            ids=self.rectifier.ids(self.reader.ids(timestamp)),
            cam_from_world=stored_cam_from_world(self.reader.world_from_camera(timestamp)),
            world_from_object=self.reader.object_poses(timestamp),
            timestamp=int(timestamp),
        )

    def jpeg(self, timestamp: int) -> bytes:
        return encode_jpeg(self.rectifier.rgb(self.reader.rgb(timestamp)))

    def instances(self, ids: np.ndarray) -> Instances:
        human, dynamic = set(), set()
        for instance_id in ids.tolist():
            if not instance_id:
                continue
            kind, motion = self.reader.instance(instance_id)
            if kind == "human":
                human.add(instance_id)
            elif motion == "dynamic":
                dynamic.add(instance_id)
        return Instances(frozenset(human), frozenset(dynamic))


def _named(error: InputError, sequence: str, name: str) -> InputError:
    """The error with its message prefixed by the unit's name (instead of the sequence's)."""
    message = str(error)
    for prefix in (f"{name}: ", f"{os.path.basename(os.path.normpath(sequence))}: "):
        if message.startswith(prefix):
            message = message[len(prefix) :]
    return InputError(f"{name}: {message}")


@dataclasses.dataclass(frozen=True)
class OpenedSequence:
    """What a sequence's chunks share: its frame timestamps [F] (the ground-truth window) and its
    frames in the stored camera (the reader and the re-rendering tables)."""

    path: str
    stamps: np.ndarray
    frames: SequenceFrames


def open_sequence(sequence: str, config: RunConfig) -> OpenedSequence:
    """Open a sequence: its reader, frame timestamps and re-rendering tables."""
    reader = open_reader(sequence, config)
    return OpenedSequence(sequence, reader.frame_timestamps(), SequenceFrames(reader, config))


def close_sequence(opened: OpenedSequence) -> None:
    """Release an opened sequence's reader when its chunks are done (a group's one closing, as its
    one opening: about 5 ms on the excerpt)."""
    opened.frames.reader.close()


def in_queries_from(sequence: str, chunk: int, config: RunConfig) -> bool:
    """False when ``--queries-from`` holds no clip of this chunk's name (then it makes no clip)."""
    return (
        not config.queries_from
        or given_queries(config.queries_from, "adt", clip_name(sequence, chunk)) is not None
    )


def annotate_opened(opened: OpenedSequence, chunk: int, config: RunConfig) -> list[ClipRecord]:
    """One chunk of an opened sequence -> its clip; InputError messages start with the unit's name."""
    sequence = opened.path
    name = unit_name((sequence, chunk))
    size = config.adt.chunk_frames
    stamps = opened.stamps[chunk * size : (chunk + 1) * size]
    if len(stamps) < config.adt.min_frames:
        raise InputError(f"{name}: {len(stamps)} frame(s), fewer than adt.min_frames={config.adt.min_frames}")
    frames = opened.frames
    record = Chunk(name=clip_name(sequence, chunk), unit=name, timestamps=stamps)
    try:
        return [annotate_chunk(record, frames.frame, frames.jpeg, frames.instances, config)]
    except InputError as error:
        raise _named(error, sequence, name) from error


def annotate_chunks(
    input_root: str, units: list[tuple[str, int]], config: RunConfig, wanted: list[Wanted] | None = None
) -> Iterator[UnitClips | Exception]:
    """Chunks of one sequence annotated together: the sequence opened once (on the first chunk
    that makes a clip) and closed after the last (or when the caller stops early); per unit, as
    soon as it is made, its clip or the exception that failed it (an unreadable sequence fails them
    all, each error naming its unit)."""
    sequences = {sequence for sequence, _ in units}
    if len(sequences) != 1:
        raise ValueError(f"annotate_chunks takes the chunks of one sequence, got {sorted(sequences)}")
    opened: OpenedSequence | Exception | None = None
    try:
        for sequence, chunk in units:
            if not in_queries_from(sequence, chunk, config):
                yield UnitClips(())
                continue
            if opened is None:
                try:
                    opened = open_sequence(sequence, config)
                except Exception as error:  # noqa: BLE001 - becomes each unit's failure
                    opened = error
            if isinstance(opened, InputError):
                yield _named(opened, sequence, unit_name((sequence, chunk)))
                continue
            if isinstance(opened, Exception):
                yield opened
                continue
            try:
                result = UnitClips(tuple(annotate_opened(opened, chunk, config)))
            except Exception as error:  # noqa: BLE001 - this chunk's failure only
                result = error
            yield result
    finally:
        if isinstance(opened, OpenedSequence):
            close_sequence(opened)


def group_of(unit: tuple[str, int]) -> str:
    """The group of a (sequence, chunk) unit: its sequence and chunk // CHUNKS_PER_GROUP."""
    sequence, chunk = unit
    return f"{sequence}/chunks_{chunk // CHUNKS_PER_GROUP}"


def no_sample_message() -> str:
    settings = " ".join(f"--set {s}" for s in EXCERPT_SETTINGS)
    return (
        "adt: there is no embedded ADT sample (ADT is real Aria recordings with a digital twin; "
        "no synthetic stand-in is shipped). Pass --input with an ADT sequence folder or a folder "
        "of them.\n"
        "To download ADT: accept the licence and get the CDN url file (ADT_download_urls.json) "
        "from https://www.projectaria.com/datasets/adt/, then, with projectaria-tools installed:\n"
        "  aria_dataset_downloader -c ADT_download_urls.json -o ADT/ "
        "-l Apartment_release_clean_seq131_M1292\n"
        "(-l takes sequence names, or all; run it without -d to list the data types and pass with -d the "
        "ones holding video.vrs, the depth and segmentation VRS files and the ground-truth csv/json "
        "files), then:\n"
        "  python -m pipeline.run --source adt --input ADT/\n"
        "To try the shared 3-frame excerpt (2 frames in its ground-truth window, depth for only "
        "the first of them within 5 ms):\n"
        f"  python -m pipeline.run --source adt --input {SHARED_EXCERPT} {settings}"
    )


def sample_input(folder: str) -> str:
    """There is no embedded ADT sample: NoSample says how to get ADT and run the shared excerpt."""
    raise NoSample(no_sample_message())


SOURCE = Source(
    name="adt",
    list_units=list_units,
    unit_name=unit_name,
    annotate_group=annotate_chunks,
    sample_input=sample_input,
    mask_min_agreement=operator.attrgetter("adt.mask_min_agreement"),
    sweepable=("adt.mask_min_agreement",),
    group_of=group_of,
)
