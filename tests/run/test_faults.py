"""Output safety, failing early and stopping cleanly: temporaries, replaces, names, start-up checks,
an output error at the end, Ctrl-C, and one-line errors from every command."""

from __future__ import annotations

import errno
import json
import os
import resource
import signal
import subprocess
import sys
import time

import pytest

from pipeline import sources
from pipeline.core.errors import InputError
from pipeline.export.layout import check_clip_name, temporary_patterns
from pipeline.io import files
from pipeline.io.file_set import complete_commits
from pipeline.io.files import remove_abandoned, remove_quietly, temporary_path, write_atomic
from tests.support.cli import REPO, command_in_process, run_in_process
from tests.support.toy.source import TOY


def test_replace_is_atomic_and_never_deletes_first(tmp_path, monkeypatch):
    path = tmp_path / "clip.npz"
    write_atomic(str(path), b"old")
    seen = []
    real_replace = os.replace

    def replace(source, target):
        seen.append(open(target, "rb").read())  # the old file is still whole at the moment of the swap
        real_replace(source, target)

    monkeypatch.setattr(os, "replace", replace)
    write_atomic(str(path), b"new")
    assert seen == [b"old"]
    assert path.read_bytes() == b"new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clip.npz"]


def test_temporaries_of_a_live_run_survive_another_runs_clean_up(tmp_path):
    out = tmp_path / "out"
    (out / "pstudio").mkdir(parents=True)
    live = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()
    try:
        host = files.writer_host()
        names = {
            "live": f".a.npz{files.PARTIAL}{host}-{live.pid}-0123456789ab",
            "dead": f".b.npz{files.PARTIAL}{host}-{gone.pid}-0123456789ab",
            "remote_fresh": f".c.npz{files.PARTIAL}otherhost-12-0123456789ab",
            "remote_old": f".d.npz{files.PARTIAL}otherhost-13-0123456789ab",
        }
        for name in names.values():
            (out / "pstudio" / name).write_bytes(b"partial")
        old = time.time() - 2 * files.REMOTE_GRACE_SECONDS
        os.utime(out / "pstudio" / names["remote_old"], (old, old))
        assert remove_abandoned(temporary_patterns(str(out), "pstudio", files.PARTIAL)) == 2
        left = sorted(p.name for p in (out / "pstudio").iterdir())
        assert left == sorted([names["live"], names["remote_fresh"]])
    finally:
        live.kill()
        live.wait()
    assert files.writer_pid(temporary_path(str(out / "x.npz"))) == os.getpid()


def test_a_file_that_vanishes_during_clean_up_is_no_error(tmp_path):
    present = tmp_path / "a"
    present.write_bytes(b"x")
    assert remove_quietly([str(tmp_path / "already_gone"), str(present)]) == 1
    assert not present.exists()


def test_over_long_names_get_a_clear_error(tmp_path):
    with pytest.raises(OSError) as raised:
        write_atomic(str(tmp_path / ("x" * 200 + ".npz")), b"data")
    assert raised.value.errno == errno.ENAMETOOLONG
    assert "at most 180" in str(raised.value)
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(InputError, match="is 161 characters, at most 160"):
        check_clip_name("c" * 161)


def test_a_bad_splits_file_or_input_stops_the_run_before_any_work(pstudio_sample, tmp_path):
    splits = tmp_path / "splits.json"
    splits.write_text('{"minival": {"pstudio": "dome_3.npz"}}')
    out = tmp_path / "out"
    result = run_in_process(
        "pstudio", "--input", pstudio_sample[0], "--output", str(out), "--set", f"splits_file={splits}"
    )
    assert result.returncode == 2
    assert not out.exists()
    assert f"cannot start: --set splits_file={splits}: not the release's splits JSON" in result.stderr
    assert "must map each source to a list of clip file names" in result.stderr
    result = run_in_process("pstudio", "--input", str(tmp_path / "absent"), "--output", str(out))
    assert result.returncode == 2
    assert "--input" in result.stderr
    assert "does not exist" in result.stderr
    assert "Traceback" not in result.stderr
    assert not out.exists()


def test_a_full_disk_is_caught_at_start(pstudio_sample, tmp_path):
    """RLIMIT_FSIZE stands in for a full disk: every write past 1 MiB fails (EFBIG) as ENOSPC would."""

    def small_disk():
        resource.setrlimit(resource.RLIMIT_FSIZE, (1 << 20, 1 << 20))

    out = tmp_path / "out"
    command = [sys.executable, "-m", "pipeline.run", "--source", "pstudio", "--input", pstudio_sample[0]]
    result = subprocess.run(
        [*command, "--output", str(out)], cwd=REPO, capture_output=True, text=True, preexec_fn=small_disk
    )
    assert result.returncode == 2, result.stderr[-2000:]
    assert f"cannot start: output folder {out} is not writable" in result.stderr
    assert not [p for p in out.rglob("*") if p.is_file()]  # the probe's temporary is gone too


def test_an_output_error_at_the_end_is_one_clear_line(pstudio_sample, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "manifests").write_text("a file where the manifests folder should be")
    result = run_in_process(
        "pstudio", "--input", pstudio_sample[0], "--output", str(out), "--set", "pstudio.cameras=3"
    )
    assert result.returncode == 2
    lines = [line for line in result.stderr.splitlines() if line.startswith("cannot finish:")]
    assert len(lines) == 1
    assert "manifests" in lines[0]
    assert "Traceback" not in result.stderr
    assert not list(out.rglob(f"*{files.PARTIAL}*"))


def test_ctrl_c_stops_with_one_line_and_no_partial_files(pstudio_sample, tmp_path):
    out = tmp_path / "out"
    command = [sys.executable, "-m", "pipeline.run", "--source", "pstudio", "--input", pstudio_sample[0]]
    slower = ["--set", "pstudio.oversample=80"]  # ten times the candidates: the run is still going
    records = out / "units" / "pstudio"
    with open(tmp_path / "stderr", "w+") as err:
        process = subprocess.Popen(
            [*command, "--output", str(out), *slower], cwd=REPO, stdout=subprocess.DEVNULL, stderr=err
        )
        deadline = time.monotonic() + 120
        while not (records.is_dir() and any(records.iterdir())) and time.monotonic() < deadline:
            time.sleep(0.05)  # the first unit is done
        process.send_signal(signal.SIGINT)
        code = process.wait(timeout=120)
    stderr = (tmp_path / "stderr").read_text()
    assert code == 130, stderr[-2000:]
    assert "Traceback" not in stderr
    assert len([line for line in stderr.splitlines() if line.startswith("interrupted:")]) == 1
    assert not list(out.rglob(f"*{files.PARTIAL}*"))


def test_commands_print_one_line_errors_and_no_beam_import_noise(tmp_path):
    """Each command's error through its main in this process; validate's from a new interpreter too,
    whose imports must add nothing (every command's: tests/run/test_closed_output.py)."""
    audit = tmp_path / "out" / "audit" / "pstudio"
    audit.mkdir(parents=True)
    (audit / "dome_3.parquet").write_bytes(b"not parquet")
    runs = {
        "sweep": ["pipeline.audit", "sweep", str(tmp_path / "out"), "--source", "pstudio"],
        "viz": ["pipeline.viz", str(tmp_path / "absent.npz"), "--out", str(tmp_path / "v.png")],
        "stats": ["pipeline.viz", "stats", str(tmp_path / "absent")],
        "compare": ["pipeline.audit", "compare", str(tmp_path / "absent"), str(tmp_path)],
        "validate": ["pipeline.validate", str(tmp_path / "absent")],
    }
    stderr = {}
    for name, args in [*runs.items(), ("validate, a new interpreter", None)]:
        if args is None:
            command = [sys.executable, "-m", *runs["validate"]]
            result = subprocess.run(command, cwd=REPO, capture_output=True, text=True)
        else:
            result = command_in_process(*args)
        lines = result.stderr.strip().splitlines()
        assert result.returncode in (1, 2), (name, result.stderr)
        assert len(lines) == 1, (name, result.stderr)
        assert "Traceback" not in result.stderr, name
        assert "apitools" not in result.stderr, name
        stderr[name] = result.stderr
    assert "sweep: audit table" in stderr["sweep"]


KILLED_FINISH = """
import os, signal, sys
import pipeline.io.file_set as file_set
kill_at = int(sys.argv[1])
moved = [0]
def die():
    os.kill(os.getpid(), signal.SIGKILL)
journal = file_set.write_atomic
def write_journal(path, data):
    if kill_at == 0:
        die()
    journal(path, data)
def move(pairs):
    for pair in pairs:
        moved[0] += 1
        if moved[0] == kill_at:
            die()
        os.replace(*pair)
file_set.write_atomic, file_set._move_into_place = write_journal, move
from pipeline.runner.command import main
sys.exit(main(sys.argv[2:]))
"""


def finish_set(out) -> tuple[int, int]:
    """(minival_per_source the run's provenance records, minival entries in the manifest), each file
    of the finish checked against the provenance's summary: one run's set."""
    record = json.loads((out / "run_toy.json").read_text())
    minival = (out / "manifests" / "minival.txt").read_text().splitlines()
    full_test = (out / "manifests" / "full_test.txt").read_text().splitlines()
    summary = record["summary"]["manifests"]
    assert (summary["minival"], summary["full_test"]) == (len(minival), len(full_test))
    assert (out / "failures_toy.jsonl").read_text() == ""
    return record["config"]["minival_per_source"], len(minival)


@pytest.fixture
def toy():
    sources.register(TOY)
    yield
    sources.unregister(TOY.name)


@pytest.mark.parametrize("kill_at", [0, 1, 3])  # before the journal, after one move, after three
def test_a_run_killed_while_it_writes_its_finish_leaves_one_set_and_a_rerun_completes_it(
    toy, tmp_path, kill_at
):
    """The run's failures, manifests and provenance are one result: killed before its journal is in
    place, the earlier set stays; after, the next command completes the new set."""
    source = tmp_path / "in"
    source.mkdir()
    for name in "abcd":
        spec = {"frames": 4, "points": [[0.0, 0.0, 2.0]], "velocity": [0.01, 0, 0]}
        (source / f"{name}.json").write_text(json.dumps(spec))
    out = tmp_path / "out"
    argv = ["--input", str(source), "--output", str(out)]
    assert run_in_process("toy", *argv, "--set", "minival_per_source=1").returncode == 0
    assert finish_set(out) == (1, 1)
    env = {**os.environ, "TAPVID3D_SOURCES": "tests.support.toy.source"}
    killed = [sys.executable, "-c", KILLED_FINISH, str(kill_at), "--source", "toy", *argv]
    done = subprocess.run(
        [*killed, "--set", "minival_per_source=2"],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == -signal.SIGKILL, done.stderr[-2000:]
    complete_commits(str(out))  # what every command does first in a folder it reads or writes
    assert finish_set(out) == ((1, 1) if kill_at == 0 else (2, 2))
    assert run_in_process("toy", *argv, "--set", "minival_per_source=2").returncode == 0
    assert finish_set(out) == (2, 2)
    assert not [path for path in out.rglob("*") if ".partial-" in path.name or ".commit-" in path.name]
