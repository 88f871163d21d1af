"""The samples' splits file (``pipeline/runner/sample_splits.json``, what ``make demo`` runs): a release run
on the sample worlds, given no ``--input``, writes every clip the samples make and says why each
other clip is not there, in words that name no option the user did not give; ``audit release`` shows
each clip's drops per filter; ``audit report`` shows the verdicts of a release run that annotated
nothing. The DriveTrack sample world is linked into the run's folder as a run without ``--input``
leaves it (a plain run writes it there once)."""

from __future__ import annotations

import json
import os
import re
import shutil

import pytest

from pipeline import demo, sources
from pipeline.audit.__main__ import main as audit_main
from pipeline.runner.splits import SAMPLE_RELEASE, read_release
from tests.support import golden
from tests.support.adt_excerpt import SAMPLE, needs_excerpt
from tests.support.cli import REPO, clip_bytes, run_in_process

SEGMENT = "sample0000000000000001_0_000_4_000"
# clip -> (status, reason) of every sample release clip a run on the samples cannot make.
NOT_WRITTEN = {
    f"tapvid3d_{SEGMENT}_1_parked_right_DDDDDDDDDDDDDDDDDD": (
        "not_produced",
        "object parked_right_DDDDDDDDDDDDDDDDDD belongs to camera 3 (the one that sees it most), not 1",
    ),
    f"tapvid3d_{SEGMENT}_2_no_such_object": (
        "not_produced",
        "object id no_such_object is not among the segment's boxes",
    ),
    "tapvid3d_1234567890_0_000_20_000_1_someone": (
        "input_absent",
        "segment 1234567890_0_000_20_000 is not in the sample world",
    ),
    f"{SAMPLE.name}_1": ("not_produced", "chunk 1 starts past the sequence's 2 annotated frames"),
    "Apartment_release_absent_seq001_0": (
        "input_absent",
        "sequence Apartment_release_absent_seq001 is not in --input",  # ADT's --input was given
    ),
}


@pytest.fixture(scope="module")
def sample_release(sample_release_runs):
    """One folder: the DriveTrack sample release run without --input, and ADT's on the excerpt."""
    runs = {"drivetrack": sample_release_runs("drivetrack")}
    if SAMPLE.is_dir():
        runs["adt"] = sample_release_runs("adt")
    return sample_release_runs.out, runs


def verdicts(out, source: str) -> dict[str, dict]:
    return {row["clip"]: row for row in map(json.loads, (out / f"release_{source}.jsonl").open())}


def test_the_sample_release_names_every_clip_the_samples_make(sample_release, reference_run):
    out, runs = sample_release
    assert runs["drivetrack"].returncode == 0, runs["drivetrack"].stderr[-3000:]
    assert "no --input given: using the embedded sample world" in runs["drivetrack"].stdout
    named = read_release(SAMPLE_RELEASE).clips
    for source in ("drivetrack", "pstudio"):
        made = {name[: -len(".npz")] for name in clip_bytes(reference_run(source), source)}
        assert made <= set(named[source]), source
        assert set(named[source]) - made, f"{source}: the file names no clip the sample cannot make"
    written = {clip for clip, row in verdicts(out, "drivetrack").items() if row["status"] == "written"}
    assert written == {name[: -len(".npz")] for name in clip_bytes(reference_run("drivetrack"), "drivetrack")}


def test_each_clip_not_written_says_why_naming_only_what_was_given(sample_release):
    out, _ = sample_release
    rows = verdicts(out, "drivetrack")
    assert {row["status"] for row in rows.values()} == {"written", "not_produced", "input_absent"}
    for clip, row in rows.items():
        if row["status"] != "written":
            assert (row["status"], row["reason"]) == NOT_WRITTEN[clip]
        assert "--input" not in row["reason"]


@needs_excerpt
def test_the_adt_excerpt_verdicts(sample_release):
    out, runs = sample_release
    assert runs["adt"].returncode == 0, runs["adt"].stderr[-3000:]
    rows = verdicts(out, "adt")
    assert rows[f"{SAMPLE.name}_0"]["status"] == "written"
    for clip in (f"{SAMPLE.name}_1", "Apartment_release_absent_seq001_0"):
        assert (rows[clip]["status"], rows[clip]["reason"]) == NOT_WRITTEN[clip]


def test_audit_release_shows_each_clips_drops_per_filter(sample_release, capsys):
    out, _ = sample_release
    assert audit_main(["release", str(out), "--source", "drivetrack"]) == 0
    printed = capsys.readouterr().out
    header = r"^clip +split +status +tracks +candidates +never_visible +flicker +mask +passed +reason$"
    assert re.search(header, printed, re.M), printed
    rows = verdicts(out, "drivetrack")
    assert sum(row["dropped"]["flicker"] for row in rows.values()) > 0
    for clip, row in rows.items():
        dropped = row["dropped"]
        cells = [row["split"], row["status"], row["tracks"], row["candidates"], dropped["never_visible"]]
        cells += [dropped["flicker"], dropped["mask"], row["passed"]]
        line = re.escape(clip) + "".join(rf" +{re.escape(str(cell))}" for cell in cells)
        assert re.search(rf"^{line} +{re.escape(row['reason'])}$", printed, re.M), clip


def test_audit_report_shows_the_verdicts_of_a_release_run_that_annotated_nothing(
    sample_split, tmp_path, capsys
):
    """A release naming only clips the sample cannot make: the run annotates nothing (exit 3); the
    page shows its verdicts instead of refusing for want of audit tables."""
    splits = tmp_path / "splits.json"
    absent = ["tapvid3d_1234567890_0_000_20_000_1_someone.npz", "tapvid3d_9_0_000_20_000_2_other.npz"]
    splits.write_text(
        json.dumps({"minival": {"drivetrack": absent[:1]}, "full_eval": {"drivetrack": absent[1:]}})
    )
    out = tmp_path / "out"
    given = ("--input", sample_split[0], "--output", str(out), "--release", str(splits))
    assert run_in_process("drivetrack", *given).returncode == 3
    assert not (out / "audit").exists()
    page = tmp_path / "page.html"
    assert audit_main(["report", str(out), "--out", str(page)]) == 0
    assert capsys.readouterr().out.startswith(
        "drivetrack: no audit tables; the page shows its 2 release verdicts"
    )
    data = json.loads(re.search(r'id="audit-data">(.*?)</script>', page.read_text(), re.S)[1])
    (source,) = data["sources"]
    assert source["verdicts_only"] is True
    assert [(row["clip"], row["status"]) for row in source["missing"]] == [
        (name[: -len(".npz")], "input_absent") for name in absent
    ]


def test_the_demo_is_a_release_run_of_the_packaged_sample_splits():
    makefile = open(os.path.join(REPO, "Makefile")).read()
    assert f"SAMPLE_RELEASE := {os.path.relpath(SAMPLE_RELEASE, REPO)}" in makefile
    demo = re.search(r"^demo:.*?(?=^\S)", makefile, re.M | re.S)[0]
    assert "$(PY) -m pipeline.demo --output $(OUT) --release $(SAMPLE_RELEASE)" in demo
    pyproject = open(os.path.join(REPO, "pyproject.toml")).read()
    assert '"pipeline.runner" = ["sample_splits.json"]' in pyproject  # in a wheel too


def demo_runs(capsys) -> tuple[dict[str, list[str]], list[list[str]], str]:
    """The demo's ``pipeline.run`` commands by source, its other commands, and what it said."""
    made = demo.commands("OUT", "SPLITS")
    runs = {command[2]: command for command in made if command[0] == "pipeline.run"}
    return runs, [command for command in made if command[0] != "pipeline.run"], capsys.readouterr().err


def test_the_demo_runs_every_registered_source_then_validates_and_shows_the_verdicts(capsys, monkeypatch):
    """Every source of the registry runs as a release run of the splits file, on its sample; ADT, on
    the excerpt read in place with the settings its two frames need, or is skipped with its reason."""
    monkeypatch.setenv("ADT_EXCERPT", os.path.join(REPO, "no-such-excerpt"))
    runs, after, said = demo_runs(capsys)
    assert sorted(runs) == sorted(set(sources.names()) - {"adt"})
    for name, command in runs.items():
        assert command == [
            "pipeline.run",
            "--source",
            name,
            "--runner",
            "DirectRunner",
            "--output",
            "OUT",
            "--release",
            "SPLITS",
        ]
    assert after == [["pipeline.validate", "OUT"], ["pipeline.audit", "release", "OUT"]]
    assert "demo: adt skipped: no ADT excerpt at " in said and "no-such-excerpt" in said


@needs_excerpt
def test_the_demo_runs_adt_on_the_excerpt(capsys):
    runs, _, said = demo_runs(capsys)
    assert runs["adt"][-8:] == [
        "--input",
        str(SAMPLE),
        "--set",
        "adt.chunk_frames=2",
        "--set",
        "adt.min_frames=2",
        "--set",
        "adt.max_gt_offset_ms=40",
    ]
    assert "skipped" not in said


def test_a_rerun_keeps_the_agreement_of_each_clip_whose_file_is_the_one_compared(sample_release, tmp_path):
    """``audit compare`` adds each written clip's agreement to its verdict; the release run again
    (every unit resumed) rewrites the verdicts and keeps each agreement whose clip file is the one
    compared (its SHA-256), and drops one recorded for other bytes."""
    out = tmp_path / "run"
    shutil.copytree(sample_release[0], out)
    assert audit_main(["compare", str(out), str(out), "--out", str(tmp_path / "self")]) == 0
    before = verdicts(out, "drivetrack")
    written = sorted(clip for clip, row in before.items() if row["status"] == "written")
    assert all(before[clip]["agreement"]["status"] == "scored" for clip in written)
    forged, kept = written[0], written[1:]
    rows = [dict(row) for row in before.values()]
    for row in rows:
        if row["clip"] == forged:
            row["agreement"] = dict(row["agreement"], clip_sha256="0" * 64)  # scored other bytes
    (out / "release_drivetrack.jsonl").write_text(
        "".join(json.dumps(row, sort_keys=True) + "\n" for row in rows)
    )

    args = golden.concrete(golden.release_args("drivetrack"), str(out))
    rerun = run_in_process("drivetrack", *args[2:])
    assert rerun.returncode == 0, rerun.stderr[-3000:]
    assert rerun.stdout.count("finished by an earlier run with these settings; skipped") == 3
    after = verdicts(out, "drivetrack")
    assert [after[clip].get("agreement") for clip in kept] == [before[clip]["agreement"] for clip in kept]
    assert "agreement" not in after[forged]
