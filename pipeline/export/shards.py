"""A run's clips as Parquet shards, ``<folder>/<prefix>-SSSSS-of-NNNNN.parquet``, one row per clip
(``shard_rows.SCHEMA``), written by a Beam pipeline through Beam's own Parquet sink.

``write_shards`` sorts the clips by name and cuts them into ``ceil(total clip bytes / shard_bytes)``
shards (at least one, at most one per clip) of consecutive clips, about ``total / count`` bytes each
(``shard_bounds``). It runs the steps of ``apache_beam.io.parquetio.WriteToParquet`` with that
transform's sink, choosing each shard's rows: the sink's initialization (its temporary folder) and
finalize (its temporaries renamed to ``-SSSSS-of-NNNNN`` names, in their names' order) in this
process; in the pipeline, one writer of the sink per shard, writing its clips in name order, one row
group each (a reader streams a shard clip by clip), then committing its file under the shard's index
by a rename. WriteToParquet's own expansion deals rows out to shards at random, and on Beam's Dask
runner, which computes its initialization once per use, finalizes empty shards. Same clips, same
shards, to the byte: their names, rows and row order, on any runner and any number of workers.

Everything is written inside ``folder``: the sink's files in a hidden staging folder, whose complete
set then replaces the folder's earlier shards of the prefix (``shard_set.publish``); a write killed
before that leaves the earlier set whole (and its staging folder, which the next write deletes).
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import uuid
from bisect import bisect_left
from collections.abc import Mapping
from itertools import accumulate

import apache_beam as beam
import pyarrow as pa
from apache_beam.io.parquetio import WriteToParquet
from apache_beam.options.pipeline_options import PipelineOptions

from pipeline.core.progress import quiet_worker_logs
from pipeline.export import shard_set
from pipeline.export.invariants import structure_problems
from pipeline.export.shard_rows import SCHEMA, clip_table
from pipeline.io import storage
from pipeline.io.beam_pipeline import pipeline_for, run_to_end
from pipeline.io.clip_reader import read_clip_file
from pipeline.io.file_set import output_lock
from pipeline.io.files import filesystems, is_local, list_files, move_file

SHARD_PREFIX = "train"  # Hugging Face's name for the files of a dataset's train split
CODEC = "zstd"


def write_shards(
    clip_paths: list[str],
    folder: str,
    source: str,
    scenes: Mapping[str, str],
    units: Mapping[str, str],
    shard_bytes: int,
    pipeline_args: list[str] | None = None,
    *,
    prefix: str = SHARD_PREFIX,
) -> list[str]:
    """Write the clip files ``clip_paths`` (``<clip>.npz`` on any Beam filesystem, read by the bounded
    reader) as the shards of ``prefix`` in ``folder`` (any Beam filesystem), replacing its earlier
    ones; the shards' paths, by index. ``scenes`` and ``units`` give each clip's scene and unit by clip
    name; ``pipeline_args`` are Beam's options (the runner, its workers, S3's endpoint, ...), the
    DirectRunner by default. ValueError before any work for no clips, two clips of one name, a clip
    without scene or unit, or ``shard_bytes`` below 1; a clip file that is not a clip fails the run,
    leaving the earlier shards as they were."""
    if shard_bytes < 1:
        raise ValueError(f"shard_bytes {shard_bytes}: at least 1")
    clips = clip_names(clip_paths)
    unnamed = [name for name in clips if name not in scenes or name not in units]
    if unnamed:
        raise ValueError(f"clip {unnamed[0]}: no scene or no unit given ({len(unnamed)} clips in all)")
    options = PipelineOptions(pipeline_args or [])
    storage.use_options(options)
    folder = folder.rstrip("/")
    storage.check_scheme(folder)
    paths = [clips[name] for name in sorted(clips)]
    sizes = clip_sizes(paths)
    shards = [paths[start:stop] for start, stop in shard_bounds([sizes[p] for p in paths], shard_bytes)]
    rows = ClipRows(source, dict(scenes), dict(units))
    shard_set.remove_abandoned_staging(folder, prefix)
    staging = shard_set.staging_folder(folder, prefix)
    try:
        sink = parquet_sink(f"{staging}/{prefix}", len(shards))
        temporary_folder = sink.initialize_write()
        pipeline = pipeline_for(options)
        _ = (
            pipeline
            | "Shards" >> beam.Create(list(enumerate(shards)))
            | "WriteShard" >> beam.ParDo(WriteShard(sink, temporary_folder, prefix, rows, options))
        )
        run_to_end(pipeline)
        committed = [committed_path(temporary_folder, index, prefix) for index in range(len(shards))]
        listed = {path.rpartition("/")[2] for path in list_files(f"{temporary_folder}/*")}
        missing = [path for path in committed if path.rpartition("/")[2] not in listed]
        if missing:
            raise OSError(f"{missing[0]}: the pipeline ended without writing this shard")
        staged = [f"{staging}/{shard_set.shard_name(prefix, i, len(shards))}" for i in range(len(shards))]
        if list(sink.finalize_write(temporary_folder, committed, None)) != staged:
            raise OSError(f"{staging}: the sink did not finalize the shards {staged[0]}...")
        with output_lock(folder):
            return shard_set.publish(staged, folder, prefix)
    finally:
        shard_set.remove_tree(staging)


def clip_names(clip_paths: list[str]) -> dict[str, str]:
    """Each clip's path by its name (the file's, without ``.npz``); ValueError for no clips, a path
    that is not a ``.npz`` or two clips of one name."""
    if not clip_paths:
        raise ValueError("no clips to write as shards")
    names: dict[str, str] = {}
    for path in clip_paths:
        file_name = path.rpartition("/")[2]
        if not file_name.endswith(".npz"):
            raise ValueError(f"{path}: not a clip file (<clip>.npz)")
        name = file_name[: -len(".npz")]
        if name in names:
            raise ValueError(f"clip {name}: two files, {names[name]} and {path}")
        names[name] = path
    return names


def clip_sizes(paths: list[str]) -> dict[str, int]:
    """Each file's size in bytes: one listing per folder on a remote filesystem. FileNotFoundError
    naming a missing file."""
    sizes: dict[str, int] = {}
    remote: dict[str, list[str]] = {}
    for path in paths:
        if is_local(path):
            sizes[path] = os.path.getsize(path)
        else:
            remote.setdefault(path.rpartition("/")[0], []).append(path)
    for parent, inside in remote.items():
        listed = filesystems().match([f"{parent}/*.npz"])[0].metadata_list
        found = {match.path: match.size_in_bytes for match in listed}
        for path in inside:
            if path not in found:
                raise FileNotFoundError(f"missing clip file {path}")
            sizes[path] = found[path]
    return sizes


def shard_bounds(sizes: list[int], shard_bytes: int) -> list[tuple[int, int]]:
    """[start, stop) of each shard over clips of ``sizes`` bytes (in name order): ceil(total /
    shard_bytes) shards, at least one and at most one per clip, consecutive clips each. Shard k starts
    at the first clip whose middle lies at or past k / count of the bytes: a shard holds about total /
    count bytes, at most that plus half its first and half its last clip."""
    total = sum(sizes)
    count = min(len(sizes), max(1, -(-total // shard_bytes)))
    # Twice the byte offset of each clip's middle (integers: no rounding), non-decreasing.
    middles = [2 * end - size for end, size in zip(accumulate(sizes), sizes, strict=True)]
    starts = [0]
    for k in range(1, count):
        start = bisect_left(middles, -(-2 * k * total // count))
        starts.append(min(max(start, starts[-1] + 1), len(sizes) - (count - k)))
    return list(zip(starts, [*starts[1:], len(sizes)], strict=True))


@dataclasses.dataclass(frozen=True)
class ClipRows:
    """What makes a clip file a shard's row: the source, and each clip's scene and unit by name."""

    source: str
    scenes: Mapping[str, str]
    units: Mapping[str, str]

    def table(self, path: str) -> pa.Table:
        """The clip file's one-row table; ValueError naming the file when it is not a clip."""
        members = read_clip_file(path)
        problems = structure_problems(members)
        if problems:
            raise ValueError(f"{path}: not a TAPVid-3D clip: {problems[0]}")
        name = path.rpartition("/")[2][: -len(".npz")]
        return clip_table(name, members, self.source, self.scenes[name], self.units[name])


def parquet_sink(file_path_prefix: str, num_shards: int):
    """Beam's Parquet sink as WriteToParquet makes it for ``SCHEMA``: files
    ``<file_path_prefix>-SSSSS-of-NNNNN.parquet``, zstd, Parquet's standard list layout."""
    writing = WriteToParquet(
        file_path_prefix,
        SCHEMA,
        codec=CODEC,
        use_compliant_nested_type=True,
        file_name_suffix=shard_set.SUFFIX,
        num_shards=num_shards,
    )
    return writing._sink


def committed_path(temporary_folder: str, index: int, prefix: str) -> str:
    """Where shard ``index``'s writer puts its finished file in the sink's temporary folder."""
    return f"{temporary_folder}/{index:09d}.{prefix}{shard_set.SUFFIX}"


class WriteShard(beam.DoFn):
    """(index, clip paths) -> the shard's file, its clips one row group each, written by a writer of
    the sink into its temporary folder and committed by a rename to ``committed_path`` (a retried
    or repeated write replaces it with the same bytes)."""

    def __init__(self, sink, temporary_folder: str, prefix: str, rows: ClipRows, options: PipelineOptions):
        self.sink, self.temporary_folder, self.prefix = sink, temporary_folder, prefix
        self.rows, self.options = rows, options

    def setup(self):
        quiet_worker_logs()
        storage.use_options(self.options)  # Beam's Dask runner gives its workers no filesystem options

    def process(self, shard):
        index, paths = shard
        writer = self.sink.open_writer(self.temporary_folder, f"{index:09d}-{uuid.uuid4().hex}")
        try:
            for path in paths:
                writer.write(self.rows.table(path))
        except BaseException:
            with contextlib.suppress(Exception):
                writer.close()
            raise
        committed = committed_path(self.temporary_folder, index, self.prefix)
        move_file(writer.close(), committed)
        yield committed
