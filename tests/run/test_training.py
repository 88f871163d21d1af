"""A training run (``python -m pipeline.run --training``, pipeline/runner/training.py): the units of
the benchmark's scenes are left out before any work and listed, a run on nothing else ends with
exit status 3, the clips of the other scenes are a plain run's with the same settings, the training
settings are checked at the door, and the dataset card counts what the run's records count."""

from __future__ import annotations

import json
import os
import shutil

import numpy as np
import pyarrow.dataset
import pytest

from pipeline import sources
from pipeline.adt.units import SequenceChunk
from pipeline.adt.units import clip_scene as adt_clip_scene
from pipeline.adt.units import scene_of as adt_scene_of
from pipeline.drivetrack.sample.waymo_world import SEGMENT
from pipeline.drivetrack.units import SegmentCamera, clip_name
from pipeline.drivetrack.units import clip_scene as drivetrack_clip_scene
from pipeline.drivetrack.units import scene_of as drivetrack_scene_of
from pipeline.pstudio.sample.dynamic3dgs_files import SEQUENCE
from pipeline.pstudio.units import SequenceCamera
from pipeline.pstudio.units import clip_scene as pstudio_clip_scene
from pipeline.pstudio.units import scene_of as pstudio_scene_of
from pipeline.runner.command import parse_args
from pipeline.runner.prepare import prepare_run
from pipeline.runner.training import SPLITS_ENV
from tests.support.cli import clip_bytes, run_in_process
from tests.support.toy.source import TOY, write_sample

# The studio sample's quick setting: one camera, one unit.
ONE_CAMERA = ("--set", "pstudio.cameras=3")
STUDIO_UNITS = ["dome/camera_16", "dome/camera_21", "dome/camera_3", "dome/camera_8"]


def splits_file(folder, clips: dict[str, list[str]]) -> str:
    """A benchmark splits file in ``folder`` naming ``clips`` (source -> clip names) in full_eval."""
    path = os.path.join(folder, "splits.json")
    with open(path, "w") as handle:
        json.dump(
            {
                "minival": {},
                "full_eval": {source: [f"{n}.npz" for n in names] for source, names in clips.items()},
            },
            handle,
        )
    return path


def training(source: str, out, splits: str, *args: str):
    return run_in_process(
        source, "--output", str(out), "--training", "--set", f"training.splits_file={splits}", *args
    )


def shard_rows(folder) -> list[dict]:
    """The name, scene and unit of every row of the shards in ``folder``, as pyarrow reads them."""
    table = pyarrow.dataset.dataset(str(folder), format="parquet").to_table(columns=["name", "scene", "unit"])
    return sorted(table.to_pylist(), key=lambda row: row["name"])


def read_lines(path) -> list[dict]:
    with open(path) as handle:
        return [json.loads(line) for line in handle]


@pytest.fixture
def toy():
    sources.register(TOY)
    yield TOY
    sources.unregister(TOY.name)


@pytest.fixture(scope="module")
def studio_training(pstudio_sample, tmp_path_factory):
    """(output folder, completed process) of a training run of one studio camera whose splits file
    names another scene only."""
    base = tmp_path_factory.mktemp("studio_training")
    splits = splits_file(base, {"pstudio": ["tennis_3", "boxes_8"]})
    out = base / "out"
    return out, training("pstudio", out, splits, "--input", pstudio_sample[0], *ONE_CAMERA)


# ------------------------------------------------------------------------------- the scenes


def test_each_source_names_the_scene_of_its_units_and_of_the_benchmarks_clips():
    assert drivetrack_clip_scene(clip_name(SEGMENT, 2, "obj_1")) == SEGMENT
    assert drivetrack_scene_of(SegmentCamera(SEGMENT, 2)) == SEGMENT
    assert drivetrack_clip_scene("dome_3") is None
    assert pstudio_clip_scene("tennis_24") == "tennis" and pstudio_clip_scene("tennis") is None
    assert pstudio_scene_of(SequenceCamera(SEQUENCE, 3)) == SEQUENCE
    assert adt_clip_scene("Apartment_release_clean_seq131_6") == "Apartment_release_clean_seq131"
    assert adt_clip_scene("Apartment_release_clean_seq131") is None
    # a fetched sequence named as ADT v2 names it (a device-serial suffix) is the v1 sequence's scene
    fetched = SequenceChunk("url:Apartment_release_clean_seq131_M1292", -1)
    assert adt_scene_of(fetched) == "Apartment_release_clean_seq131"
    assert adt_scene_of(SequenceChunk("url:Lite_release_recognition_WoodenFork_seq031", 0)) == (
        "Lite_release_recognition_WoodenFork_seq031"
    )


# ------------------------------------------------------------------------------- left out


def test_a_splits_file_naming_the_sample_sequence_leaves_out_every_unit_and_ends_with_3(
    pstudio_sample, tmp_path
):
    splits = splits_file(tmp_path, {"pstudio": ["dome_3", "tennis_1"]})
    out = tmp_path / "out"
    result = training("pstudio", out, splits, "--input", pstudio_sample[0])
    assert result.returncode == 3, result.stderr
    rows = read_lines(out / "train" / "exclusions_pstudio.jsonl")
    assert sorted(row["unit"] for row in rows) == STUDIO_UNITS
    assert {(row["scene"], tuple(row["clips"])) for row in rows} == {("dome", ("dome_3",))}
    assert "training: left out 4 of 4 unit(s), of 1 benchmark scene(s)" in result.stdout
    assert result.stdout.splitlines()[-1].startswith(
        "no clip written: every one of the 4 unit(s) is of a scene"
    )
    assert not (out / "pstudio").exists() and not (out / "train" / "pstudio").exists()


def test_the_driving_samples_segment_leaves_out_each_of_its_cameras(sample_split, tmp_path):
    splits = splits_file(
        tmp_path, {"drivetrack": [clip_name(SEGMENT, 1, "car"), clip_name("other_1_000_2_000", 1, "x")]}
    )
    out = tmp_path / "out"
    result = training("drivetrack", out, splits, "--input", sample_split[0])
    assert result.returncode == 3, result.stderr
    rows = read_lines(out / "train" / "exclusions_drivetrack.jsonl")
    assert [row["unit"] for row in rows] == [f"{SEGMENT}/camera_{camera}" for camera in (1, 2, 3)]
    assert all(row["scene"] == SEGMENT and row["clips"] == [clip_name(SEGMENT, 1, "car")] for row in rows)


def test_only_the_units_of_benchmark_scenes_are_left_out(toy, tmp_path):
    root = write_sample(str(tmp_path / "in"))
    shutil.copy(os.path.join(root, "walk.json"), os.path.join(root, "stroll.json"))
    out = tmp_path / "out"
    result = training("toy", out, splits_file(tmp_path, {"toy": ["toy_stroll"]}), "--input", root)
    assert result.returncode == 0, result.stderr
    assert [row["unit"] for row in read_lines(out / "train" / "exclusions_toy.jsonl")] == ["stroll"]
    assert sorted(os.listdir(out / "toy")) == ["toy_walk.npz"]
    assert shard_rows(out / "train" / "toy") == [{"name": "toy_walk", "scene": "walk", "unit": "walk"}]


# ------------------------------------------------------------------------------- the clips


def test_a_splits_file_of_other_scenes_leaves_out_nothing_and_the_clips_are_a_plain_runs(
    studio_training, pstudio_sample, tmp_path
):
    out, result = studio_training
    assert result.returncode == 0, result.stderr
    assert (out / "train" / "exclusions_pstudio.jsonl").read_text() == ""
    assert "training: pstudio.tracks_per_clip=1024 (training.tracks_per_clip" in result.stdout
    plain = tmp_path / "plain"
    same = ("--input", pstudio_sample[0], *ONE_CAMERA, "--set", "pstudio.tracks_per_clip=1024")
    assert run_in_process("pstudio", "--output", str(plain), *same).returncode == 0
    made, expected = clip_bytes(str(out), "pstudio"), clip_bytes(str(plain), "pstudio")
    assert sorted(made) == sorted(expected) == ["dome_3.npz"]
    with np.load(out / "pstudio" / "dome_3.npz") as got, np.load(plain / "pstudio" / "dome_3.npz") as want:
        assert sorted(got.files) == sorted(want.files)
        for name in want.files:
            np.testing.assert_array_equal(got[name], want[name], err_msg=name)
        assert got["tracks_XYZ"].shape[1] == 1024
    assert shard_rows(out / "train" / "pstudio") == [
        {"name": "dome_3", "scene": "dome", "unit": "dome/camera_3"}
    ]


def test_an_explicit_tracks_per_clip_wins_over_the_trainings(pstudio_sample, tmp_path):
    splits = splits_file(tmp_path, {"pstudio": ["tennis_3"]})
    argv = ["--source", "pstudio", "--output", str(tmp_path / "out"), "--training"]
    argv += ["--set", f"training.splits_file={splits}", "--set", "pstudio.tracks_per_clip=60"]
    prepared = prepare_run(*parse_args(argv))
    assert prepared.config.to_dict()["pstudio"]["tracks_per_clip"] == 60
    assert prepared.config.rules == "refined"
    assert prepared.training is not None
    assert (
        "training: --set pstudio.tracks_per_clip=60 wins over training.tracks_per_clip (1024)"
        in prepared.training.lines
    )


# ------------------------------------------------------------------------------- the door


@pytest.mark.parametrize(
    ("extra", "said"),
    [
        (
            ["--set", "training.tracks_per_clip=0"],
            "--set training.tracks_per_clip=0: must be an integer in [1, 100000]",
        ),
        (["--set", "training.shard_mb=-1"], "--set training.shard_mb=-1: must be an integer in [1, 65536]"),
        (
            ["--set", "training.splits_file=/no/such/splits.json"],
            "--set training.splits_file=/no/such/splits.json does not exist",
        ),
        (
            ["--release", "splits.json"],
            "--training leaves out the benchmark's scenes, --release makes its clips: give one",
        ),
    ],
)
def test_a_bad_training_run_is_refused_in_one_line_before_any_work(extra, said, tmp_path):
    out = tmp_path / "out"
    result = run_in_process("pstudio", "--output", str(out), "--training", *extra)
    assert result.returncode == 2
    assert (
        said in result.stderr
        and len([line for line in result.stderr.splitlines() if "training" in line]) == 1
    )
    assert not out.exists() and result.stdout == ""


def test_without_a_splits_file_the_run_says_how_to_give_one(tmp_path, monkeypatch):
    monkeypatch.setenv(SPLITS_ENV, str(tmp_path / "absent.json"))
    out = tmp_path / "out"
    result = run_in_process("pstudio", "--output", str(out), "--training")
    assert result.returncode == 2 and not out.exists()
    (line,) = result.stderr.splitlines()
    assert "--set training.splits_file=FILE" in line and str(tmp_path / "absent.json") in line


def test_a_source_that_names_no_scene_cannot_make_a_training_run(tmp_path):
    import dataclasses

    sources.register(dataclasses.replace(TOY, scene_of=None, clip_scene=None))
    try:
        result = run_in_process("toy", "--output", str(tmp_path / "out"), "--training")
    finally:
        sources.unregister(TOY.name)
    assert result.returncode == 2
    assert "source toy does not say what a scene is" in result.stderr


# ------------------------------------------------------------------------------- the card


def test_the_cards_counts_are_the_runs_records(studio_training):
    out, result = studio_training
    assert result.returncode == 0, result.stderr
    card = json.loads((out / "train" / "DATASET_CARD.json").read_text())
    section = card["sources"]["pstudio"]
    summary = json.loads((out / "run_pstudio.json").read_text())["summary"]
    frames = 0
    for name in clip_bytes(str(out), "pstudio"):
        with np.load(out / "pstudio" / name) as clip:
            frames += clip["tracks_XYZ"].shape[0]
    assert section["counts"] == {
        "units": summary["units"],
        "units_failed": summary["units_failed"],
        "clips": summary["clips_written"],
        "tracks": summary["tracks_written"],
        "frames": frames,
    }
    assert section["filters"]["dropped"] == summary["dropped_by_filter"]
    assert section["exclusions"] == {
        "units": 0,
        "scenes": 0,
        "file": "exclusions_pstudio.jsonl",
        "splits_file": section["exclusions"]["splits_file"],
    }
    assert "http://domedb.perception.cs.cmu.edu/" in section["licence"]["links"]
    assert section["command"].startswith("python -m pipeline.run --source pstudio --input ")
    page = (out / "train" / "DATASET_CARD.md").read_text()
    assert "| pstudio | 1 | 1 | 1,024 |" in page and "non-commercial research" in page


def test_each_sources_run_updates_its_own_section_of_the_card(studio_training, toy, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(studio_training[0], out)
    before = json.loads((out / "train" / "DATASET_CARD.json").read_text())["sources"]["pstudio"]
    splits = splits_file(tmp_path, {"toy": ["toy_elsewhere"]})
    assert training("toy", out, splits, "--input", write_sample(str(tmp_path / "in"))).returncode == 0
    card = json.loads((out / "train" / "DATASET_CARD.json").read_text())
    assert card["sources"]["pstudio"] == before
    assert card["sources"]["toy"]["counts"]["clips"] == 1 and card["sources"]["toy"]["licence"] is None
    page = (out / "train" / "DATASET_CARD.md").read_text()
    assert "## pstudio" in page and "## toy" in page and "not stated by the source" in page


def test_a_rerun_that_leaves_out_every_unit_takes_the_earlier_shards_away(
    studio_training, pstudio_sample, tmp_path
):
    out = tmp_path / "out"
    shutil.copytree(studio_training[0], out)
    splits = splits_file(tmp_path, {"pstudio": ["dome_3"]})
    result = training("pstudio", out, splits, "--input", pstudio_sample[0], *ONE_CAMERA)
    assert result.returncode == 3, result.stderr
    assert (
        "training: removed 1 earlier shard(s) of pstudio and its section of the dataset card" in result.stdout
    )
    assert not list((out / "train" / "pstudio").glob("*.parquet"))
    assert json.loads((out / "train" / "DATASET_CARD.json").read_text())["sources"] == {}
