"""A clip as one row of a Parquet shard, both ways: ``clip_table`` turns a clip file's members into a
one-row table of ``SCHEMA``; ``shard_problems`` and ``ShardRow.of`` check a shard's schema and read a
row back as arrays.

Every array is a flat list beside ``num_frames`` (T) and ``num_tracks`` (N), so pyarrow and Hugging
Face ``datasets`` read the rows unchanged::

    name, source, scene, unit   string
    num_frames, num_tracks      int32
    frames                      list<binary>   [T] JPEG bytes
    intrinsics                  list<float64>  [4] fx, fy, cx, cy
    extrinsics                  list<float64>  [T * 16] world-to-camera, row-major; null without them
    queries                     list<float32>  [N * 3] x, y, t
    tracks                      list<float32>  [T * N * 3] metres, camera frame
    visibility                  list<bool>     [T * N]
    quality                     list<float32>  [N] per track

Values are stored as the clip file stores them (float32 queries and tracks, float64 intrinsics and
extrinsics): a row's arrays equal its file's. ``quality`` is each track's steadiness
(``track_quality``), read from its visibility: a clip file keeps no other per-track figure.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping

import numpy as np
import pyarrow as pa

from pipeline.filters.flicker import visibility_flips
from pipeline.io.clip_reader import FRAMES

# Written into every shard's schema: what the file is and the version of its layout.
FORMAT_KEY = b"tapvid3d.shard"
FORMAT_VERSION = b"1"

SCHEMA = pa.schema(
    [
        ("name", pa.string()),
        ("source", pa.string()),
        ("scene", pa.string()),
        ("unit", pa.string()),
        ("num_frames", pa.int32()),
        ("num_tracks", pa.int32()),
        ("frames", pa.list_(pa.binary())),
        ("intrinsics", pa.list_(pa.float64())),
        ("extrinsics", pa.list_(pa.float64())),
        ("queries", pa.list_(pa.float32())),
        ("tracks", pa.list_(pa.float32())),
        ("visibility", pa.list_(pa.bool_())),
        ("quality", pa.list_(pa.float32())),
    ],
    metadata={FORMAT_KEY: FORMAT_VERSION},
)
# Each member of a clip file and the dtype its column stores.
STORED = {
    "queries_xyt": np.dtype(np.float32),
    "tracks_XYZ": np.dtype(np.float32),
    "fx_fy_cx_cy": np.dtype(np.float64),
    "extrinsics_w2c": np.dtype(np.float64),
}


def track_quality(visibility: np.ndarray) -> np.ndarray:
    """[N] float32: each track's steadiness, 1 - its visibility changes / (T - 1), from visibility
    [T, N] (1: never flips; a single frame counts as steady). On the worlds with ray-cast truth,
    steady tracks are the ones the visibility gets right most often (docs/training.md)."""
    changes = visibility_flips(visibility).astype(np.float64)
    return (1.0 - changes / max(visibility.shape[0] - 1, 1)).astype(np.float32)


def clip_table(name: str, members: Mapping[str, np.ndarray], source: str, scene: str, unit: str) -> pa.Table:
    """The one-row table of ``SCHEMA`` for the clip ``name`` whose file holds ``members`` (checked to
    be a clip: ``invariants.structure_problems``). ValueError naming the clip when a member's dtype is
    not the one its column stores (a pipeline's clip file always has them)."""
    for key, dtype in STORED.items():
        if key in members and members[key].dtype != dtype:
            raise ValueError(f"{name}: {key} is {members[key].dtype}, a shard stores {dtype}")
    visibility = members["visibility"]
    extrinsics = members.get("extrinsics_w2c")
    frames = [bytes(frame) for frame in members[FRAMES]]
    columns = {
        "name": pa.array([name]),
        "source": pa.array([source]),
        "scene": pa.array([scene]),
        "unit": pa.array([unit]),
        "num_frames": pa.array([len(frames)], pa.int32()),
        "num_tracks": pa.array([visibility.shape[1]], pa.int32()),
        "frames": _one_list(pa.array(frames, pa.binary())),
        "intrinsics": _one_list(members["fx_fy_cx_cy"]),
        "extrinsics": pa.nulls(1, SCHEMA.field("extrinsics").type)
        if extrinsics is None
        else _one_list(extrinsics),
        "queries": _one_list(members["queries_xyt"]),
        "tracks": _one_list(members["tracks_XYZ"]),
        "visibility": _one_list(visibility),
        "quality": _one_list(track_quality(visibility)),
    }
    return pa.Table.from_arrays([columns[field] for field in SCHEMA.names], schema=SCHEMA)


def _one_list(values: np.ndarray | pa.Array) -> pa.ListArray:
    """A list array of one list, the values (an array of any shape, flattened row-major) unchanged."""
    if isinstance(values, np.ndarray):
        values = pa.array(np.ascontiguousarray(values).reshape(-1))
    return pa.ListArray.from_arrays(pa.array([0, len(values)], pa.int32()), values)


def shard_problems(schema: pa.Schema) -> list[str]:
    """What keeps a Parquet file of ``schema`` from being a shard of clips: missing columns, or a
    column of another type (lists compared by their items' type). Empty when it is one."""
    problems = []
    for field in SCHEMA:
        if field.name not in schema.names:
            problems.append(f"no column {field.name!r}")
            continue
        found = schema.field(field.name).type
        if pa.types.is_list(field.type):
            same = pa.types.is_list(found) and found.value_type == field.type.value_type
        else:
            same = found == field.type
        if not same:
            problems.append(f"column {field.name!r} is {found}, a shard's is {field.type}")
    return problems


@dataclasses.dataclass(frozen=True)
class ShardRow:
    """One row of a shard, its arrays reshaped (read-only views of the table's buffers).

    frames: the T frames as JPEG bytes. queries: [N, 3] float32. tracks: [T, N, 3] float32.
    visibility: [T, N] bool. intrinsics: [4] float64. extrinsics: [T, 4, 4] float64 or None.
    quality: [N] float32.
    """

    name: str
    source: str
    scene: str
    unit: str
    frames: tuple[bytes, ...]
    queries: np.ndarray
    tracks: np.ndarray
    visibility: np.ndarray
    intrinsics: np.ndarray
    extrinsics: np.ndarray | None
    quality: np.ndarray

    @classmethod
    def of(cls, table: pa.Table, row: int, where: str) -> ShardRow:
        """Row ``row`` of ``table`` (a shard's columns); ValueError naming ``where`` (the file) and the
        clip when a value is missing or a list's length does not fit its T and N."""
        value = {name: table.column(name)[row] for name in SCHEMA.names}
        name = value["name"].as_py()
        missing = [key for key, item in value.items() if not item.is_valid and key != "extrinsics"]
        if missing:
            raise ValueError(f"{where}: row {row} ({name}): no value in {', '.join(missing)}")
        num_frames, num_tracks = value["num_frames"].as_py(), value["num_tracks"].as_py()
        shapes = {
            "frames": (num_frames,),
            "intrinsics": (4,),
            "extrinsics": (num_frames, 4, 4),
            "queries": (num_tracks, 3),
            "tracks": (num_frames, num_tracks, 3),
            "visibility": (num_frames, num_tracks),
            "quality": (num_tracks,),
        }
        if num_frames < 1 or num_tracks < 1:
            raise ValueError(f"{where}: {name}: T = {num_frames} frames and N = {num_tracks} tracks")
        for key, shape in shapes.items():
            if value[key].is_valid and value[key].values.null_count:
                raise ValueError(f"{where}: {name}: {key} holds nulls")
            if value[key].is_valid and len(value[key].values) != math.prod(shape):
                raise ValueError(
                    f"{where}: {name}: {key} holds {len(value[key].values)} values, "
                    f"{math.prod(shape)} for T = {num_frames} and N = {num_tracks}"
                )
        valid = [key for key in shapes if key != "frames" and value[key].is_valid]
        arrays = {key: _array(value[key], shapes[key]) for key in valid}
        extrinsics = arrays.get("extrinsics")
        return cls(
            name=name,
            source=value["source"].as_py(),
            scene=value["scene"].as_py(),
            unit=value["unit"].as_py(),
            frames=tuple(value["frames"].values.to_pylist()),
            queries=arrays["queries"],
            tracks=arrays["tracks"],
            visibility=arrays["visibility"],
            intrinsics=arrays["intrinsics"],
            extrinsics=extrinsics,
            quality=arrays["quality"],
        )


def _array(item: pa.ListScalar, shape: tuple[int, ...]) -> np.ndarray:
    """A list value (not null) as a read-only array of ``shape``."""
    array = np.asarray(item.values.to_numpy(zero_copy_only=False)).reshape(shape)
    array.flags.writeable = False
    return array
