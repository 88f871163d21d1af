"""Shared fixtures: the sample driving and studio worlds, written once per test session."""

from __future__ import annotations

import shutil

import pytest

from tests.cli import run_pipeline
from tests.fixtures.driving_world import DrivingWorld
from tests.fixtures.dynamic3dgs_files import write_sequence
from tests.fixtures.waymo_world import write_split


@pytest.fixture(scope="session")
def world() -> DrivingWorld:
    return DrivingWorld()


@pytest.fixture(scope="session")
def sample_split(tmp_path_factory, world):
    """(split folder, generator output) for the one-segment sample world."""
    folder = tmp_path_factory.mktemp("waymo") / "split"
    generated = write_split(str(folder), world=world)
    return str(folder), generated


@pytest.fixture
def split_copy(sample_split, tmp_path):
    """A private copy of the sample split that a test may corrupt."""
    target = tmp_path / "split"
    shutil.copytree(sample_split[0], target)
    return str(target)


@pytest.fixture(scope="session")
def pstudio_sample(tmp_path_factory):
    """(root holding data/ and output/, the StudioWorld) for the one-sequence studio sample."""
    root = tmp_path_factory.mktemp("pstudio") / "root"
    studio = write_sequence(str(root))
    return str(root), studio


@pytest.fixture(scope="session")
def reference_run(tmp_path_factory, sample_split, pstudio_sample):
    """``reference_run(source)``: the output folder of one plain DirectRunner run on that source's
    sample (drivetrack or pstudio), made on first use and shared by the tests that compare bytes."""
    inputs = {"drivetrack": sample_split[0], "pstudio": pstudio_sample[0]}
    made: dict[str, str] = {}

    def run(source: str) -> str:
        if source not in made:
            out = str(tmp_path_factory.mktemp(f"reference_{source}"))
            result = run_pipeline(source, "--input", inputs[source], "--output", out)
            assert result.returncode == 0, result.stderr[-3000:]
            made[source] = out
        return made[source]

    return run
