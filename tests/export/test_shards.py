"""Parquet shards of a run's clips (``pipeline/export/shards.py``) and their reader
``pipeline.clips.shards``: every row holds its clip file's arrays; pyarrow's datasets and Hugging Face
``datasets`` read the shards unchanged; ``shard_bytes`` bounds the shards; the same clips give the
same bytes on two workers; a write killed mid-way leaves the earlier set whole and a rerun completes
the new one; replacing a set never shows a mix of two; the reader refuses what is not a shard, on a
local disk or S3."""

from __future__ import annotations

import glob
import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pyarrow as pa
import pyarrow.dataset as ds
import pyarrow.parquet as pq
import pytest

import pipeline.clips
from pipeline.export import shard_set
from pipeline.export.npz_writer import encode_npz
from pipeline.export.shard_rows import SCHEMA, shard_problems
from pipeline.export.shards import write_shards
from tests.support.cli import REPO
from tests.support.s3 import explicit_options_only

ARRAYS = ("queries", "tracks", "visibility", "intrinsics")


@pytest.fixture(scope="module")
def studio(reference_run, tmp_path_factory):
    """(clip paths, scenes, units) of the Panoptic Studio sample run's four clips, and a fifth: a copy
    of one with extrinsics [T, 4, 4] float64 (the studio's clips have none)."""
    run = reference_run("pstudio")
    paths = sorted(glob.glob(os.path.join(run, "pstudio", "*.npz")))
    units = {}
    for record in glob.glob(os.path.join(run, "units", "pstudio", "*.json")):
        for report in json.load(open(record))["reports"]:
            units[report["clip"]] = report["unit"]
    with np.load(paths[0]) as archive:
        members = {key: archive[key] for key in archive.files}
    steps = np.arange(len(members["visibility"]), dtype=np.float64)
    members["extrinsics_w2c"] = np.tile(np.eye(4), (len(steps), 1, 1))
    members["extrinsics_w2c"][:, :3, 3] = np.stack([steps * 1e3 + 0.125, -steps, steps / 3], axis=1)
    posed = tmp_path_factory.mktemp("posed") / "posed_3.npz"
    posed.write_bytes(encode_npz(members))
    units["posed_3"] = "posed/camera_3"
    paths.append(str(posed))
    scenes = {name: unit.partition("/")[0] for name, unit in units.items()}
    return paths, scenes, units


def clip_name(path: str) -> str:
    return os.path.basename(path)[: -len(".npz")]


def write(studio, folder, shard_bytes: int = 1 << 30, **kwargs) -> list[str]:
    paths, scenes, units = studio
    return write_shards(paths, str(folder), "pstudio", scenes, units, shard_bytes, **kwargs)


def shard_names(shards: list[str]) -> list[list[str]]:
    return [pq.read_table(path, columns=["name"]).column("name").to_pylist() for path in shards]


def test_each_row_holds_its_clip_files_arrays(studio, tmp_path):
    paths, scenes, units = studio
    started = time.monotonic()
    shards = write(studio, tmp_path / "train")
    print(f"5 clips written as 1 shard in {time.monotonic() - started:.1f} s")
    assert shards == [str(tmp_path / "train" / "train-00000-of-00001.parquet")]
    shard = pq.ParquetFile(shards[0])
    assert not shard_problems(shard.schema_arrow)
    assert shard.metadata.num_row_groups == len(paths)  # one row group per clip
    table = shard.read()
    assert table.column("name").to_pylist() == sorted(map(clip_name, paths))
    flickering = 0  # tracks whose quality is below 1: the figure is not constant here
    for row in table.to_pylist():
        clip = pipeline.clips.open(next(path for path in paths if clip_name(path) == row["name"]))
        frames, tracks = clip.num_frames, clip.num_tracks
        assert (row["source"], row["scene"], row["unit"]) == ("pstudio", scenes[clip.name], units[clip.name])
        assert (row["num_frames"], row["num_tracks"]) == (frames, tracks)
        assert tuple(row["frames"]) == clip.frames
        for column in ARRAYS:
            stored = getattr(clip, column)
            value = np.asarray(row[column], dtype=stored.dtype)
            assert np.array_equal(value, stored.reshape(-1)), (clip.name, column)
        changes = (clip.visibility[1:] != clip.visibility[:-1]).sum(axis=0)
        steadiness = (1 - changes / (clip.num_frames - 1)).astype(np.float32)
        assert np.array_equal(np.asarray(row["quality"], np.float32), steadiness)
        flickering += int((steadiness < 1).sum())
        if clip.extrinsics is None:
            assert row["extrinsics"] is None
        else:
            assert clip.extrinsics.dtype == np.float64
            assert np.array_equal(np.asarray(row["extrinsics"]), clip.extrinsics.reshape(-1))
    assert sorted(os.listdir(tmp_path / "train")) == [".lock", "train-00000-of-00001.parquet"]
    assert flickering > 0


def test_shards_streams_the_clips_as_open_reads_them(studio, tmp_path):
    paths, scenes, units = studio
    shards = write(studio, tmp_path / "train", shard_bytes=1_000_000)
    assert len(shards) > 1
    read = list(pipeline.clips.shards(str(tmp_path / "train")))
    assert [clip.name for clip in read] == sorted(map(clip_name, paths))
    for clip in read:
        opened = pipeline.clips.open(next(path for path in paths if clip_name(path) == clip.name))
        assert (clip.source, clip.scene, clip.unit) == ("pstudio", scenes[clip.name], units[clip.name])
        assert clip.frames == opened.frames and clip.frame_size == opened.frame_size
        for column in (*ARRAYS, "extrinsics"):
            stored, value = getattr(opened, column), getattr(clip, column)
            if stored is None:
                assert value is None
                continue
            assert value.dtype == stored.dtype and np.array_equal(value, stored), (clip.name, column)
            assert not value.flags.writeable
        assert clip.quality.dtype == np.float32 and clip.quality.shape == (clip.num_tracks,)
        assert clip.image(0).shape == (*clip.frame_size, 3)
    last = list(pipeline.clips.shards(shards[-1]))
    assert [clip.name for clip in last] == shard_names(shards)[-1]


def test_pyarrow_datasets_read_the_folder(studio, tmp_path):
    write(studio, tmp_path / "train", shard_bytes=1_000_000)
    table = ds.dataset(str(tmp_path / "train"), format="parquet").to_table()
    assert table.num_rows == len(studio[0])
    assert table.schema.names == SCHEMA.names
    assert sorted(table.column("name").to_pylist()) == sorted(map(clip_name, studio[0]))


def test_hugging_face_datasets_read_the_shards_unchanged(studio, tmp_path, monkeypatch):
    monkeypatch.setenv("HF_DATASETS_OFFLINE", "1")
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    monkeypatch.setenv("HF_HOME", str(tmp_path / "hf_home"))
    import datasets

    shards = write(studio, tmp_path / "train", shard_bytes=1_000_000)
    cache = str(tmp_path / "hf")
    loaded = datasets.load_dataset("parquet", data_files=shards, split="train", cache_dir=cache)
    assert loaded.column_names == SCHEMA.names
    assert loaded["name"] == sorted(map(clip_name, studio[0]))
    row = loaded[0]
    clip = pipeline.clips.open(studio[0][0])
    assert row["name"] == clip.name and row["frames"] == list(clip.frames)
    tracks = np.asarray(row["tracks"], np.float32).reshape(row["num_frames"], row["num_tracks"], 3)
    assert np.array_equal(tracks, clip.tracks)
    assert np.array_equal(np.asarray(row["visibility"]).reshape(clip.visibility.shape), clip.visibility)
    # The folder alone: its files' names make them the train split.
    folder = datasets.load_dataset(str(tmp_path / "train"), split="train", cache_dir=cache)
    assert folder["name"] == loaded["name"]


def test_a_small_shard_bytes_gives_several_bounded_shards_each_clip_in_one(studio, tmp_path):
    paths = studio[0]
    sizes = {clip_name(path): os.path.getsize(path) for path in paths}
    shard_bytes = sum(sizes.values()) // 3 + 1
    shards = write(studio, tmp_path / "train", shard_bytes=shard_bytes)
    expected = [f"train-{index:05d}-of-00003.parquet" for index in range(3)]
    assert [os.path.basename(path) for path in shards] == expected
    names = shard_names(shards)
    assert [name for shard in names for name in shard] == sorted(sizes)  # each once, in name order
    for shard in names:
        assert shard and sum(sizes[name] for name in shard) <= shard_bytes + max(sizes.values())
    one_each = write(studio, tmp_path / "tiny", shard_bytes=1)
    assert shard_names(one_each) == [[name] for name in sorted(sizes)]
    # A rerun with other bounds replaces the folder's set: no shard of the earlier one is left.
    again = write(studio, tmp_path / "train")
    assert sorted(glob.glob(str(tmp_path / "train" / "*.parquet"))) == again


def shard_bytes_by_name(shards: list[str]) -> dict[str, bytes]:
    return {os.path.basename(path): open(path, "rb").read() for path in shards}


def test_two_workers_write_the_same_bytes(studio, tmp_path):
    """The shards, their names, rows and row order, do not depend on the runner or its workers:
    Beam's Dask runner on a cluster of two processes (where Beam's own WriteToParquet finalizes
    empty shards) writes the DirectRunner's bytes."""
    from distributed import Client, LocalCluster

    direct = shard_bytes_by_name(write(studio, tmp_path / "direct", shard_bytes=1_000_000))
    assert len(direct) == 3
    with (
        LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as local,
        Client(local) as client,
    ):
        dask = [
            "--runner=apache_beam.runners.dask.dask_runner.DaskRunner",
            f"--dask_client_address={local.scheduler_address}",
            "--dask_partition_size=1",
        ]
        on_dask = write(studio, tmp_path / "dask", shard_bytes=1_000_000, pipeline_args=dask)
        tasks = client.run(lambda dask_worker: dask_worker.state.executed_count)
    assert len(tasks) == 2 and all(tasks.values()), tasks
    assert shard_bytes_by_name(on_dask) == direct


# Writes the shards of the clips given as JSON on stdin, each clip's row a second late: the test kills
# this process while the sink's temporary files are being written.
SLOW_WRITER = """
import json, sys, time
import pipeline.export.shards as shards
made = shards.clip_table
def slow(*args, **kwargs):
    time.sleep(1.0)
    return made(*args, **kwargs)
shards.clip_table = slow
paths, scenes, units, folder = json.load(sys.stdin)
shards.write_shards(paths, folder, "pstudio", scenes, units, 1)
"""


def test_a_write_killed_mid_way_leaves_the_earlier_set_and_a_rerun_completes(studio, tmp_path):
    paths, scenes, units = studio
    folder = tmp_path / "train"
    earlier = write_shards(paths[:2], str(folder), "pstudio", scenes, units, 1)
    earlier_bytes = {path: open(path, "rb").read() for path in earlier}
    writer = subprocess.Popen(
        [sys.executable, "-c", textwrap.dedent(SLOW_WRITER)], cwd=REPO, stdin=subprocess.PIPE, text=True
    )
    assert writer.stdin is not None
    writer.stdin.write(json.dumps([paths, scenes, units, str(folder)]))
    writer.stdin.close()
    temporaries = str(folder / ".train.staging-*" / "beam-temp-*" / "*.parquet")
    deadline = time.monotonic() + 120
    while not glob.glob(temporaries) and writer.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    assert glob.glob(temporaries), "the writer wrote no temporary shard"
    os.kill(writer.pid, signal.SIGKILL)
    writer.wait()
    # The earlier set is whole and alone; the killed write's files are hidden in its staging folder.
    assert sorted(glob.glob(str(folder / "*.parquet"))) == earlier
    assert {path: open(path, "rb").read() for path in earlier} == earlier_bytes
    assert [clip.name for clip in pipeline.clips.shards(str(folder))] == sorted(map(clip_name, paths[:2]))
    assert glob.glob(str(folder / ".train.staging-*"))
    rerun = write_shards(paths, str(folder), "pstudio", scenes, units, 1)
    assert len(rerun) == len(paths)
    assert sorted(glob.glob(str(folder / "*.parquet"))) == rerun
    assert not glob.glob(str(folder / ".train.staging-*"))  # the killed write's staging folder is gone
    assert [clip.name for clip in pipeline.clips.shards(str(folder))] == sorted(map(clip_name, paths))


class Cut(Exception):
    """The process dies here."""


def test_replacing_a_set_never_shows_two_sets_mixed(studio, tmp_path, monkeypatch):
    """A publish cut short after each of its steps (deletes, then moves) leaves the old set whole, a
    set missing an index, no shard, or the new set whole: the reader refuses the middle ones."""
    paths, scenes, units = studio
    old = write_shards(paths[:2], str(tmp_path / "old"), "pstudio", scenes, units, 1)
    new = write_shards(paths[2:4], str(tmp_path / "new"), "pstudio", scenes, units, 1)
    old_bytes = {os.path.basename(p): open(p, "rb").read() for p in old}
    new_bytes = {os.path.basename(p): open(p, "rb").read() for p in new}
    assert set(old_bytes) == set(new_bytes)  # the same names: only the contents tell the sets apart
    steps = len(old) + len(new)
    seen = set()
    for cut_after in range(steps + 1):
        folder, staging = tmp_path / f"cut{cut_after}", tmp_path / f"cut{cut_after}" / ".train.staging-x"
        shutil.copytree(tmp_path / "old", folder)
        shutil.copytree(tmp_path / "new", staging)
        done = []

        def step(real, *args, done=done, cut_after=cut_after):
            if len(done) == cut_after:
                raise Cut
            done.append(args)
            return real(*args)

        with monkeypatch.context() as patch:
            patch.setattr(os, "remove", lambda path, real=os.remove: step(real, path))
            patch.setattr(os, "replace", lambda a, b, real=os.replace: step(real, a, b))
            try:
                shard_set.publish(shard_set.shard_paths(str(staging), "train"), str(folder), "train")
            except Cut:
                pass
        found = {os.path.basename(p): open(p, "rb").read() for p in glob.glob(str(folder / "*.parquet"))}
        if not found:
            seen.add("none")
            with pytest.raises(ValueError, match="no Parquet shards"):
                list(pipeline.clips.shards(str(folder)))
        elif shard_set.set_problems(sorted(found)):
            seen.add("incomplete")
            with pytest.raises(ValueError, match="missing"):
                list(pipeline.clips.shards(str(folder)))
        else:
            assert found in (old_bytes, new_bytes), cut_after
            seen.add("old" if found == old_bytes else "new")
    assert seen == {"old", "incomplete", "none", "new"}


def test_shards_refuses_what_is_not_a_shard(studio, tmp_path):
    other = tmp_path / "other.parquet"
    pq.write_table(pa.table({"name": ["a"], "tracks": [[1.0, 2.0]]}), other)
    with pytest.raises(ValueError, match=f"{other}: not a shard of clips: no column 'source'"):
        list(pipeline.clips.shards(str(other)))
    shards = write(studio, tmp_path / "train")
    wrong = tmp_path / "wrong.parquet"
    table = pq.read_table(shards[0])
    index = table.schema.get_field_index("tracks")
    doubles = table.column("tracks").cast(pa.list_(pa.float64()))
    pq.write_table(table.set_column(index, "tracks", doubles), wrong)
    with pytest.raises(ValueError, match=f"{wrong}: not a shard of clips: column 'tracks' is list<"):
        list(pipeline.clips.shards(str(wrong)))
    text = tmp_path / "text.parquet"
    text.write_text("not parquet")
    with pytest.raises(ValueError, match=f"{text}: not a Parquet file"):
        list(pipeline.clips.shards(str(text)))
    with pytest.raises(ValueError, match="no Parquet shards"):
        list(pipeline.clips.shards(str(tmp_path / "nothing")))
    cut = tmp_path / "cut"
    several = write(studio, cut, shard_bytes=1)
    os.remove(several[1])
    with pytest.raises(ValueError, match="train-\\*-of-00005: missing 00001"):
        list(pipeline.clips.shards(str(cut)))


def test_bad_arguments_are_refused_before_any_work(studio, tmp_path):
    paths, scenes, units = studio
    folder = str(tmp_path / "train")
    with pytest.raises(ValueError, match="no clips"):
        write_shards([], folder, "pstudio", scenes, units, 1)
    with pytest.raises(ValueError, match="shard_bytes 0"):
        write_shards(paths, folder, "pstudio", scenes, units, 0)
    with pytest.raises(ValueError, match=f"clip {clip_name(paths[0])}: two files"):
        write_shards([paths[0], paths[0]], folder, "pstudio", scenes, units, 1)
    with pytest.raises(ValueError, match="no scene or no unit"):
        write_shards(paths, folder, "pstudio", {}, units, 1)
    with pytest.raises(ValueError, match="not a clip file"):
        write_shards([folder + "/clip.parquet"], folder, "pstudio", scenes, units, 1)
    assert not os.path.exists(folder)


@pytest.fixture
def s3(monkeypatch):
    """(endpoint URL, boto3 client) of an S3 server on 127.0.0.1 with an empty bucket, configured by
    explicit options only (no profile, endpoint or instance metadata from the environment)."""
    import boto3
    from moto.server import ThreadedMotoServer

    explicit_options_only(monkeypatch)
    server = ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    server.start()
    try:
        host, port = server.get_host_and_port()
        endpoint = f"http://{host}:{port}"
        credentials = {"aws_access_key_id": "testing", "aws_secret_access_key": "testing"}
        client = boto3.client("s3", endpoint_url=endpoint, region_name="us-east-1", **credentials)
        client.create_bucket(Bucket="tapvid3d")
        yield endpoint, client
    finally:
        server.stop()


def test_shards_on_s3_are_written_replaced_and_streamed(studio, s3):
    endpoint, client = s3
    options = [
        f"--s3_endpoint_url={endpoint}",
        "--s3_access_key_id=testing",
        "--s3_secret_access_key=testing",
        "--s3_region_name=us-east-1",
    ]
    paths, scenes, units = studio
    for path in paths:
        client.upload_file(path, "tapvid3d", f"run/pstudio/{os.path.basename(path)}")
    remote = [f"s3://tapvid3d/run/pstudio/{os.path.basename(path)}" for path in paths]
    folder = "s3://tapvid3d/run/train/pstudio"
    write_shards(remote[:2], folder, "pstudio", scenes, units, 1, options)
    shards = write_shards(remote, folder, "pstudio", scenes, units, 1_000_000, options)
    assert len(shards) > 1
    keys = sorted(item["Key"] for item in client.list_objects_v2(Bucket="tapvid3d")["Contents"])
    assert [key for key in keys if key.startswith("run/train/")] == [
        path.removeprefix("s3://tapvid3d/") for path in shards
    ]
    read = list(pipeline.clips.shards(folder))
    assert [clip.name for clip in read] == sorted(map(clip_name, paths))
    for clip in read:
        opened = pipeline.clips.open(next(path for path in paths if clip_name(path) == clip.name))
        assert clip.frames == opened.frames and np.array_equal(clip.tracks, opened.tracks)
