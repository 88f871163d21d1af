"""``--release``: a run restricted to the release's clips writes exactly those clips, byte for byte
the clips a plain run makes of the same names, manifests exactly the file's splits, and a verdict for
every clip the file names, with its reason. The splits file here names, per sample, two real clips
(one per split), plus clips a run cannot make: an object id the segment does not have, an object of
another camera, a segment and a sequence absent from --input, a Panoptic camera absent from its
train_meta.json, a chunk past the ADT excerpt's end, and a camera whose images are corrupt."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from pipeline.audit.__main__ import main as audit_main
from pipeline.samples.waymo_world import SEGMENT
from tests.support.adt_excerpt import ONE_FRAME_CHUNKS, SAMPLE, needs_excerpt
from tests.support.cli import clip_bytes, run_in_process

LEAD = f"tapvid3d_{SEGMENT}_1_lead_car_AAAAAAAAAAAAAAAAAAAAAA"
PARKED = f"tapvid3d_{SEGMENT}_3_parked_right_DDDDDDDDDDDDDDDDDD"
PARKED_ON_1 = f"tapvid3d_{SEGMENT}_1_parked_right_DDDDDDDDDDDDDDDDDD"
NO_OBJECT = f"tapvid3d_{SEGMENT}_2_no_such_object"
NO_SEGMENT = "tapvid3d_1234567890_0_000_20_000_1_someone"
ADT = SAMPLE.name  # the excerpt's folder name is its v1 sequence name

RELEASE = {
    "minival": {"drivetrack": [f"{LEAD}.npz"], "pstudio": ["dome_3.npz"], "adt": [f"{ADT}_0.npz"]},
    "full_eval": {
        "drivetrack": [f"{name}.npz" for name in (PARKED, PARKED_ON_1, NO_OBJECT, NO_SEGMENT)],
        "pstudio": ["dome_8.npz", "dome_16.npz", "dome_5.npz", "hall_2.npz"],
        "adt": [f"{ADT}_1.npz", f"{ADT}_5.npz", "Apartment_release_absent_seq001_0.npz"],
    },
}
WRITTEN = {"drivetrack": {LEAD, PARKED}, "pstudio": {"dome_3", "dome_8"}, "adt": {f"{ADT}_0", f"{ADT}_1"}}
# clip -> (status, reason) of every clip a run cannot make.
NOT_WRITTEN = {
    PARKED_ON_1: (
        "not_produced",
        "object parked_right_DDDDDDDDDDDDDDDDDD belongs to camera 3 (the one that sees it most), not 1",
    ),
    NO_OBJECT: ("not_produced", "object id no_such_object is not among the segment's boxes"),
    NO_SEGMENT: ("input_absent", "segment 1234567890_0_000_20_000 is not in --input"),
    "dome_5": ("input_absent", "camera 5 is not among dome's train_meta.json cameras (3, 8, 16, 21)"),
    "hall_2": ("input_absent", "sequence hall is not in --input"),
    f"{ADT}_5": ("not_produced", "chunk 5 starts past the sequence's 2 annotated frames"),
    "Apartment_release_absent_seq001_0": (
        "input_absent",
        "sequence Apartment_release_absent_seq001 is not in --input",
    ),
}


@pytest.fixture(scope="module")
def release_file(tmp_path_factory) -> str:
    path = tmp_path_factory.mktemp("release") / "splits.json"
    path.write_text(json.dumps(RELEASE))
    return str(path)


@pytest.fixture(scope="module")
def studio_with_a_corrupt_camera(pstudio_sample, tmp_path_factory) -> str:
    """The studio sample (hard links) with camera 16's first image replaced by junk."""
    from tests.conftest import link_tree

    root = str(tmp_path_factory.mktemp("studio") / "root")
    link_tree(pstudio_sample[0], root)
    image = os.path.join(root, "data", "dome", "ims", "16", "000000.jpg")
    os.remove(image)
    with open(image, "wb") as handle:
        handle.write(b"not a jpeg")
    return root


@pytest.fixture(scope="module")
def release_run(release_file, sample_split, studio_with_a_corrupt_camera, tmp_path_factory):
    """One output folder holding a --release run of each source: {source: CompletedProcess}."""
    out = str(tmp_path_factory.mktemp("release_out"))
    inputs = {
        "drivetrack": (sample_split[0],),
        "pstudio": (studio_with_a_corrupt_camera,),
        "adt": (str(SAMPLE), *ONE_FRAME_CHUNKS),
    }
    runs = {}
    for source, (root, *settings) in inputs.items():
        if source == "adt" and not SAMPLE.is_dir():
            continue
        runs[source] = run_in_process(
            source, "--input", root, "--output", out, "--release", release_file, *settings
        )
    return out, runs


@pytest.fixture(scope="module")
def plain_adt(tmp_path_factory) -> str:
    out = str(tmp_path_factory.mktemp("plain_adt"))
    result = run_in_process("adt", "--input", str(SAMPLE), "--output", out, *ONE_FRAME_CHUNKS)
    assert result.returncode == 0, result.stderr[-3000:]
    return out


def verdicts(out: str, source: str) -> dict[str, dict]:
    with open(os.path.join(out, f"release_{source}.jsonl")) as handle:
        return {row["clip"]: row for row in map(json.loads, handle)}


def test_exit_status_and_summary_line(release_run):
    _, runs = release_run
    assert runs["drivetrack"].returncode == 0, runs["drivetrack"].stderr[-3000:]
    assert (
        "release clips: 5 named, 2 written, 2 not produced, 1 input absent, 0 failed"
        in runs["drivetrack"].stdout
    )
    assert runs["pstudio"].returncode == 1  # camera 16's unit failed
    assert (
        "release clips: 5 named, 2 written, 0 not produced, 2 input absent, 1 failed"
        in runs["pstudio"].stdout
    )


@needs_excerpt
def test_adt_summary_line(release_run):
    _, runs = release_run
    assert runs["adt"].returncode == 0, runs["adt"].stderr[-3000:]
    assert "release clips: 4 named, 2 written, 1 not produced, 1 input absent, 0 failed" in runs["adt"].stdout


@pytest.mark.parametrize("source", ["drivetrack", "pstudio"])
def test_only_the_named_clips_are_written_with_a_plain_runs_bytes(release_run, reference_run, source):
    out, _ = release_run
    written = clip_bytes(out, source)
    assert set(written) == {f"{name}.npz" for name in WRITTEN[source]}
    plain = clip_bytes(reference_run(source), source)
    assert all(written[name] == plain[name] for name in written)


@needs_excerpt
def test_adt_release_clips_are_the_plain_runs_bytes(release_run, plain_adt):
    out, _ = release_run
    written = clip_bytes(out, "adt")
    assert set(written) == {f"{name}.npz" for name in WRITTEN["adt"]}
    assert written == clip_bytes(plain_adt, "adt")


def test_manifests_are_exactly_the_files_splits(release_run):
    out, _ = release_run
    sources = [source for source in RELEASE["minival"] if os.path.isdir(os.path.join(out, source))]
    for split, key in (("minival", "minival"), ("full_test", "full_eval")):
        listed = open(os.path.join(out, "manifests", f"{split}.txt")).read().splitlines()
        expected = sorted(
            f"{source}/{name}"
            for source in sources
            for name in RELEASE[key][source]
            if name[: -len(".npz")] in WRITTEN[source]
        )
        assert listed == expected


@pytest.mark.parametrize("source", ["drivetrack", "pstudio", "adt"])
def test_every_named_clip_has_its_verdict(release_run, source):
    out, runs = release_run
    if source not in runs:
        pytest.skip("the ADT excerpt is absent")
    rows = verdicts(out, source)
    named = {
        name[: -len(".npz")]: split for split in ("minival", "full_eval") for name in RELEASE[split][source]
    }
    assert set(rows) == set(named)
    for clip, row in rows.items():
        assert row["split"] == named[clip]
        if clip in WRITTEN[source]:
            with np.load(os.path.join(out, source, f"{clip}.npz")) as data:
                tracks = data["tracks_XYZ"].shape[1]
            assert (row["status"], row["tracks"]) == ("written", tracks)
            assert row["passed"] >= tracks
            assert row["candidates"] >= row["passed"]
            target = {"drivetrack": 256, "pstudio": 50, "adt": 1024}[source]
            below = f", below the target of {target:,}" if tracks < target else ""
            assert row["reason"] == f"{tracks:,} tracks written{below}"
        elif clip in NOT_WRITTEN:
            assert (row["status"], row["reason"], row["tracks"]) == (*NOT_WRITTEN[clip], 0)
        else:  # the corrupt camera
            assert clip == "dome_16"
            assert row["status"] == "failed"
            assert row["tracks"] == 0
            assert row["reason"].startswith("InputError: ")
            assert "16/000000.jpg" in row["reason"]


def test_the_run_record_keeps_the_verdict_counts(release_run, release_file):
    out, _ = release_run
    record = json.load(open(os.path.join(out, "run_drivetrack.json")))
    assert record["release"] == release_file
    counts = {key: value for key, value in record["summary"]["release"].items() if key != "line"}
    assert counts == {"named": 5, "written": 2, "not_produced": 2, "input_absent": 1, "failed": 0}


def test_audit_release_prints_each_split_and_the_common_reasons(release_run, capsys):
    out, _ = release_run
    assert audit_main(["release", out, "--source", "drivetrack"]) == 0
    printed = capsys.readouterr().out
    assert "minival         1             1             0             0             0" in printed
    assert "full_eval       4             1             2             1             0" in printed
    assert "object id X is not among the segment's boxes" in printed
    assert "segment X is not in --input" in printed


def test_the_sweep_counts_surviving_release_clips_as_a_rerun_does(
    release_run, release_file, sample_split, tmp_path
):
    """At min_tracks=200 the parked car (fewer passing tracks) no longer survives: the sweep's count
    per split equals the verdicts of a new release run at that setting."""
    out, _ = release_run
    first = verdicts(out, "drivetrack")
    assert first[PARKED]["passed"] < 200 <= first[LEAD]["passed"]
    report = tmp_path / "report"
    grid = ["--grid", "min_tracks=1,200"]
    assert (
        audit_main(["sweep", out, "--source", "drivetrack", *grid, "--out", str(report)]) == 0
    )
    markdown = (report / "report.md").read_text()
    assert "| 200 |" in markdown
    assert "| 1 of 1 | 0 of 4 |" in markdown
    assert "| 1 of 1 | 1 of 4 |" in markdown
    rerun = str(tmp_path / "rerun")
    result = run_in_process(
        "drivetrack",
        "--input",
        sample_split[0],
        "--output",
        rerun,
        "--release",
        release_file,
        "--set",
        "min_tracks=200",
    )
    assert result.returncode == 0, result.stderr[-3000:]
    written = {split: 0 for split in ("minival", "full_eval")}
    for row in verdicts(rerun, "drivetrack").values():
        written[row["split"]] += row["status"] == "written"
    assert written == {"minival": 1, "full_eval": 0}
    passed = first[PARKED]["passed"]
    assert (
        verdicts(rerun, "drivetrack")[PARKED]["reason"]
        == f"{passed} tracks passed the filters, below min_tracks 200"
    )
