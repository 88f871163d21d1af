"""docs/adding-a-source.md holds true: its code examples, run as written (``<name>`` given a value)
against the toy source's functions, make a source that registers, runs, refuses its settings out of
range and sweeps its threshold; and the toy source by itself, named in ``TAPVID3D_SOURCES`` (its
folder and that one line, nothing else in the package), goes through every command a built-in
source does: the run (a release run), validate, each audit command, the settings page."""

from __future__ import annotations

import dataclasses
import json
import operator
import os
import re
import subprocess
import sys

import numpy as np
import pytest

from pipeline import sources
from pipeline.audit.sweep import main as sweep_main
from pipeline.runner.command import main as run_main
from pipeline.settings import fields
from pipeline.sources import PLUGINS_ENV, Source
from tests.support.cli import REPO, run_in_process
from tests.support.toy import source as toy_source

PAGE = os.path.join(REPO, "docs", "adding-a-source.md")
NAME = "doctoy"


def python_blocks() -> list[str]:
    """The page's Python code blocks, in order, ``<name>`` replaced by NAME."""
    with open(PAGE) as handle:
        text = handle.read()
    return [block.replace("<name>", NAME) for block in re.findall(r"```python\n(.*?)```", text, re.S)]


@pytest.fixture
def documented():
    """The source the page's examples define, made of the toy's functions and registered."""
    settings_block, source_block = python_blocks()
    names = {
        "dataclasses": dataclasses,
        "ranged": fields.ranged,
        "path_setting": fields.path_setting,
        "not_in_clips": fields.not_in_clips,
    }
    exec(settings_block, names)  # the page's settings section, as written
    names.update(
        Source=Source,
        YourUnit=toy_source.SpecFile,
        list_units=toy_source.list_units,
        annotate_group=sources.one_by_one(annotate),
        sample_input=toy_source.write_sample,
        operator=operator,
    )
    exec(source_block, names)  # the page's registration, as written
    source = names["SOURCE"]
    sources.register(toy_source.TOY)  # its annotate reads the toy's section
    sources.register(source)
    yield source, names["ToyConfig"]
    sources.unregister(NAME)
    sources.unregister(toy_source.TOY.name)


def annotate(input_root: str, unit: toy_source.SpecFile, config) -> list:
    """The toy's clips, made for the page's source."""
    return [dataclasses.replace(clip, source=NAME) for clip in toy_source.annotate(input_root, unit, config)]


def test_the_pages_examples_make_a_source_that_runs(documented, tmp_path, capsys):
    source, config = documented
    assert source.name == NAME and source.settings is config and source.group_of is not None
    assert [f.name for f in dataclasses.fields(config)] == ["mask_min_agreement", "masks_dir", "scratch_dir"]
    out = tmp_path / "out"
    assert run_main(["--source", NAME, "--output", str(out), "--set", f"{NAME}.mask_min_agreement=0.25"]) == 0
    with np.load(out / NAME / "toy_walk.npz") as clip:
        assert clip["tracks_XYZ"].shape == (12, 3, 3)
    record = json.loads((out / f"run_{NAME}.json").read_text())
    assert record["config"][NAME]["mask_min_agreement"] == 0.25  # the section the page declares
    grid = ["--grid", f"{NAME}.mask_min_agreement=0,0.5"]  # the page's sweepable threshold
    assert sweep_main([str(out), "--source", NAME, *grid]) == 0
    capsys.readouterr()


def test_the_pages_settings_are_checked_before_any_work(documented, tmp_path):
    refused = run_in_process(NAME, "--output", str(tmp_path / "out"), "--set", f"{NAME}.mask_min_agreement=2")
    assert refused.returncode == 2
    assert f"--set {NAME}.mask_min_agreement=2: must be a number in [0, 1]" in refused.stderr
    missing = run_in_process(NAME, "--output", str(tmp_path / "out"), "--set", f"{NAME}.masks_dir=/no/such")
    assert missing.returncode == 2 and f"{NAME}.masks_dir" in missing.stderr


def plugin(*command: str, check: bool = True) -> subprocess.CompletedProcess:
    """``python -m <command>`` with the toy named in TAPVID3D_SOURCES, nothing else."""
    env = dict(os.environ, **{PLUGINS_ENV: "tests.support.toy.source"})
    done = subprocess.run(
        [sys.executable, "-m", *command], cwd=REPO, env=env, capture_output=True, text=True, timeout=300
    )
    if check:
        assert done.returncode == 0, f"{' '.join(command)}: {done.stderr[-2000:]}"
    return done


def test_the_toy_by_itself_goes_through_every_command(tmp_path):
    splits = tmp_path / "splits.json"
    splits.write_text(
        json.dumps({"minival": {"toy": ["toy_walk.npz"]}, "full_eval": {"toy": ["toy_gone.npz"]}})
    )
    out = str(tmp_path / "out")
    plugin("pipeline.run", "--source", "toy", "--output", out, "--release", str(splits))
    assert os.path.exists(os.path.join(out, "toy", "toy_walk.npz"))
    plugin("pipeline.validate", out)
    release = plugin("pipeline.audit", "release", out).stdout
    assert "toy_walk" in release and "toy_gone" in release
    plugin("pipeline.audit", "sweep", out, "--source", "toy", "--grid", "flicker.max_fraction=0,0.5")
    plugin("pipeline.audit", "report", out, "--out", str(tmp_path / "page.html"))
    assert "toy_walk" in (tmp_path / "page.html").read_text()
    plugin("pipeline.audit", "compare", out, out, "--out", str(tmp_path / "self"))
    assert json.loads((tmp_path / "self.json").read_text())["clips"][0]["source"] == "toy"
    page = plugin("pipeline.settings.doc").stdout
    assert "toy.speed_scale" in page
