"""A ten-hour fetch meets the real world: a process killed mid-download, a server that trickles, one
that answers 503 while the user presses Ctrl-C, URLs with tokens that lead nowhere, a ground-truth
file that is no CSV. Each is met with its documented outcome (docs/release.md, ADT under bounded
disk), against the real excerpt served from 127.0.0.1 (tests/support/adt_server.py)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from benchmarks.file_server import serve
from pipeline.adt.download import FETCH_FOLDER, fetch_sequence, plan_download, read_url_file, reclaim_scratch
from pipeline.adt.reader import check_csv, required_files
from pipeline.core.errors import InputError
from pipeline.io.files import PARTIAL, writer_host
from pipeline.io.http import FileClock, HttpError
from pipeline.settings.run_config import HttpConfig
from tests.support.adt_excerpt import ONE_FRAME_CHUNKS, SAMPLE, needs_excerpt
from tests.support.adt_server import write_layout
from tests.support.cli import REPO, run_in_process

SEQUENCE = SAMPLE.name
TOKEN = "tok-SECRET-3c9e"


@pytest.fixture
def served(tmp_path):
    folder = tmp_path / "served"
    folder.mkdir()
    with serve(folder, trickle_s=0.05) as server:
        yield server, write_layout(SAMPLE, SEQUENCE, folder, server.base_url)


def plan(url_file):
    return plan_download(read_url_file(str(url_file)), SEQUENCE, required_files(True))


KILLED_FETCH = """
import sys
from pipeline.adt.download import fetch_sequence, plan_download, read_url_file
from pipeline.adt.reader import required_files
download = plan_download(read_url_file(sys.argv[1]), sys.argv[2], required_files(True))
with fetch_sequence(download, sys.argv[3]):
    pass
"""


@needs_excerpt
def test_a_fetch_killed_mid_download_is_reclaimed_by_the_next(served, tmp_path):
    """SIGKILL leaves the killed process's fetch folder (its partial download in it); the next fetch
    into the same scratch folder deletes it, counts it free, completes and leaves the folder empty.
    A folder that is not a fetch folder, and a live process's fetch folder, are left alone."""
    server, layout = served
    server.fail(layout.filename("depth"), "trickle")
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    keep = [scratch / "notes", scratch / f"{FETCH_FOLDER}{PARTIAL}{writer_host()}-{os.getpid()}-live"]
    for folder in keep:
        folder.mkdir()
    env = dict(os.environ, PYTHONPATH=REPO)
    process = subprocess.Popen(
        [sys.executable, "-c", KILLED_FETCH, str(layout.url_file), SEQUENCE, str(scratch)], cwd=REPO, env=env
    )
    deadline = time.monotonic() + 60
    while server.sent(layout.filename("depth")) < 20_000 and time.monotonic() < deadline:
        time.sleep(0.05)
    process.send_signal(signal.SIGKILL)
    process.wait(30)
    left = [path for path in scratch.iterdir() if path not in keep]
    assert len(left) == 1 and left[0].name.startswith(
        f"{FETCH_FOLDER}{PARTIAL}{writer_host()}-{process.pid}-"
    )
    assert any(name.endswith(".download-0") for name in os.listdir(left[0]))
    server.reset()
    with fetch_sequence(plan(layout.url_file), str(scratch), HttpConfig(retries=1)) as folder:
        assert os.path.isfile(os.path.join(folder, "depth_images_with_skeleton.vrs"))
    assert sorted(scratch.iterdir()) == sorted(keep)


def test_reclaim_takes_only_dead_processes_fetch_folders(tmp_path):
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    ours = tmp_path / f"{FETCH_FOLDER}{PARTIAL}{writer_host()}-{dead.pid}-abc123"
    (ours / "sequence").mkdir(parents=True)
    (ours / "sequence.download-0").write_bytes(bytes(5000))
    others = [
        tmp_path / f"{FETCH_FOLDER}{PARTIAL}{writer_host()}-{os.getpid()}-def456",  # alive: this one
        tmp_path / f"{FETCH_FOLDER}-oldstyle123",  # not named as ours
        tmp_path / "data",
    ]
    for folder in others:
        folder.mkdir()
    (tmp_path / f"{FETCH_FOLDER}{PARTIAL}file").write_bytes(b"a file, not a folder")
    assert reclaim_scratch(str(tmp_path)) == 5000
    assert not ours.exists()
    assert all(folder.is_dir() for folder in others)
    assert (tmp_path / f"{FETCH_FOLDER}{PARTIAL}file").is_file()


@needs_excerpt
def test_a_trickling_server_fails_its_file_within_the_stall_rule(served, tmp_path):
    """1 KiB every 50 ms (20 KiB/s) is below a 100 KB/s stall rule of 1 s: the file fails after
    about a second, retries included, in one line."""
    server, layout = served
    server.fail(layout.filename("depth"), *["trickle"] * 5)
    started = time.monotonic()
    with pytest.raises(InputError) as caught:
        with fetch_sequence(
            plan(layout.url_file), str(tmp_path / "s"), HttpConfig(stall_s=1, stall_bytes_per_s=100_000)
        ):
            pass
    assert time.monotonic() - started < 5
    message = str(caught.value)
    assert message.startswith(f"{SEQUENCE}: data group depth: stalled: ")
    assert message.endswith("bytes in the last 1 s, below 100,000 bytes/s")


class FakeClock:
    def __init__(self):
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_the_default_stall_rule_fails_a_trickling_file_within_two_minutes():
    """With the defaults, a server sending 1 KiB every 20 s fails its file at the first sample past
    120 s; one sending 20 KiB/s never does, and a healthy file's deadline is two hours."""
    clock = FakeClock()
    trickle = FileClock(HttpConfig(), "https://example.org/f", clock)
    with pytest.raises(HttpError) as caught:
        while True:
            clock.now += 20.0
            trickle.got(1024)
    assert caught.value.kind == "stalled" and clock.now == 120.0
    steady = FileClock(HttpConfig(), "https://example.org/f", clock)
    for _ in range(600):  # 10 minutes
        clock.now += 1.0
        steady.got(20 << 10)
    clock.now += 7200.0
    with pytest.raises(HttpError, match="^deadline: not done after 7200 s"):
        steady.check()


@needs_excerpt
def test_no_output_holds_a_download_urls_token(served, tmp_path):
    """A URL with a port out of range, and one the server redirects to ftp://, both with a token:
    their sequences fail, and the token is in no output: stdout, stderr, the failures, the unit
    records, the verdicts, the run's provenance."""
    server, layout = served
    server.fail(layout.filename("segmentation"), "redirect:ftp://files.example.org/seg.zip?token=" + TOKEN)
    data = json.loads(layout.url_file.read_text())
    data["sequences"][SEQUENCE]["depth"]["download_url"] = f"http://127.0.0.1:99999/depth.zip?token={TOKEN}"
    data["sequences"][SEQUENCE]["segmentation"]["download_url"] += f"?token={TOKEN}"
    urls = tmp_path / "urls.json"
    urls.write_text(json.dumps(data))
    splits = tmp_path / "splits.json"
    splits.write_text(json.dumps({"minival": {"adt": [f"{SEQUENCE}_0.npz"]}, "full_eval": {}}))
    out = tmp_path / "out"
    outputs = []
    for _ in range(2):  # the bad port, then the redirect (the depth group fetched first, largest)
        result = run_in_process(
            "adt",
            *("--input", str(urls), "--output", str(out), "--release", str(splits), *ONE_FRAME_CHUNKS),
            *("--set", f"adt.scratch_dir={tmp_path / 'scratch'}", "--set", "http.retries=0"),
        )
        assert result.returncode == 1
        outputs.append(result.stdout + result.stderr)
        failures = (out / "failures_adt.jsonl").read_text()
        data["sequences"][SEQUENCE]["depth"]["download_url"] = layout.entry("depth")["download_url"]
        urls.write_text(json.dumps(data))
    assert "data group depth: not a usable URL" in outputs[0]
    assert "data group segmentation: unsupported URL scheme ftp://" in failures
    for root, _, names in os.walk(out):
        for name in names:
            assert TOKEN not in open(os.path.join(root, name), errors="replace").read(), name
    assert not any(TOKEN in text for text in outputs)


CTRL_C_RUN = (
    "-m",
    "pipeline.run",
    "--source",
    "adt",
    "--set",
    "http.backoff_s=15",
    "--set",
    "http.retries=5",
)


@needs_excerpt
def test_ctrl_c_in_a_retry_wait_exits_130(served, tmp_path):
    server, layout = served
    server.fail(layout.filename("depth"), *["503"] * 10)
    command = [
        sys.executable,
        *CTRL_C_RUN,
        *("--input", str(layout.url_file), "--output", str(tmp_path / "out"), *ONE_FRAME_CHUNKS),
        *("--set", f"adt.scratch_dir={tmp_path / 'scratch'}"),
    ]
    process = subprocess.Popen(command, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while server.requests(layout.filename("depth")) < 2 and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(0.5)  # the second try failed: now waiting 30 s before the third
    process.send_signal(signal.SIGINT)
    _, stderr = process.communicate(timeout=30)
    assert process.returncode == 130, stderr[-2000:]
    assert "interrupted: stopped" in stderr
    assert "cannot finish" not in stderr


@needs_excerpt
@pytest.mark.parametrize("mode", ["in_process", "multi_processing"])
def test_sigterm_mid_download_stops_as_ctrl_c_does_and_empties_the_scratch_folder(served, tmp_path, mode):
    """SIGTERM (a scheduler stopping the run) while a group's body trickles in: exit 143, one line,
    and no partial download left in the scratch folder, also where a worker process was fetching."""
    server, layout = served
    server.fail(layout.filename("depth"), *["trickle"] * 4)
    scratch = tmp_path / "scratch"
    workers = (
        ["--direct_running_mode=multi_processing", "--direct_num_workers=1"] if mode != "in_process" else []
    )
    command = [
        sys.executable,
        *("-m", "pipeline.run", "--source", "adt", "--input", str(layout.url_file)),
        *(
            "--output",
            str(tmp_path / "out"),
            *ONE_FRAME_CHUNKS,
            "--set",
            f"adt.scratch_dir={scratch}",
            *workers,
        ),
    ]
    process = subprocess.Popen(command, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while server.sent(layout.filename("depth")) < 4096 and time.monotonic() < deadline:
        time.sleep(0.05)
    assert any(scratch.rglob("*")), "the download had not started"
    process.send_signal(signal.SIGTERM)
    _, stderr = process.communicate(timeout=30)
    assert process.returncode == 143, stderr[-2000:]
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("terminated: stopped"), lines
    assert list(scratch.iterdir()) == []


def test_a_ground_truth_csv_that_no_reader_can_read_is_one_line(tmp_path):
    path = tmp_path / "scene_objects.csv"
    path.write_text("object_uid,timestamp[ns]\n" + "x" * 200_000 + ",1\n")
    with pytest.raises(InputError) as caught:
        check_csv(str(path))
    assert str(caught.value).startswith(
        "scene_objects.csv is not a readable CSV (field larger than field limit"
    )


@needs_excerpt
def test_units_failing_alike_stop_the_run(served, tmp_path):
    """Eight sequences on a server that trickles: each fails on the stall rule; after three in a row
    (``max_failures_in_a_row=3``) the run stops itself, exit 4, with one line naming the cause,
    instead of going through every sequence."""
    server, layout = served
    server.fail(layout.filename("depth"), *["trickle"] * 40)
    data = json.loads(layout.url_file.read_text())
    entry = data["sequences"].pop(SEQUENCE)
    data["sequences"] = {f"{SEQUENCE}_copy{i}": entry for i in range(8)}
    urls = tmp_path / "urls.json"
    urls.write_text(json.dumps(data))
    command = [
        sys.executable,
        *("-m", "pipeline.run", "--source", "adt", "--input", str(urls), "--output", str(tmp_path / "out")),
        *("--set", f"adt.scratch_dir={tmp_path / 'scratch'}", "--set", "max_failures_in_a_row=3"),
        *("--set", "http.stall_s=0.5", "--set", "http.stall_bytes_per_s=1000000", "--set", "http.retries=0"),
    ]
    result = subprocess.run(command, cwd=REPO, capture_output=True, text=True, timeout=120)
    assert result.returncode == 4, result.stderr[-2000:]
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith("stopped: the last 3 units failed alike (InputError: ")
    assert "data group depth: stalled: " in last
    assert last.endswith("rerun the same command to resume")
    assert result.stdout.count(" FAILED: ") < 8
