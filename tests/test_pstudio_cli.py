"""``python -m pipeline.run --source pstudio`` end to end: valid clips, determinism, bad input."""

from __future__ import annotations

import json
import os
import shutil

import numpy as np
import pytest

from pipeline.validate import main as validate_main
from tests.cli import run_pipeline


def run_cli(*args):
    return run_pipeline("pstudio", *args)


def clip_files(out):
    folder = os.path.join(out, "pstudio")
    return sorted(os.listdir(folder)) if os.path.isdir(folder) else []


@pytest.fixture(scope="module")
def direct_run(pstudio_sample, tmp_path_factory):
    out = str(tmp_path_factory.mktemp("pstudio_direct"))
    result = run_cli("--input", pstudio_sample[0], "--output", out)
    assert result.returncode == 0, result.stderr[-3000:]
    return out, result


def test_run_writes_valid_clips(direct_run):
    out, result = direct_run
    assert clip_files(out) == ["dome_16.npz", "dome_21.npz", "dome_3.npz", "dome_8.npz"]
    assert validate_main([out]) == 0
    summary = json.load(open(os.path.join(out, "run_pstudio.json")))["summary"]
    assert summary["clips_written"] == 4 and summary["clips_below_target"] == 0
    assert summary["dropped_by_filter"]["mask"] > 0  # the floaters
    with np.load(os.path.join(out, "pstudio", "dome_3.npz"), allow_pickle=True) as clip:
        assert "extrinsics_w2c" not in clip.files
        assert clip["tracks_XYZ"].shape == (40, 50, 3)
    assert "pstudio: 4 unit(s), 0 failed" in result.stdout


def test_multiprocessing_runner_writes_identical_bytes(direct_run, pstudio_sample, tmp_path):
    out, _ = direct_run
    other = str(tmp_path / "mp")
    result = run_cli(
        "--input",
        pstudio_sample[0],
        "--output",
        other,
        "--direct_running_mode=multi_processing",
        "--direct_num_workers=2",
    )
    assert result.returncode == 0, result.stderr[-3000:]
    for name in clip_files(out):
        with (
            open(os.path.join(out, "pstudio", name), "rb") as a,
            open(os.path.join(other, "pstudio", name), "rb") as b,
        ):
            assert a.read() == b.read(), name


def clone_sequence(root: str, name: str) -> None:
    shutil.copytree(os.path.join(root, "data", "dome"), os.path.join(root, "data", name))
    shutil.copytree(
        os.path.join(root, "output", "pretrained", "dome"), os.path.join(root, "output", "pretrained", name)
    )


def rewrite_params(root: str, name: str, change) -> None:
    path = os.path.join(root, "output", "pretrained", name, "params.npz")
    with np.load(path) as params:
        arrays = dict(params)
    change(arrays)
    np.savez(path, **arrays)


def test_bad_input_fails_its_units_only(pstudio_sample, tmp_path):
    root = str(tmp_path / "root")
    shutil.copytree(pstudio_sample[0], root)
    for name in ("bad_shapes", "pickled", "missing_mask"):
        clone_sequence(root, name)
    rewrite_params(root, "bad_shapes", lambda a: a.update(means3D=a["means3D"][:, :-1]))
    rewrite_params(root, "pickled", lambda a: a.update(seg_colors=np.array([{"x": 1}], dtype=object)))
    os.remove(os.path.join(root, "data", "missing_mask", "seg", "8", "000005.png"))
    out = str(tmp_path / "out")
    result = run_cli("--input", root, "--output", out, "--set", "pstudio.cameras=3,99")
    assert result.returncode == 1, result.stderr[-3000:]
    failures = [json.loads(line) for line in open(os.path.join(out, "failures_pstudio.jsonl"))]
    by_unit = {f["unit"]: f["error"] for f in failures}
    assert sorted(by_unit) == sorted(
        [f"{seq}/camera_99" for seq in ("bad_shapes", "dome", "missing_mask", "pickled")]
        + ["bad_shapes/camera_3", "missing_mask/camera_3", "pickled/camera_3"]
    )
    assert "camera 99 is not in train_meta.json" in by_unit["dome/camera_99"]
    count = len(pstudio_sample[1].part_of_gaussian)
    assert (
        f"unnorm_rotations has shape (40, {count}, 4), expected (40, {count - 1}, 4)"
        in by_unit["bad_shapes/camera_3"]
    )
    assert "pickled object array" in by_unit["pickled/camera_3"]
    assert (
        "missing file" in by_unit["missing_mask/camera_3"]
        and "seg/8/000005.png" in by_unit["missing_mask/camera_3"]
    )
    # The good unit finished and is valid; nothing else and nothing partial was written.
    assert clip_files(out) == ["dome_3.npz"]
    assert validate_main([out]) == 0
    leftovers = [f for _, _, files in os.walk(out) for f in files if "partial" in f]
    assert leftovers == []
    assert "7 failure(s)" in result.stderr
