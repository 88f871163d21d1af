"""``python -m pipeline.run --source pstudio`` end to end: valid clips, determinism
(bad input: tests/pstudio/test_bad_input.py)."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from pipeline.validate import main as validate_main


def clip_files(out):
    folder = os.path.join(out, "pstudio")
    return sorted(os.listdir(folder)) if os.path.isdir(folder) else []


@pytest.fixture(scope="module")
def direct_run(reference_run):
    """(output folder, completed process) of the session's end-to-end DirectRunner run."""
    return reference_run("pstudio"), reference_run.result("pstudio")


def test_run_writes_valid_clips(direct_run):
    out, result = direct_run
    assert clip_files(out) == ["dome_16.npz", "dome_21.npz", "dome_3.npz", "dome_8.npz"]
    assert validate_main([out]) == 0
    summary = json.load(open(os.path.join(out, "run_pstudio.json")))["summary"]
    assert summary["clips_written"] == 4
    assert summary["clips_below_target"] == 0
    assert summary["dropped_by_filter"]["mask"] > 0  # the floaters
    with np.load(os.path.join(out, "pstudio", "dome_3.npz"), allow_pickle=False) as clip:
        assert "extrinsics_w2c" not in clip.files
        assert clip["tracks_XYZ"].shape == (40, 50, 3)
    assert "pstudio: 4 unit(s), 0 finished earlier, 0 failed" in result.stdout


def test_multiprocessing_runner_writes_identical_bytes(direct_run, reference_run):
    out, _ = direct_run
    other, result = reference_run.multi_processing("pstudio")
    assert result.returncode == 0, result.stderr[-3000:]
    assert clip_files(other) == clip_files(out)
    for name in clip_files(out):
        with (
            open(os.path.join(out, "pstudio", name), "rb") as a,
            open(os.path.join(other, "pstudio", name), "rb") as b,
        ):
            assert a.read() == b.read(), name
