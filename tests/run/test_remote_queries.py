"""``pipeline.run --queries-from <http base>`` as the run meets a server that fails (benchmarks/file_server.py
on 127.0.0.1), on the toy source (four units, one clip each): it says once what it could not do as
asked, blames the fetches (not the reference) when they fail, resumes across a rotated token, and
stops when the server is gone. And a DirectRunner run never reaches for Beam's Prism runner."""

from __future__ import annotations

import json
import shutil

import pytest

from benchmarks.file_server import serve
from pipeline import sources
from tests.support.cli import run_in_process
from tests.support.toy.source import TOY

UNITS = ("a", "b", "c", "d")
TOKEN = "tok-SECRET-99e1"


@pytest.fixture(scope="module", autouse=True)
def toy():
    sources.register(TOY)
    yield
    sources.unregister(TOY.name)


@pytest.fixture(scope="module")
def toy_input(tmp_path_factory):
    """(input folder of four toy units, folder of their clips as a run made them: the served release)."""
    folder = tmp_path_factory.mktemp("toy_input")
    spec = {"frames": 6, "points": [[-0.2, 0.1, 2.0], [0.1, 0.0, 3.0]], "velocity": [0.01, 0, 0]}
    for name in UNITS:
        (folder / f"{name}.json").write_text(json.dumps(spec))
    made = tmp_path_factory.mktemp("made")
    result = run_in_process("toy", "--input", str(folder), "--output", str(made))
    assert result.returncode == 0, result.stderr[-2000:]
    served = tmp_path_factory.mktemp("served")
    shutil.copytree(made / "toy", served / "toy")
    return folder, served


def run(toy_input, out, base: str, *args: str):
    return run_in_process(
        "toy", "--input", str(toy_input[0]), "--output", str(out), "--queries-from", base, *args
    )


def test_a_server_that_ignores_range_is_said_once_with_its_bound(toy_input, tmp_path):
    with serve(toy_input[1], ranges=False) as whole:
        result = run(toy_input, tmp_path / "out", f"{whole.base_url}?token={TOKEN}")
    assert result.returncode == 0, result.stderr[-2000:]
    notes = [line for line in result.stderr.splitlines() if line.startswith("note: ")]
    assert notes == [
        f"note: {whole.base_url}: the server ignores Range requests; reading whole files from it "
        "(at most 4,294,967,296 bytes each)"
    ]
    record = json.loads((tmp_path / "out" / "run_toy.json").read_text())
    assert record["summary"]["notes"] == [notes[0].removeprefix("note: ")]
    assert TOKEN not in result.stdout + result.stderr


@pytest.mark.parametrize(
    ("fault", "cause"), [("416", "HTTP 416 (range not satisfiable)"), ("html", "not an .npz")]
)
def test_when_the_fetches_fail_the_last_line_says_so_not_that_the_reference_lacks_the_clips(
    toy_input, tmp_path, fault, cause
):
    with serve(toy_input[1]) as server:
        for name in UNITS:
            server.fail(f"toy/toy_{name}.npz", fault)
        result = run(toy_input, tmp_path / "out", server.base_url, "--set", "http.retries=0")
    assert result.returncode == 1
    last = result.stdout.strip().splitlines()[-1]
    assert last.startswith("no clip written: all 4 unit(s) failed (fetching --queries-from failed: 4 with ")
    assert cause in last and "holds none of their clips" not in last


def test_a_rotated_token_resumes_every_unit(toy_input, tmp_path):
    out = tmp_path / "out"
    with serve(toy_input[1]) as server:
        first = run(toy_input, out, f"{server.base_url}?token=one")
        assert first.returncode == 0, first.stderr[-2000:]
        second = run(toy_input, out, f"{server.base_url}?token=two")
    assert second.returncode == 0, second.stderr[-2000:]
    assert second.stdout.count("finished by an earlier run with these settings; skipped") == len(UNITS)


def test_units_failing_alike_against_a_dead_server_stop_the_run_even_as_the_last_ones(toy_input, tmp_path):
    with serve(toy_input[1]) as server:
        base = server.base_url
    result = run(toy_input, tmp_path / "out", base, "--set", "max_failures_in_a_row=2")
    assert result.returncode == 4
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith("stopped: the last ") and "connection refused" in last


def test_a_direct_runner_run_never_reaches_for_the_prism_runner(toy_input, tmp_path, monkeypatch):
    """Beam's DirectRunner would first try its Prism runner, downloading it at run time."""
    from apache_beam.runners.portability import prism_runner

    tried = []
    monkeypatch.setattr(prism_runner.PrismRunner, "__init__", lambda self, *a, **k: tried.append(1))
    result = run_in_process("toy", "--input", str(toy_input[0]), "--output", str(tmp_path / "out"))
    assert result.returncode == 0, result.stderr[-2000:]
    assert tried == []
