"""A run's clips in a researcher's hands: ``open`` reads one clip file as a typed, frozen ``Clip``,
``split`` yields the clips of a run's split (``minival``, ``full_test``) in its manifest's order, and
``shards`` those of a training run's Parquet shards::

    import pipeline.clips

    for clip in pipeline.clips.split("out/demo", "minival"):
        print(clip.source, clip.name, clip.tracks.shape)
    for clip in pipeline.clips.shards("out/train/pstudio"):
        print(clip.scene, clip.name, clip.quality.mean())

Every file is read through the bounded reader (``pipeline/io/clip_reader.py``: nothing is unpickled,
sizes are capped from the headers) and checked to be a clip (keys, dtypes, shapes) before it is
handed over; the release's own files open the same way. A reader of some members only (``audit
compare``) hands them over as a ``Clip`` too (``from_members``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator, Mapping
from typing import TYPE_CHECKING

import cv2
import numpy as np

from pipeline import sources
from pipeline.core.images import jpeg_size
from pipeline.export import invariants
from pipeline.export.layout import clip_path, manifest_path
from pipeline.export.shard_set import shard_files
from pipeline.io.clip_reader import DEFAULT_LIMITS, FRAMES, ReadLimits, read_clip_file
from pipeline.io.files import open_binary, read_bytes

if TYPE_CHECKING:
    from pipeline.export.shard_rows import ShardRow

# The splits a run's manifests hold; ``full_eval`` (the release's name) reads ``full_test``.
SPLITS = ("minival", "full_test")
MAX_MANIFEST_BYTES = 64 << 20


@dataclasses.dataclass(frozen=True)
class Clip:
    """One clip in the TAPVid-3D schema, its arrays read-only. ``open`` fills every field (``extrinsics``
    where the file holds them); a reader of some members only (``audit compare``, of a published clip
    or a prediction) leaves the others empty or None.

    name: the file's name without ``.npz``.
    source: the source whose folder holds it (``<out>/<source>/<clip>.npz``), else None.
    frames: the T frames, each as JPEG bytes; empty where they were not read.
    queries: [N, 3] float, (x, y, t): where track i is queried, in pixels of frame t; None where not
      read (a prediction file holds tracks and visibility only).
    tracks: [T, N, 3] float, metres, in each frame's camera frame (x right, y down, z forward).
    visibility: [T, N] bool.
    intrinsics: [4] float64, fx, fy, cx, cy of the stored frames (pixel centres at +0.5); None where
      not read (the release's ADT and Panoptic Studio files hold annotations only).
    extrinsics: [T, 4, 4] float, world-to-camera per frame; None where the file has none (Panoptic
      Studio, the release's ADT files) or they were not read.
    frame_size: (height, width) of the frames, from the first one's JPEG header; None where the file
      holds no frames.
    scene, unit: the scene and the unit a clip of a Parquet shard (``shards``) comes from; None for a
      clip file.
    quality: [N] float32, a shard's per-track quality figure (the fraction of frames each track is
      visible in); None for a clip file.
    """

    name: str
    source: str | None
    frames: tuple[bytes, ...]
    queries: np.ndarray | None
    tracks: np.ndarray
    visibility: np.ndarray
    intrinsics: np.ndarray | None
    extrinsics: np.ndarray | None
    frame_size: tuple[int, int] | None
    scene: str | None = None
    unit: str | None = None
    quality: np.ndarray | None = None

    @property
    def num_frames(self) -> int:
        return int(self.tracks.shape[0])

    @property
    def num_tracks(self) -> int:
        return int(self.tracks.shape[1])

    def image(self, t: int) -> np.ndarray:
        """Frame ``t`` decoded: [H, W, 3] uint8, RGB."""
        bgr = cv2.imdecode(np.frombuffer(self.frames[t], np.uint8), cv2.IMREAD_COLOR)
        if bgr is None:
            raise ValueError(f"{self.name}: frame {t} is not a decodable JPEG")
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def _read_only(array: np.ndarray) -> np.ndarray:
    array.flags.writeable = False
    return array


def from_members(path: str, members: Mapping[str, np.ndarray], frame_size: tuple[int, int] | None) -> Clip:
    """The clip of the members a reader read from the file at ``path`` (its name and source from the
    path), by their names in the file (``pipeline.io.clip_reader.CLIP_KEYS``: ``tracks_XYZ`` and
    ``visibility`` at least), and its frames' (height, width) as the reader found it: visibility as
    bool, intrinsics as float64, every array read-only. Nothing is checked: ``open`` checks a whole
    clip first."""
    folder, _, file_name = path.rstrip("/").rpartition("/")
    source = folder.rpartition("/")[2]
    queries, intrinsics = members.get("queries_xyt"), members.get("fx_fy_cx_cy")
    extrinsics = members.get("extrinsics_w2c")
    return Clip(
        name=file_name[: -len(".npz")] if file_name.endswith(".npz") else file_name,
        source=source if source in sources.names() else None,
        frames=tuple(bytes(frame) for frame in members.get(FRAMES, ())),
        queries=None if queries is None else _read_only(queries),
        tracks=_read_only(members["tracks_XYZ"]),
        visibility=_read_only(members["visibility"].astype(bool, copy=False)),
        intrinsics=None if intrinsics is None else _read_only(intrinsics.astype(np.float64)),
        extrinsics=None if extrinsics is None else _read_only(extrinsics),
        frame_size=frame_size,
    )


def open(path: str, limits: ReadLimits = DEFAULT_LIMITS) -> Clip:
    """The clip in the file at ``path`` (any Beam filesystem), every field filled but ``extrinsics``
    where it holds none; ValueError naming the file when it is refused by the reader's caps, would
    need pickle, or is not shaped like a clip."""
    members = read_clip_file(path, limits)
    problems = invariants.structure_problems(members)
    if problems:
        raise ValueError(f"{path}: not a TAPVid-3D clip: {problems[0]}")
    return from_members(path, members, invariants.frame_size(members))


def shards(path: str, limits: ReadLimits = DEFAULT_LIMITS) -> Iterator[Clip]:
    """The clips of a folder of Parquet shards (``pipeline/export/shards.py``: a training run's
    ``<out>/train/<source>/``) or of one shard, on any Beam filesystem, one at a time: each file's row
    groups are read one by one, in the files' name order. ValueError naming the file when it is not a
    shard (a column missing or of another type), a row does not fit its T and N or exceeds
    ``limits``, or when a folder holds no shards or a set cut short."""
    # pyarrow is imported here, not with the module: what reads clip files only does not pay for it.
    import pyarrow as pa
    import pyarrow.parquet as pq

    from pipeline.export.shard_rows import ShardRow, shard_problems

    for file in shard_files(path):
        with open_binary(file) as handle:
            try:
                parquet = pq.ParquetFile(handle)
            except (pa.ArrowException, OSError) as error:
                raise ValueError(f"{file}: not a Parquet file ({error})") from error
            problems = shard_problems(parquet.schema_arrow)
            if problems:
                raise ValueError(f"{file}: not a shard of clips: {problems[0]}")
            for group in range(parquet.num_row_groups):
                declared = parquet.metadata.row_group(group).total_byte_size
                if declared > limits.max_clip_bytes * max(1, parquet.metadata.row_group(group).num_rows):
                    raise ValueError(f"{file}: row group {group} holds {declared} bytes, more than allowed")
                table = parquet.read_row_group(group)
                for row in range(table.num_rows):
                    yield _shard_clip(ShardRow.of(table, row, file), file, limits)


def _shard_clip(row: ShardRow, file: str, limits: ReadLimits) -> Clip:
    """A shard's row as a Clip; ValueError naming the file beyond ``limits`` or without a readable
    first frame."""
    num_frames, num_tracks = row.visibility.shape
    if num_frames > limits.max_frames or num_tracks > limits.max_tracks:
        raise ValueError(f"{file}: {row.name}: T = {num_frames}, N = {num_tracks}, beyond the limits")
    frame_size = jpeg_size(row.frames[0])
    if frame_size is None:
        raise ValueError(f"{file}: {row.name}: frame 0 is not a JPEG")
    return Clip(
        name=row.name,
        source=row.source,
        frames=row.frames,
        queries=row.queries,
        tracks=row.tracks,
        visibility=row.visibility,
        intrinsics=row.intrinsics,
        extrinsics=row.extrinsics,
        frame_size=frame_size,
        scene=row.scene,
        unit=row.unit,
        quality=row.quality,
    )


def split_paths(output: str, split: str) -> list[str]:
    """The clip files ``<output>/manifests/<split>.txt`` lists, in its order; ValueError naming an
    unknown split or a manifest that is missing or lists something other than ``<source>/<clip>.npz``."""
    name = "full_test" if split == "full_eval" else split
    if name not in SPLITS:
        raise ValueError(f"split {split!r}: a run's splits are {', '.join(SPLITS)} (or full_eval)")
    manifest = manifest_path(output.rstrip("/"), name)
    try:
        entries = read_bytes(manifest, MAX_MANIFEST_BYTES).decode().splitlines()
    except (OSError, UnicodeDecodeError) as error:
        raise ValueError(f"{manifest}: no manifest of a run ({error})") from error
    paths = []
    for number, entry in enumerate(entries, 1):
        source, _, file_name = entry.partition("/")
        if source not in sources.names() or not file_name.endswith(".npz") or "/" in file_name:
            raise ValueError(f"{manifest} line {number}: {entry!r} is not <source>/<clip>.npz")
        paths.append(clip_path(output.rstrip("/"), source, file_name[: -len(".npz")]))
    return paths


def split(output: str, name: str, limits: ReadLimits = DEFAULT_LIMITS) -> Iterator[Clip]:
    """The clips of the run in ``output`` that its manifest of split ``name`` lists, one at a time."""
    for path in split_paths(output, name):
        yield open(path, limits)
