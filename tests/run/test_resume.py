"""Resume and crash safety: a rerun skips the units an earlier run finished (clips as their
checkpoints recorded them, same settings), a run killed with SIGKILL leaves no visible partial file,
and its rerun completes the set with the bytes of an uninterrupted run. The ledger's checks one by
one: tests/run/test_ledger.py."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time

import pytest

from pipeline.export.invariants import check_clip_bytes
from pipeline.io import files
from pipeline.validate import main as validate_main
from tests.support.bad_input import partial_files
from tests.support.cli import REPO, clip_bytes, run_in_process


def skipped_units(stdout: str) -> int:
    return stdout.count("finished by an earlier run with these settings; skipped")


def sample_input(reference: str, source: str) -> str:
    return json.load(open(os.path.join(reference, f"run_{source}.json")))["input"]


@pytest.fixture
def finished_copy(reference_run, tmp_path):
    """(input, output) where output is a private copy of a finished pstudio run."""
    reference = reference_run("pstudio")
    out = str(tmp_path / "out")
    shutil.copytree(reference, out, ignore=shutil.ignore_patterns("sample_input"))
    return sample_input(reference, "pstudio"), out


def test_rerun_skips_finished_units_and_redoes_a_damaged_clip(finished_copy, reference_run):
    source_input, out = finished_copy
    expected = clip_bytes(reference_run("pstudio"), "pstudio")
    damaged = sorted(expected)[1]
    path = os.path.join(out, "pstudio", damaged)
    with open(path, "r+b") as handle:
        handle.truncate(os.path.getsize(path) // 2)

    result = run_in_process("pstudio", "--input", source_input, "--output", out)
    assert result.returncode == 0, result.stderr[-3000:]
    assert skipped_units(result.stdout) == 3
    unit = damaged[: -len(".npz")].replace("_", "/camera_")  # dome_21 -> dome/camera_21
    assert f"unit {unit}: 1 of 1 clip(s) written" in result.stdout  # rewritten
    assert clip_bytes(out, "pstudio") == expected
    summary = json.load(open(os.path.join(out, "run_pstudio.json")))["summary"]
    reference_summary = json.load(open(os.path.join(reference_run("pstudio"), "run_pstudio.json")))["summary"]
    assert summary["units_resumed"] == 3
    assert {**summary, "units_resumed": 0} == reference_summary


def test_changed_settings_or_overwrite_redo_every_unit(finished_copy):
    source_input, out = finished_copy
    before = clip_bytes(out, "pstudio")
    # Two of the four cameras: their units are redone, the other two clips are left as they were.
    settings = ("--set", "seed=7", "--set", "pstudio.cameras=3,8")
    redone = {"dome_3.npz", "dome_8.npz"}
    changed = run_in_process("pstudio", "--input", source_input, "--output", out, *settings)
    assert changed.returncode == 0, changed.stderr[-3000:]
    assert skipped_units(changed.stdout) == 0
    after = clip_bytes(out, "pstudio")
    assert set(after) == set(before)
    assert redone < set(before)
    assert all((after[name] != before[name]) == (name in redone) for name in before)

    again = run_in_process("pstudio", "--input", source_input, "--output", out, *settings)
    assert skipped_units(again.stdout) == 2
    forced = run_in_process("pstudio", "--input", source_input, "--output", out, *settings, "--overwrite")
    assert forced.returncode == 0
    assert skipped_units(forced.stdout) == 0
    assert clip_bytes(out, "pstudio") == after


def test_sigkill_mid_run_then_rerun_completes_with_identical_bytes(reference_run, tmp_path):
    reference = reference_run("pstudio")
    expected = clip_bytes(reference, "pstudio")
    source_input = sample_input(reference, "pstudio")
    out = str(tmp_path / "out")
    command = [
        sys.executable,
        "-m",
        "pipeline.run",
        "--source",
        "pstudio",
        "--input",
        source_input,
        "--output",
        out,
    ]
    process = subprocess.Popen(
        command, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True
    )
    clips, records = os.path.join(out, "pstudio"), os.path.join(out, "units", "pstudio")
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and process.poll() is None:  # until the first unit is done
        if os.path.isdir(records) and any(name.endswith(".json") for name in os.listdir(records)):
            break
        time.sleep(0.02)
    os.killpg(process.pid, signal.SIGKILL)
    process.wait()
    assert process.returncode == -signal.SIGKILL

    # Killed part-way: some clips, not all; every visible file is whole.
    written = clip_bytes(out, "pstudio")
    assert 1 <= len(written) < len(expected)
    assert all(not check_clip_bytes(data) and data == expected[name] for name, data in written.items())
    assert not os.path.exists(os.path.join(out, "run_pstudio.json"))
    # A hidden temporary of an interrupted write, as a kill during a write leaves one.
    # Its name carries the writer's host and pid: the killed process, gone now.
    partial = f".dome_3.npz{files.PARTIAL}{files.writer_host()}-{process.pid}-0123456789ab"
    open(os.path.join(clips, partial), "wb").write(b"half a clip")

    result = run_in_process("pstudio", "--input", source_input, "--output", out)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "partial file(s) an interrupted run left" in result.stdout
    assert skipped_units(result.stdout) >= 1
    assert clip_bytes(out, "pstudio") == expected
    assert partial_files(out) == []
    assert validate_main([out]) == 0


def test_a_clip_left_without_tracks_by_new_settings_is_removed(finished_copy):
    source_input, out = finished_copy
    assert len(clip_bytes(out, "pstudio")) == 4
    # No query attaches to a Gaussian centre within 1 nm: the earlier run's clips must not survive it.
    result = run_in_process(
        "pstudio", "--input", source_input, "--output", out, "--set", "pstudio.max_attach_distance_m=1e-9"
    )
    assert result.returncode == 3, result.stderr[-3000:]  # nothing produced, nothing resumed
    assert result.stdout.splitlines()[-1] == "no clip written: the 4 clip(s) made had no candidate track"
    assert clip_bytes(out, "pstudio") == {}
    assert open(os.path.join(out, "manifests", "minival.txt")).read() == ""
