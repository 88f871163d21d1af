"""``--release``: a run restricted to the release's clips follows the release's rules, writes exactly
those clips, byte for byte the clips a plain run makes of the same names under the same rules,
manifests exactly the file's splits, and a verdict for every clip the file names, with its reason.
The splits file here names, per sample, two real clips (one per split), plus clips a run cannot
make: an object id the segment does not have, an object of another camera, a segment and a sequence
absent from --input, a Panoptic camera absent from its train_meta.json, a chunk past the ADT
excerpt's end, and a camera whose images are corrupt."""

from __future__ import annotations

import json
import os

import cv2
import numpy as np
import pyarrow.parquet as pq
import pytest

from pipeline.audit.__main__ import main as audit_main
from pipeline.drivetrack.sample.waymo_world import DISTORTION, FX_FY_CX_CY, SEGMENT
from pipeline.drivetrack.settings import DriveTrackConfig
from pipeline.runner.command import parse_args
from pipeline.runner.prepare import prepare_run
from pipeline.runner.resume import run_fingerprint
from pipeline.settings.fields import with_overrides, with_rules
from pipeline.settings.run_config import RunConfig
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
def plain_release_rules(sample_split, pstudio_sample, tmp_path_factory) -> str:
    """One output folder holding a plain (unrestricted) run of the DriveTrack and Panoptic Studio
    samples under ``--set rules=release``."""
    out = str(tmp_path_factory.mktemp("plain_release_rules"))
    for source, root in (("drivetrack", sample_split[0]), ("pstudio", pstudio_sample[0])):
        result = run_in_process(source, "--input", root, "--output", out, "--set", "rules=release")
        assert result.returncode == 0, result.stderr[-3000:]
    return out


@pytest.fixture(scope="module")
def release_refined_rules(release_file, sample_split, tmp_path_factory):
    """A --release run of the DriveTrack sample under ``--set rules=refined``."""
    out = str(tmp_path_factory.mktemp("release_refined"))
    result = run_in_process(
        "drivetrack",
        "--input",
        sample_split[0],
        "--output",
        out,
        "--release",
        release_file,
        "--set",
        "rules=refined",
    )
    assert result.returncode == 0, result.stderr[-3000:]
    return out, result


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
def test_only_the_named_clips_are_written_with_a_plain_runs_bytes_under_the_same_rules(
    release_run, plain_release_rules, source
):
    out, _ = release_run
    written = clip_bytes(out, source)
    assert set(written) == {f"{name}.npz" for name in WRITTEN[source]}
    plain = clip_bytes(plain_release_rules, source)
    assert all(written[name] == plain[name] for name in written)


def test_a_release_run_under_the_refined_rules_writes_a_plain_runs_clips(
    release_refined_rules, reference_run
):
    out, result = release_refined_rules
    assert result.stdout.startswith("rules: refined (")
    written = clip_bytes(out, "drivetrack")
    plain = clip_bytes(reference_run("drivetrack"), "drivetrack")
    assert set(written) == {f"{name}.npz" for name in WRITTEN["drivetrack"]}
    assert all(written[name] == plain[name] for name in written)


def test_a_release_run_names_its_rules_first_and_records_them(release_run, reference_run):
    out, runs = release_run
    first = runs["drivetrack"].stdout.splitlines()[0]
    assert first == (
        "rules: release (the original generators' choices; docs/release.md): drivetrack.facing_test=false, "
        "drivetrack.parallax_cleanup=false, drivetrack.refined_visibility=false, "
        "drivetrack.stable_query_frames=false, drivetrack.undistort_frames=false "
        "(refined: true, true, true, true, true)"
    )
    assert reference_run.result("drivetrack").stdout.startswith("rules: refined (ours, measured better;")
    record = json.load(open(os.path.join(out, "run_drivetrack.json")))
    assert record["config"]["rules"] == "release"
    assert record["config"]["drivetrack"]["facing_test"] is False
    assert record["rules"]["sets"] == {
        "drivetrack.facing_test": False,
        "drivetrack.parallax_cleanup": False,
        "drivetrack.refined_visibility": False,
        "drivetrack.stable_query_frames": False,
        "drivetrack.undistort_frames": False,
    }
    assert "drivetrack.oversample" in record["rules"]["not_known"]


def test_an_explicit_setting_wins_over_the_rules_and_says_so(release_file, sample_split, tmp_path):
    argv = ["--source", "drivetrack", "--input", sample_split[0], "--output", str(tmp_path)]
    args, beam_args = parse_args([*argv, "--release", release_file, "--set", "drivetrack.facing_test=true"])
    prepared = prepare_run(args, beam_args)
    assert prepared.config.rules == "release"
    assert prepared.config.section(DriveTrackConfig).facing_test is True
    assert prepared.config.section(DriveTrackConfig).undistort_frames is False
    first, *others = prepared.rules.lines()
    # the rule set's own values first, then what --set changed: no line contradicts another
    assert first.startswith("rules: release (") and "drivetrack.facing_test=false," in first
    assert "rules: --set drivetrack.facing_test=true wins over rules=release (false)" in others
    args, beam_args = parse_args([*argv, "--set", "rules=release"])
    assert prepare_run(args, beam_args).config == with_rules(RunConfig(), "release")


def test_the_resume_fingerprint_covers_the_rules():
    release = with_rules(RunConfig(), "release")
    assert run_fingerprint("drivetrack", release) != run_fingerprint("drivetrack", RunConfig())
    # the same values under another rule set's name is another run
    renamed = with_overrides(RunConfig(), ["rules=release"])
    assert run_fingerprint("drivetrack", renamed) != run_fingerprint("drivetrack", RunConfig())


def stored_jpegs(split: str, camera: int) -> dict[int, bytes]:
    """The camera's JPEGs in the input's camera_image file, by timestamp (read here with pyarrow)."""
    table = pq.read_table(os.path.join(split, "camera_image", f"{SEGMENT}.parquet"))
    rows = table.to_pydict()
    return {
        stamp: image
        for stamp, name, image in zip(
            rows["key.frame_timestamp_micros"],
            rows["key.camera_name"],
            rows["[CameraImageComponent].image"],
            strict=True,
        )
        if name == camera
    }


def clip_frames(out: str, clip: str) -> list[bytes]:
    with np.load(os.path.join(out, "drivetrack", f"{clip}.npz")) as data:
        return [bytes(frame) for frame in data["images_jpeg_bytes"]]


def test_release_rules_keep_the_inputs_jpegs_and_refined_rules_undistort_them(
    release_run, reference_run, sample_split
):
    """Frames of the lead car's clip (camera 1): under the release's rules the input's own JPEGs, byte
    for byte; under ours each is the input's frame undistorted with OpenCV (pixel centres at integers
    there) and re-encoded."""
    out, _ = release_run
    stored = stored_jpegs(sample_split[0], 1)
    kept, undistorted = clip_frames(out, LEAD), clip_frames(reference_run("drivetrack"), LEAD)
    assert len(kept) == len(undistorted) >= 24
    inputs = set(stored.values())
    assert all(frame in inputs for frame in kept)
    assert not any(frame in inputs for frame in undistorted)
    first = next(image for image in stored.values() if image == kept[0])
    fx, fy, cx, cy = FX_FY_CX_CY
    matrix = np.array([[fx, 0, cx - 0.5], [0, fy, cy - 0.5], [0, 0, 1.0]])
    expected = cv2.undistort(
        cv2.imdecode(np.frombuffer(first, np.uint8), cv2.IMREAD_COLOR), matrix, DISTORTION[1]
    )
    ours = cv2.imdecode(np.frombuffer(undistorted[0], np.uint8), cv2.IMREAD_COLOR)
    inner = (slice(8, -8), slice(8, -8))  # the borders differ in what fills beyond the sensor
    difference = np.abs(ours[inner].astype(int) - expected[inner].astype(int))
    assert difference.mean() < 2.0


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
        name[: -len(".npz")]: "full_test" if split == "full_eval" else split
        for split in ("minival", "full_eval")
        for name in RELEASE[split][source]
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
    assert "full_test       4             1             2             1             0" in printed
    assert "object id X is not among the segment's boxes" in printed
    assert "segment X is not in --input" in printed


def test_the_sweep_counts_surviving_release_clips_as_a_rerun_does(
    release_run, release_file, sample_split, tmp_path
):
    """At min_tracks=500 the parked car (fewer passing tracks) no longer survives: the sweep's count
    per split equals the verdicts of a new release run at that setting."""
    out, _ = release_run
    first = verdicts(out, "drivetrack")
    assert first[PARKED]["passed"] < 500 <= first[LEAD]["passed"]
    report = tmp_path / "report"
    grid = ["--grid", "min_tracks=1,500"]
    assert audit_main(["sweep", out, "--source", "drivetrack", *grid, "--out", str(report)]) == 0
    markdown = (report / "report.md").read_text()
    assert "| 500 |" in markdown
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
        "min_tracks=500",
    )
    assert result.returncode == 0, result.stderr[-3000:]
    written = {split: 0 for split in ("minival", "full_test")}
    for row in verdicts(rerun, "drivetrack").values():
        written[row["split"]] += row["status"] == "written"
    assert written == {"minival": 1, "full_test": 0}
    passed = first[PARKED]["passed"]
    assert (
        verdicts(rerun, "drivetrack")[PARKED]["reason"]
        == f"{passed} tracks passed the filters, below min_tracks 500"
    )
