"""``audit compare`` against a reference served from 127.0.0.1 that fails (benchmarks/file_server.py):
it never erases a finding it could not replace, counts what it could not read apart and says so in
its exit status, stops when the server is gone, reads a few clips at a time, and its outputs (the
report and the verdicts it amends) change together or not at all, also when it is killed while
writing them.

NEW is a release run in miniature: 12 clips of ``toy`` and a verdict file naming them (and one the
run did not make); REF the same clips, served."""

from __future__ import annotations

import hashlib
import importlib
import json
import os
import signal
import subprocess
import sys

import cv2
import numpy as np
import pytest

from benchmarks.file_server import serve
from pipeline import sources
from pipeline.audit.compare import main as compare_main
from pipeline.export.npz_writer import encode_npz
from pipeline.runner.verdicts import Verdict, verdict_lines
from tests.support.cli import REPO, call_main
from tests.support.toy.source import TOY

CLIPS = [f"c{i:02d}" for i in range(12)]
NOT_MADE = "c99"
TOKEN = "tok-SECRET-0a17"
JPEG = cv2.imencode(".jpg", np.zeros((16, 32, 3), np.uint8))[1].tobytes()


@pytest.fixture(scope="module", autouse=True)
def toy():
    sources.register(TOY)
    yield
    sources.unregister(TOY.name)


def clip(index: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(index)
    tracks = rng.random((3, 5, 3)) + [0.0, 0.0, 2.0]
    return {
        "images_jpeg_bytes": np.array([JPEG] * 3),
        "queries_xyt": np.tile([8.0, 8.0, 0.0], (5, 1)),
        "tracks_XYZ": tracks,
        "visibility": np.ones((3, 5), bool),
        "fx_fy_cx_cy": np.array([0.6, 0.6, 16.0, 8.0]),
    }


@pytest.fixture
def folders(tmp_path):
    """(REF folder, NEW folder): the same clips in both; NEW's verdicts name them and ``NOT_MADE``."""
    ref, new = tmp_path / "ref", tmp_path / "new"
    for root in (ref, new):
        (root / "toy").mkdir(parents=True)
        for index, name in enumerate(CLIPS):
            (root / "toy" / f"{name}.npz").write_bytes(encode_npz(clip(index)))
    rows = [Verdict(name, "full_test", "written", 5, "5 tracks written") for name in CLIPS]
    rows.append(Verdict(NOT_MADE, "minival", "not_produced", 0, "no candidate track"))
    (new / "release_toy.jsonl").write_bytes(verdict_lines(sorted(rows, key=lambda row: row.clip)))
    return ref, new


def compare(base: str, new, *args: str):
    return call_main(compare_main, [base, str(new), "--set", "http.retries=0", *args])


def outputs(new) -> dict[str, bytes]:
    return {name: (new / name).read_bytes() for name in ("compare.md", "compare.json", "release_toy.jsonl")}


def verdict_agreements(new) -> dict[str, dict]:
    rows = [json.loads(line) for line in (new / "release_toy.jsonl").read_text().splitlines()]
    return {row["clip"]: row.get("agreement") for row in rows}


def test_a_compare_that_finds_nothing_leaves_the_earlier_outputs_as_they_were(folders):
    ref, new = folders
    with serve(ref) as server:
        first = compare(f"{server.base_url}?token={TOKEN}", new)
        assert first.returncode == 0, first.stderr
        before = outputs(new)
        for name in CLIPS:
            server.fail(f"toy/{name}.npz", "416")
        again = compare(f"{server.base_url}?token={TOKEN}", new)
    assert again.returncode == 1
    assert outputs(new) == before
    assert again.stderr.strip().splitlines()[-1] == (
        f"{len(CLIPS)} of {len(CLIPS) + 1} clip(s) could not be read from REF; earlier findings kept for "
        f"{len(CLIPS)}; nothing written: the earlier report and verdicts are as they were; rerun to "
        "complete them"
    )
    assert TOKEN not in again.stdout + again.stderr


def test_a_server_dying_part_way_keeps_each_earlier_finding_and_exits_1(folders):
    ref, new = folders
    with serve(ref) as server:
        base = f"{server.base_url}?token={TOKEN}"
        assert compare(base, new).returncode == 0
        earlier = json.loads((new / "compare.json").read_text())
        for name in CLIPS[2:]:
            server.fail(f"toy/{name}.npz", "503")
        moved = clip(0)
        moved["tracks_XYZ"] = moved["tracks_XYZ"] + [0.003, 0.0, 0.0]  # c00 changed: 3 mm off now
        (new / "toy" / "c00.npz").write_bytes(encode_npz(moved))
        result = compare(base, new, "--set", "max_failures_in_a_row=0")
    assert result.returncode == 1
    report = json.loads((new / "compare.json").read_text())
    rows = {row["clip"]: row for row in report["clips"]}
    assert rows["c00.npz"]["p95_mm"] == pytest.approx(3.0)
    assert rows["c00.npz"]["compared_at"] == report["compared_at"]
    for name in CLIPS[2:]:
        row = rows[f"{name}.npz"]
        assert row["carried"] is True and row["status"] == "scored"
        assert row["compared_at"] == earlier["compared_at"] and "HTTP 503" in row["error_now"]
    toy, total = report["sources"]
    assert (toy["clips"], toy["carried"], toy["ref_errors"], toy["not_made"]) == (12, 10, 0, 1)
    agreements = verdict_agreements(new)
    assert agreements["c00"]["p95_mm"] == pytest.approx(3.0)
    assert agreements["c05"]["compared_at"] == earlier["compared_at"] and agreements["c05"]["agrees"]
    assert agreements["c05"]["ref"] == report["ref"] == ref_shown(base)
    assert agreements[NOT_MADE]["status"] == "not_made"
    assert "10 of 13 clip(s) could not be read from REF; earlier findings kept for 10" in result.stderr


def ref_shown(base: str) -> str:
    return base.split("?")[0]


def test_the_stop_rule_ends_a_compare_against_a_dead_server_in_a_few_clips(folders):
    ref, new = folders
    with serve(ref) as server:
        base = server.base_url
    result = compare(base, new, "--set", "max_failures_in_a_row=3", "--jobs", "1")
    assert result.returncode == 4
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith("stopped: the last 3 clips failed alike (")
    assert "connection refused" in last and "max_failures_in_a_row=3" in last
    assert result.stderr.count("(REF unreadable") == 3  # the others not reached, said once
    assert f"not scored: {len(CLIPS) - 3} clip(s) not compared: the compare stopped first" in result.stderr
    assert f"{NOT_MADE}.npz: not made by the run: not_produced: no candidate track" in result.stderr
    assert not (new / "compare.json").exists()  # nothing was found: nothing written


def test_clips_are_read_a_few_at_a_time(folders, tmp_path):
    ref, new = folders
    with serve(ref, latency_s=0.2) as server:
        assert compare(server.base_url, new, "--jobs", "4").returncode == 0
        assert server.most_at_once() == 4
        server.reset()
        assert compare(server.base_url, new, "--jobs", "1", "--out", str(tmp_path / "one")).returncode == 0
        assert server.most_at_once() == 1


def test_a_local_reference_missing_a_clip_and_a_clip_list_label_what_they_left_out(folders, tmp_path):
    ref, new = folders
    (ref / "toy" / "c03.npz").unlink()
    listing = tmp_path / "list.txt"
    listing.write_text("toy/c00.npz\ntoy/c03.npz\n")
    result = compare(str(ref), new, "--clips", str(listing))
    assert result.returncode == 0
    report = json.loads((new / "compare.json").read_text())
    assert [row["status"] for row in report["clips"]] == ["scored", "not_in_ref"]
    assert report["only_in_new"] == ["toy/c03.npz"]  # REF lacks it: NEW holds it alone
    assert report["not_requested"] == len(CLIPS) - 2  # in both, left out by --clips
    table = (new / "compare.md").read_text().splitlines()
    pipes = [line.count(" | ") for line in table if line.startswith("| ")]
    separators = [line for line in table if line.startswith("|---")]
    assert len(separators) == 2
    for separator in separators:  # each table's header, separator and rows: one cell count
        block = table[table.index(separator) - 1 :]
        block = block[: next((i for i, line in enumerate(block) if not line.startswith("|")), len(block))]
        cells = {line.count("|") for line in block}
        assert len(cells) == 1, block
    assert pipes


def test_an_encrypted_member_in_the_reference_is_one_line_and_the_other_clips_are_scored(folders):
    ref, new = folders
    path = ref / "toy" / "c01.npz"
    data = bytearray(path.read_bytes())
    for marker, flags in ((b"PK\x03\x04", 6), (b"PK\x01\x02", 8)):
        at = data.find(marker)
        while at >= 0:
            data[at + flags] |= 1  # the member's "encrypted" flag
            at = data.find(marker, at + 4)
    path.write_bytes(bytes(data))
    result = compare(str(ref), new)
    assert result.returncode == 1
    assert "Traceback" not in result.stderr
    line = next(line for line in result.stderr.splitlines() if "c01" in line)
    assert line.endswith("is encrypted; refused (REF unreadable: left out of the means)")
    report = json.loads((new / "compare.json").read_text())
    assert sum(row["status"] == "scored" for row in report["clips"]) == len(CLIPS) - 1


KILLED_COMPARE = """
import os, signal, sys
from pipeline import sources
from tests.support.toy.source import TOY
import pipeline.io.file_set as file_set
sources.register(TOY)
moves = [0]
real = os.replace
def replace(source, target):
    if moves[0] == int(sys.argv[1]):
        os.kill(os.getpid(), signal.SIGKILL)
    moves[0] += 1
    real(source, target)
file_set.os.replace = replace
from pipeline.audit.compare import main
sys.exit(main(sys.argv[2:]))
"""


def consistent(new) -> str:
    """The SHA-256 of the c00 file the outputs scored, when the report and the verdicts it amended
    are one set (the same compare's finding in both); fails otherwise."""
    report = json.loads((new / "compare.json").read_text())
    assert f"({report['compared_at']})" in (new / "compare.md").read_text().splitlines()[0]
    (row,) = [row for row in report["clips"] if row["clip"] == "c00.npz"]
    agreement = verdict_agreements(new)["c00"]
    assert (agreement["clip_sha256"], agreement["compared_at"]) == (row["clip_sha256"], row["compared_at"])
    return row["clip_sha256"]


def leftovers(folder) -> list[str]:
    return [name for name in os.listdir(folder) if ".partial-" in name or ".commit-" in name]


def test_a_compare_killed_at_any_write_leaves_one_set_and_the_next_command_completes_it(folders):
    """Killed before each move that puts its outputs in place (the journal's, then one per file): a
    reader finds the earlier set (killed before the journal) or the new one, whole; the next compare
    reclaims what the killed one left and completes."""
    ref, new = folders
    assert compare(str(ref), new).returncode == 0
    release = importlib.import_module("pipeline.audit.release").main
    for kill_at in range(4):  # the journal, compare.md, compare.json, the verdicts
        before = consistent(new)
        changed = encode_npz(clip(100 + kill_at))  # a new finding on c00 each time
        (new / "toy" / "c00.npz").write_bytes(changed)
        command = [sys.executable, "-c", KILLED_COMPARE, str(kill_at), str(ref), str(new)]
        done = subprocess.run(command, cwd=REPO, capture_output=True, text=True, timeout=60)
        assert done.returncode == -signal.SIGKILL, done.stderr[-2000:]
        assert call_main(release, [str(new)]).returncode == 0  # a reader: it settles the folder
        expected = before if kill_at == 0 else hashlib.sha256(changed).hexdigest()
        assert consistent(new) == expected, kill_at
        assert compare(str(ref), new).returncode == 0  # the next compare: reclaims, completes
        assert consistent(new) == hashlib.sha256(changed).hexdigest()
        assert leftovers(new) == [], kill_at


def test_a_folder_of_clips_without_verdicts_is_only_read(folders, tmp_path):
    """NEW is a folder of clips, not a release run's: compare writes its report under --out and
    nothing, not even a lock, into NEW."""
    ref, new = folders
    (new / "release_toy.jsonl").unlink()
    before = sorted(path.relative_to(new) for path in new.rglob("*"))
    done = call_main(compare_main, [str(ref), str(new), "--out", str(tmp_path / "out" / "report")])
    assert done.returncode == 0, done.stderr
    assert sorted(path.relative_to(new) for path in new.rglob("*")) == before
    assert (tmp_path / "out" / "report.json").exists()
