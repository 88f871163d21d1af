"""ADT under bounded disk, end to end: ``--input`` is the download-URLs JSON of the real excerpt
served over HTTP on 127.0.0.1 (a zip per data group, sha1s in the JSON). Each sequence is fetched into
the scratch folder, annotated and deleted: the clips are byte for byte those of the local-folder run,
the scratch folder is empty afterwards, and each injected fault (one 500 then success, a truncated
body, a wrong sha1, the server gone) gives its documented outcome, after which a rerun completes."""

from __future__ import annotations

import json
import os
import pathlib

import pytest

from benchmarks.file_server import serve
from tests.support.adt_excerpt import ONE_FRAME_CHUNKS, SAMPLE, needs_excerpt
from tests.support.adt_server import write_layout
from tests.support.cli import clip_bytes, run_in_process

pytestmark = needs_excerpt

SEQUENCE = SAMPLE.name
FAST_RETRIES = ("--set", "http.retries=2", "--set", "http.backoff_s=0.01")


@pytest.fixture(scope="module")
def local_clips(tmp_path_factory) -> dict[str, bytes]:
    out = str(tmp_path_factory.mktemp("local"))
    result = run_in_process("adt", "--input", str(SAMPLE), "--output", out, *ONE_FRAME_CHUNKS)
    assert result.returncode == 0, result.stderr[-3000:]
    return clip_bytes(out, "adt")


@pytest.fixture
def served(tmp_path):
    """(server, layout) of the excerpt, served from a folder of this test."""
    folder = tmp_path / "served"
    folder.mkdir()
    with serve(folder) as server:
        yield server, write_layout(SAMPLE, SEQUENCE, folder, server.base_url)


def fetch_run(url_file: pathlib.Path, out: pathlib.Path, scratch: pathlib.Path, *extra: str):
    return run_in_process(
        "adt",
        "--input",
        str(url_file),
        "--output",
        str(out),
        "--set",
        f"adt.scratch_dir={scratch}",
        *ONE_FRAME_CHUNKS,
        *FAST_RETRIES,
        *extra,
    )


def failures(out: pathlib.Path) -> list[dict]:
    return [json.loads(line) for line in (out / "failures_adt.jsonl").read_text().splitlines()]


def test_fetched_clips_are_the_local_runs_and_scratch_is_left_empty(served, local_clips, tmp_path):
    server, layout = served
    out, scratch = tmp_path / "out", tmp_path / "scratch"
    result = fetch_run(layout.url_file, out, scratch)
    assert result.returncode == 0, result.stderr[-3000:]
    assert clip_bytes(str(out), "adt") == local_clips
    assert os.listdir(scratch) == []
    assert "peak scratch: 1 worker(s) x " in result.stdout
    # Only the groups holding the files the annotation reads were fetched, each once.
    fetched = {
        group for group in layout.data["sequences"][SEQUENCE] if server.requests(layout.filename(group))
    }
    assert fetched == {"main_vrs", "main_groundtruth", "depth", "segmentation"}
    assert all(server.requests(layout.filename(group)) == 1 for group in fetched)


def test_a_500_then_success_is_retried(served, local_clips, tmp_path):
    server, layout = served
    server.fail(layout.filename("depth"), "500")
    out, scratch = tmp_path / "out", tmp_path / "scratch"
    result = fetch_run(layout.url_file, out, scratch)
    assert result.returncode == 0, result.stderr[-3000:]
    assert server.requests(layout.filename("depth")) == 2
    assert clip_bytes(str(out), "adt") == local_clips
    assert os.listdir(scratch) == []


@pytest.mark.parametrize(
    "fault, cause",
    [
        ("truncate", "truncated: got "),
        ("sha1", "sha1 mismatch (expected 0000000000000000000000000000000000000000, got "),
    ],
)
def test_a_bad_download_fails_the_sequence_and_a_rerun_completes(served, local_clips, tmp_path, fault, cause):
    server, layout = served
    url_file = layout.url_file
    if fault == "sha1":
        url_file = layout.variant("wrong_sha1", "segmentation", sha1sum="0" * 40)
    else:
        server.fail(layout.filename("segmentation"), fault, fault, fault)  # every try
    out, scratch = tmp_path / "out", tmp_path / "scratch"
    result = fetch_run(url_file, out, scratch)
    assert result.returncode == 1
    (failure,) = failures(out)
    assert failure["unit"] == f"{SEQUENCE}/all_chunks"
    assert failure["error"].startswith(f"InputError: {SEQUENCE}/all_chunks: data group segmentation: {cause}")
    assert os.listdir(scratch) == []
    assert not (out / "adt").exists()
    rerun = fetch_run(layout.url_file, out, scratch)
    assert rerun.returncode == 0, rerun.stderr[-3000:]
    assert clip_bytes(str(out), "adt") == local_clips
    assert os.listdir(scratch) == []


def test_the_server_gone_fails_the_sequence_and_a_rerun_completes(served, local_clips, tmp_path):
    server, layout = served
    server.stop()
    out, scratch = tmp_path / "out", tmp_path / "scratch"
    result = fetch_run(layout.url_file, out, scratch)
    assert result.returncode == 1
    (failure,) = failures(out)
    assert "data group " in failure["error"]
    assert failure["error"].endswith("connection refused")
    assert os.listdir(scratch) == []
    with serve(layout.folder) as again:  # back, on another port: the JSON names it
        url_file = write_layout(SAMPLE, SEQUENCE, layout.folder, again.base_url).url_file
        rerun = fetch_run(url_file, out, scratch)
    assert rerun.returncode == 0, rerun.stderr[-3000:]
    assert clip_bytes(str(out), "adt") == local_clips
    assert os.listdir(scratch) == []


def test_a_release_run_fetches_only_the_sequences_it_names(served, local_clips, tmp_path):
    server, layout = served
    release = tmp_path / "splits.json"
    release.write_text(
        json.dumps({"minival": {"adt": [f"{SEQUENCE}_1.npz"]}, "full_eval": {"adt": ["Other_seq_0.npz"]}})
    )
    out, scratch = tmp_path / "out", tmp_path / "scratch"
    result = fetch_run(layout.url_file, out, scratch, "--release", str(release))
    assert result.returncode == 0, result.stderr[-3000:]
    assert clip_bytes(str(out), "adt") == {f"{SEQUENCE}_1.npz": local_clips[f"{SEQUENCE}_1.npz"]}
    rows = [json.loads(line) for line in (out / "release_adt.jsonl").read_text().splitlines()]
    assert [(row["clip"], row["status"]) for row in rows] == [
        ("Other_seq_0", "input_absent"),
        (f"{SEQUENCE}_1", "written"),
    ]
    assert rows[0]["reason"] == "sequence Other_seq is not in the download-URLs JSON"

    nothing = tmp_path / "nothing.json"
    nothing.write_text(json.dumps({"minival": {"adt": ["Other_seq_0.npz"]}}))
    server.reset()
    result = fetch_run(layout.url_file, tmp_path / "out2", scratch, "--release", str(nothing))
    assert all(server.requests(layout.filename(group)) == 0 for group in layout.data["sequences"][SEQUENCE])
