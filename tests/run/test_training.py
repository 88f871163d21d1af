"""A training run (``python -m pipeline.run --training``, pipeline/runner/training.py): the units of
the benchmark's scenes are left out before any work and listed, a run on nothing else ends with
exit status 3, the clips of the other scenes are a plain run's with the same settings, each source's
clips hold at most ``training.clip_frames`` frames (windows of the whole clips, a ``--set`` of the
source's own length winning; a release run refuses windows), the training settings are checked at
the door, and the dataset card counts what the run's records count."""

from __future__ import annotations

import json
import os
import pathlib
import shutil

import numpy as np
import pyarrow.dataset
import pytest

import pipeline.clips
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
from pipeline.runner.splits import SAMPLE_RELEASE
from pipeline.runner.training import SPLITS_ENV
from tests.support.adt_excerpt import SAMPLE as ADT_EXCERPT
from tests.support.adt_excerpt import SETTINGS as ADT_SETTINGS
from tests.support.adt_excerpt import needs_excerpt
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


# ------------------------------------------------------------------------------- the clip lengths


def same_points(window: np.ndarray, whole: np.ndarray) -> list[tuple[int, int]]:
    """(window track, whole clip track) of each track of ``window`` [T, N, 3] whose positions are bit
    for bit those of a track of ``whole`` [T, M, 3] (the same point, tracked in both)."""
    tracks = {whole[:, j].tobytes(): j for j in range(whole.shape[1])}
    return [
        (i, tracks[window[:, i].tobytes()])
        for i in range(window.shape[1])
        if window[:, i].tobytes() in tracks
    ]


def test_a_studio_training_run_cuts_each_cameras_sequence_into_windows_of_clip_frames(
    studio_training, pstudio_sample, tmp_path
):
    whole_out, whole_result = studio_training
    assert "training: pstudio.clip_frames=64 (training.clip_frames; a plain run's: 0)" in whole_result.stdout
    out = tmp_path / "out"
    splits = splits_file(tmp_path, {"pstudio": ["tennis_3"]})
    windows = ("--set", "training.clip_frames=16")
    result = training("pstudio", out, splits, "--input", pstudio_sample[0], *ONE_CAMERA, *windows)
    assert result.returncode == 0, result.stderr
    assert "training: pstudio.clip_frames=16 (training.clip_frames; a plain run's: 0)" in result.stdout
    # the 40 frames: frames 0-15 and 16-31; the 8 left are fewer than pstudio.min_frames (24)
    assert sorted(clip_bytes(str(out), "pstudio")) == ["dome_3_w0.npz", "dome_3_w1.npz"]
    assert shard_rows(out / "train" / "pstudio") == [
        {"name": f"dome_3_w{k}", "scene": "dome", "unit": "dome/camera_3"} for k in (0, 1)
    ]
    shared = 0
    with np.load(whole_out / "pstudio" / "dome_3.npz") as whole:
        for k in (0, 1):
            frames = slice(16 * k, 16 * k + 16)
            with np.load(out / "pstudio" / f"dome_3_w{k}.npz") as window:
                np.testing.assert_array_equal(window["images_jpeg_bytes"], whole["images_jpeg_bytes"][frames])
                assert window["tracks_XYZ"].shape[0] == 16 and window["queries_xyt"][:, 2].max() <= 15
                pairs = same_points(window["tracks_XYZ"], whole["tracks_XYZ"][frames])
                for i, j in pairs:
                    np.testing.assert_array_equal(window["visibility"][:, i], whole["visibility"][frames, j])
                shared += len(pairs)
    assert shared >= 200  # of the 1,024 tracks of each window


def test_a_driving_training_run_cuts_each_objects_run_into_windows_of_clip_frames(
    reference_run, sample_split, tmp_path
):
    whole = pathlib.Path(reference_run("drivetrack")) / "drivetrack"  # a plain run: 256 tracks, whole runs
    out = tmp_path / "out"
    splits = splits_file(tmp_path, {"drivetrack": [clip_name("other_1_000_2_000", 1, "x")]})
    same = ("--set", "drivetrack.tracks_per_clip=256", "--set", "drivetrack.min_contiguous_frames=12")
    windows = ("--set", "training.clip_frames=16")
    result = training("drivetrack", out, splits, "--input", sample_split[0], *same, *windows)
    assert result.returncode == 0, result.stderr
    # each run of T frames: windows of 16 frames, and a rest of at least 12 (the 28-frame run's)
    lengths = {
        name[: -len(".npz")]: pipeline.clips.open(str(whole / name)).num_frames for name in os.listdir(whole)
    }
    assert sorted(lengths.values()) == [28, 33, 40, 40]
    expected = {
        f"{name}_w{k}.npz": (name, 16 * k, min(16 * k + 16, frames))
        for name, frames in lengths.items()
        for k in range(frames // 16 + 1)
        if min(16 * k + 16, frames) - 16 * k >= 12
    }
    assert sorted(clip_bytes(str(out), "drivetrack")) == sorted(expected) and len(expected) == 8
    compared = agree = 0
    for name, (run, start, stop) in expected.items():
        with np.load(out / "drivetrack" / name) as window, np.load(whole / f"{run}.npz") as clip:
            frames = slice(start, stop)
            for member in ("images_jpeg_bytes", "extrinsics_w2c"):
                np.testing.assert_array_equal(
                    window[member], clip[member][frames], err_msg=f"{name} {member}"
                )
            assert window["queries_xyt"][:, 2].max() < stop - start
            for i, j in same_points(window["tracks_XYZ"], clip["tracks_XYZ"][frames]):
                agree += int((window["visibility"][:, i] == clip["visibility"][frames, j]).sum())
                compared += stop - start
    # the points both track (~150 of them): the refined visibility reads the object's surface from the
    # clip's own sweeps, a window's fewer than its whole run's, and agrees on nearly every frame
    assert compared >= 50 * 16 and agree >= 0.99 * compared


@needs_excerpt
def test_adts_chunks_take_training_clip_frames(tmp_path):
    splits = splits_file(tmp_path, {"adt": ["Apartment_release_clean_seq131_0"]})
    out, plain = tmp_path / "out", tmp_path / "plain"
    excerpt = ("--input", str(ADT_EXCERPT), "--set", "adt.max_gt_offset_ms=40")
    result = training("adt", out, splits, *excerpt, "--set", "training.clip_frames=2")
    assert result.returncode == 0, result.stderr
    said = "training: adt.chunk_frames=2, adt.min_frames=2 (training.clip_frames; a plain run's: 300, 300)"
    assert said in result.stdout
    assert (
        run_in_process("adt", "--output", str(plain), "--input", str(ADT_EXCERPT), *ADT_SETTINGS).returncode
        == 0
    )
    made = clip_bytes(str(out), "adt")
    assert list(made) == ["aria_digital_twin_test_data_0.npz"] and made == clip_bytes(str(plain), "adt")


@pytest.mark.parametrize(
    ("source", "given", "lengths", "said"),
    [
        (
            "drivetrack",
            ["drivetrack.clip_frames=20"],
            {"clip_frames": 20},
            "--set drivetrack.clip_frames=20 wins over training.clip_frames (16): drivetrack.clip_frames=20",
        ),
        (
            "adt",
            ["adt.min_frames=10"],
            {"chunk_frames": 300, "min_frames": 10},
            "--set adt.min_frames=10 wins over training.clip_frames (16): adt.chunk_frames=300, "
            "adt.min_frames=10",
        ),
    ],
)
def test_a_set_of_the_sources_own_length_wins_over_the_trainings(source, given, lengths, said, tmp_path):
    splits = splits_file(tmp_path, {})
    argv = ["--source", source, "--input", str(tmp_path), "--output", str(tmp_path / "out"), "--training"]
    for assignment in [f"training.splits_file={splits}", "training.clip_frames=16", *given]:
        argv += ["--set", assignment]
    prepared = prepare_run(*parse_args(argv))
    assert prepared.training is not None and f"training: {said}" in prepared.training.lines
    assert {key: prepared.config.to_dict()[source][key] for key in lengths} == lengths


@pytest.mark.parametrize("source", ["drivetrack", "pstudio"])
def test_a_release_run_refuses_a_clip_length_that_cuts_the_releases_clips(source, tmp_path):
    out = tmp_path / "out"
    result = run_in_process(
        source, "--output", str(out), "--release", SAMPLE_RELEASE, "--set", f"{source}.clip_frames=16"
    )
    assert result.returncode == 2 and result.stdout == "" and not out.exists()
    assert result.stderr.splitlines() == [
        f"cannot start: --release makes the release's clips, whole: --set {source}.clip_frames=16 cuts them "
        "into clips it does not name; drop it"
    ]


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
            ["--set", "training.clip_frames=-1"],
            "--set training.clip_frames=-1: must be an integer in [0, 100000]",
        ),
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
