"""``pipeline.audit sweep``: replayed thresholds equal what real runs at those thresholds count; a folder
without a run is refused unless ``--run-sample`` asks for one; the old option spellings name the new."""

from __future__ import annotations

import errno
import json
import os
import shutil

import pyarrow.parquet as pq
import pytest

from pipeline.audit.__main__ import main as audit_main
from pipeline.drivetrack.sample.waymo_world import SAMPLE_VERSION
from pipeline.io import file_set
from pipeline.runner.command import main as run_main
from tests.conftest import link_tree


def summary(out, source):
    return json.loads((out / f"run_{source}.json").read_text())["summary"]


@pytest.fixture(scope="module")
def pstudio_run(reference_run, tmp_path_factory):
    """A copy of the plain Panoptic Studio run (the sweep writes its report into the run's folder)."""
    out = tmp_path_factory.mktemp("sweep") / "pstudio"
    shutil.copytree(reference_run("pstudio"), out)
    return out


def test_sweep_at_run_thresholds_reproduces_the_run(pstudio_run, capsys):
    code = audit_main(
        ["sweep", str(pstudio_run), "--source", "pstudio", "--grid", "flicker.max_fraction=0.1"]
    )
    assert code == 0
    report = (pstudio_run / "sweep_pstudio" / "report.md").read_text()
    assert "reproduces the run's counts" in report
    run = summary(pstudio_run, "pstudio")
    # the grid names only the run's own threshold: one row, labelled as both
    row = f"| run = grid | 0.1 | {run['candidate_tracks']} | 0 | {run['dropped_by_filter']['flicker']} | "
    assert row in report
    assert report.count("| 0.1 |") == 1
    for picture in ("survival.png", "histograms.png"):
        assert (pstudio_run / "sweep_pstudio" / picture).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_sweep_predicts_a_rerun_at_other_thresholds(pstudio_sample, pstudio_run, tmp_path):
    """The replay at mask 0.9 and flicker 0.05 counts exactly what a new run there counts."""
    settings = ["pstudio.mask_min_agreement=0.9", "flicker.max_fraction=0.05"]
    rerun = tmp_path / "rerun"
    command = ["--source", "pstudio", "--input", pstudio_sample[0], "--output", str(rerun)]
    assert run_main(command + [f"--set={s}" for s in settings]) == 0
    expected = summary(rerun, "pstudio")
    grid = ["--grid", "pstudio.mask_min_agreement=0.75,0.9", "--grid", "flicker.max_fraction=0.05,0.1"]
    report_dir = tmp_path / "report"
    assert (
        audit_main(["sweep", str(pstudio_run), "--source", "pstudio", *grid, "--out", str(report_dir)]) == 0
    )
    rows = pq.read_table(report_dir / "sweep.parquet").to_pylist()
    (row,) = [
        r for r in rows if r["pstudio.mask_min_agreement"] == "0.9" and r["flicker.max_fraction"] == "0.05"
    ]
    assert row["dropped_mask"] == expected["dropped_by_filter"]["mask"] > 0
    assert row["dropped_flicker"] == expected["dropped_by_filter"]["flicker"] > 0
    assert row["passed"] == expected["tracks_passing_filters"]
    assert row["clips_below_target"] == expected["clips_below_target"]
    # Stricter thresholds never keep more.
    loose = [
        r for r in rows if r["pstudio.mask_min_agreement"] == "0.75" and r["flicker.max_fraction"] == "0.1"
    ]
    assert loose[0]["passed"] > row["passed"]


def test_run_sample_runs_the_pipeline_into_an_empty_folder_then_sweeps_it(sample_split, tmp_path, capsys):
    """``--run-sample`` runs the sample world into OUT first (here already written there, as a run
    without --input leaves it), and the sweep of that run reproduces it."""
    out = tmp_path / "dt"
    link_tree(sample_split[0], str(out / "sample_input" / "drivetrack"))
    (out / "sample_input" / "drivetrack" / f".complete-v{SAMPLE_VERSION}").touch()
    grid = ["--grid", "drivetrack.mask_min_agreement=0.5,0.8"]
    assert audit_main(["sweep", str(out), "--source", "drivetrack", "--run-sample", *grid]) == 0
    printed = capsys.readouterr().out
    assert printed.startswith(f"--run-sample: running the pipeline on the drivetrack sample world into {out}")
    assert (out / "run_drivetrack.json").exists()
    report = (out / "sweep_drivetrack" / "report.md").read_text()
    assert "reproduces the run's counts" in report


def test_a_folder_without_a_run_is_refused_and_left_as_it_was(tmp_path, capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    absent = tmp_path / "absent"
    for folder in (empty, absent):
        assert audit_main(["sweep", str(folder), "--source", "pstudio"]) == 2
        (line,) = capsys.readouterr().err.splitlines()
        assert line.startswith(f"sweep: no pstudio run in {folder} (no run_pstudio.json, no audit tables)")
        assert line.endswith("or add --run-sample")
    assert os.listdir(empty) == []
    assert not absent.exists()


@pytest.mark.parametrize(
    "old, message",
    [
        ("--output", "--output is now the positional OUT"),
        ("--report", "--report is now --out"),
        ("--input", "--input is gone: run python -m pipeline.run"),
    ],
)
def test_an_old_spelling_names_the_new_one(pstudio_run, tmp_path, capsys, old, message):
    with pytest.raises(SystemExit) as stop:
        audit_main(["sweep", str(pstudio_run), "--source", "pstudio", old, str(tmp_path)])
    assert stop.value.code == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith(f"python -m pipeline.audit sweep: {message}")
    assert os.listdir(tmp_path) == []


def test_sweep_refuses_a_setting_that_needs_annotation(pstudio_run, capsys):
    grid = ["--grid", "pstudio.depth_delta_m=0.1"]
    assert audit_main(["sweep", str(pstudio_run), "--source", "pstudio", *grid]) == 2
    assert "needs a new run" in capsys.readouterr().err


def test_a_report_that_cannot_be_written_whole_leaves_the_earlier_one(
    pstudio_run, tmp_path, monkeypatch, capsys
):
    """The sweep's report, table and figures are one result: a write failing part-way (a full disk)
    leaves the earlier report's files as they were, one line, exit 2, no temporary."""
    report = tmp_path / "report"
    grid = ["sweep", str(pstudio_run), "--source", "pstudio", "--out", str(report)]
    assert audit_main([*grid, "--grid", "flicker.max_fraction=0.05"]) == 0
    before = {path.name: path.read_bytes() for path in report.iterdir()}
    real = file_set._write_plain

    def full_disk(path, data):
        if path.rpartition("/")[2].startswith(".survival.png"):
            raise OSError(errno.ENOSPC, "No space left on device", path)
        real(path, data)

    monkeypatch.setattr(file_set, "_write_plain", full_disk)
    capsys.readouterr()
    assert audit_main([*grid, "--grid", "flicker.max_fraction=0.2"]) == 2
    assert capsys.readouterr().err.startswith(f"sweep: cannot write the report in {report}: ")
    assert {path.name: path.read_bytes() for path in report.iterdir()} == before
