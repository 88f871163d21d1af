"""Every command ends quietly when its output is closed (``| head``): exit 141, no traceback, nothing on
stderr, whether stderr goes elsewhere or into the same closed pipe (``2>&1 | head``), through one
shared ending (``pipeline/pipes.py``). Every command is run with its stderr apart (where it can be
read: silent); the same closed pipe for both, which the shared ending handles alike for every
command, on three whose outputs differ most (a run's progress, a long table, a figure).
``pipeline.run`` stopping mid-run is ``tests/run/test_command_lines.py``'s."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from tests.support.cli import REPO

NAMES = ("run", "audit sweep", "audit release", "audit report", "audit compare", "validate", "viz")
NAMES += ("viz stats", "settings_doc")


def command(name: str, run: str, given: str, tmp: str) -> list[str]:
    """The words of command ``name``, given a finished Panoptic Studio run, its input and a scratch
    folder (which holds a release_pstudio.jsonl)."""
    return {
        "run": ["pipeline.run", "--source", "pstudio", "--input", given, "--output", tmp],
        "audit sweep": ["pipeline.audit", "sweep", run, "--source", "pstudio", "--out", tmp],
        "audit release": ["pipeline.audit", "release", tmp],
        "audit report": ["pipeline.audit", "report", run, "--out", f"{tmp}/r.html"],
        "audit compare": ["pipeline.audit", "compare", run, run, "--out", f"{tmp}/c"],
        "validate": ["pipeline.validate", run],
        "viz": ["pipeline.viz", f"{run}/pstudio/dome_3.npz", "--out", f"{tmp}/c.png"],
        "viz stats": ["pipeline.viz", "stats", run, "--out", f"{tmp}/s.png"],
        "settings_doc": ["pipeline.settings.doc"],
    }[name]


ROWS = 3000  # verdicts whose table outgrows a pipe's buffer


def verdict_rows(count: int) -> str:
    """``count`` rows of a release_<source>.jsonl, every fifth not produced."""
    rows = []
    for index in range(count):
        made = index % 5 != 0
        reason = "50 tracks written" if made else "all 400 candidates dropped: flicker 390, mask 10"
        rows.append(
            {
                "clip": f"seq{index:05d}_3",
                "split": "minival" if index < 50 else "full_test",
                "status": "written" if made else "not_produced",
                "tracks": 50 if made else 0,
                "reason": reason,
                "candidates": 400,
                "dropped": {"never_visible": 0, "flicker": 100 if made else 390, "mask": 10},
                "passed": 290 if made else 0,
            }
        )
    return "".join(json.dumps(row) + "\n" for row in rows)


@pytest.fixture
def scratch(tmp_path) -> str:
    (tmp_path / "release_pstudio.jsonl").write_text(verdict_rows(ROWS))
    return str(tmp_path)


def closed_run(words: list[str], same_pipe: bool) -> subprocess.CompletedProcess:
    """``python -m <words>`` with stdout a pipe whose reader is gone, and stderr into that pipe too
    (then nothing of it can be read back) or captured."""
    reader, writer = os.pipe()
    os.close(reader)
    try:
        return subprocess.run(
            [sys.executable, "-m", *words],
            cwd=REPO,
            stdout=writer,
            stderr=writer if same_pipe else subprocess.PIPE,
            text=True,
            timeout=120,
        )
    finally:
        os.close(writer)


CASES = [(name, False) for name in NAMES] + [(name, True) for name in ("run", "audit release", "viz stats")]


@pytest.mark.parametrize(
    "name,same_pipe", CASES, ids=[f"{n}-{'stderr in the pipe' if p else 'stderr apart'}" for n, p in CASES]
)
def test_a_closed_output_ends_the_command_quietly(name, same_pipe, reference_run, pstudio_sample, scratch):
    result = closed_run(command(name, reference_run("pstudio"), pstudio_sample[0], scratch), same_pipe)
    assert result.returncode == 141, result.stderr
    assert not result.stderr


def test_head_on_a_long_table_ends_the_command_quietly(scratch):
    """A real ``| head -3`` on a table longer than the pipe holds: the write that finds the reader
    gone ends the command, 141, stderr silent."""
    shell = f"{sys.executable} -m pipeline.audit release {scratch} | head -3"
    result = subprocess.run(
        ["bash", "-o", "pipefail", "-c", shell], cwd=REPO, capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 141, result.stderr
    assert result.stderr == ""
    assert len(result.stdout.splitlines()) == 3
    full = subprocess.run(
        [sys.executable, "-m", *command("audit release", "", "", scratch)], cwd=REPO, capture_output=True
    )
    assert full.returncode == 0
    assert len(full.stdout) > 1 << 16  # more than a pipe's buffer: the command was still writing
