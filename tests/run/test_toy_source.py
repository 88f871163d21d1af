"""A source registered from the test suite goes through run, validate, sweep and compare with no
change to any other module (the Source interface, pipeline/sources.py), and brings its settings
section with it (``--set toy.speed_scale=...``, range-checked like any other)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pipeline import sources
from pipeline.audit.compare import main as compare_main
from pipeline.audit.sweep import main as sweep_main
from pipeline.runner.command import main as run_main
from pipeline.validate import main as validate_main
from tests.support.cli import run_in_process
from tests.support.toy.source import TOY, truth, write_sample


@pytest.fixture
def toy():
    sources.register(TOY)
    yield TOY
    sources.unregister(TOY.name)


def test_a_toy_source_runs_validates_sweeps_and_compares(toy, tmp_path, capsys):
    assert "toy" in sources.names()
    out = tmp_path / "out"
    assert run_main(["--source", "toy", "--output", str(out)]) == 0  # its sample world, then the run
    with np.load(out / "toy" / "toy_walk.npz") as clip:
        spec = json.loads((out / "sample_input" / "toy" / "walk.json").read_text())
        np.testing.assert_allclose(clip["tracks_XYZ"], truth(spec), atol=1e-6)  # float32 storage
        assert clip["visibility"].all() and "extrinsics_w2c" not in clip.files
    assert (out / "manifests" / "minival.txt").read_text() == "toy/toy_walk.npz\n"
    record = json.loads((out / "run_toy.json").read_text())
    assert record["metrics"]["clips_written"] == 1 and record["summary"]["tracks_written"] == 3

    assert validate_main([str(out)]) == 0
    grid = ["--grid", "flicker.max_fraction=0,0.5"]
    assert sweep_main([str(out), "--source", "toy", *grid]) == 0
    assert "| 0.5 |" in (out / "sweep_toy" / "report.md").read_text()
    assert sweep_main([str(out), "--source", "toy", "--grid", "pstudio.mask_min_agreement=1"]) == 2
    assert compare_main([str(out), str(out), "--out", str(tmp_path / "self")]) == 0
    (row,) = json.loads((tmp_path / "self.json").read_text())["clips"]
    assert row["source"] == "toy" and row["aj_none"] == 1.0
    capsys.readouterr()


def test_an_unregistered_source_is_refused(tmp_path):
    write_sample(str(tmp_path / "in"))
    with pytest.raises(SystemExit):
        run_main(["--source", "toy", "--input", str(tmp_path / "in"), "--output", str(tmp_path / "out")])


def test_the_toys_setting_changes_its_clips_as_its_annotate_says(toy, tmp_path, capsys):
    out = tmp_path / "out"
    assert run_main(["--source", "toy", "--output", str(out), "--set", "toy.speed_scale=2.5"]) == 0
    spec = json.loads((out / "sample_input" / "toy" / "walk.json").read_text())
    with np.load(out / "toy" / "toy_walk.npz") as clip:
        np.testing.assert_allclose(clip["tracks_XYZ"], truth(spec, 2.5), atol=1e-6)
        assert np.abs(clip["tracks_XYZ"][-1] - truth(spec)[-1]).max() > 0.3  # 11 frames x 1.5 x 0.02 m
    record = json.loads((out / "run_toy.json").read_text())
    assert record["config"]["toy"] == {"speed_scale": 2.5}
    capsys.readouterr()


def test_a_toy_setting_out_of_its_range_is_refused(toy, tmp_path):
    out = tmp_path / "out"
    refused = run_in_process("toy", "--output", str(out), "--set", "toy.speed_scale=-1")
    assert refused.returncode == 2
    assert "--set toy.speed_scale=-1: must be a number in [0, 10]" in refused.stderr
    assert not (out / "toy").exists()
