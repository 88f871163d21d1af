"""The published release, side by side, over HTTP. "Published" files are made from a release run of the
DriveTrack sample with planted differences (the lead car's clip as it is; the crossing car's with the
visibility flipped on every tenth (frame, track) pair; the oncoming car's with every point moved 3 mm;
the parked car's absent) and served from 127.0.0.1 with a token in the base URL's query string. A
``--release --queries-from <base>`` run re-annotates their queries, ``audit compare <base> OUT``
scores each clip: the agreement is exactly what was planted, only the members needed are fetched,
a server that ignores Range gives the same figures, each fault gives its documented outcome, and the
token appears in no output."""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import shutil
import zipfile

import numpy as np
import pytest

from benchmarks.file_server import serve
from pipeline.audit.__main__ import main as audit_main
from pipeline.drivetrack.sample.waymo_world import SEGMENT
from pipeline.export.npz_writer import encode_npz
from pipeline.io.clip_reader import read_clip_file
from pipeline.io.given_queries import given_queries
from pipeline.io.http import HttpClient, HttpError
from pipeline.settings.run_config import HttpConfig
from tests.support.cli import run_in_process

TOKEN = "tok3n-SECRET-7f1c"
LEAD = f"tapvid3d_{SEGMENT}_1_lead_car_AAAAAAAAAAAAAAAAAAAAAA"
CROSSING = f"tapvid3d_{SEGMENT}_1_crossing_car_BBBBBBBBBBBBBBBBBB"
ONCOMING = f"tapvid3d_{SEGMENT}_1_oncoming_car_CCCCCCCCCCCCCCCCCC"
PARKED = f"tapvid3d_{SEGMENT}_3_parked_right_DDDDDDDDDDDDDDDDDD"
SPLITS = {
    "minival": {"drivetrack": [f"{LEAD}.npz"]},
    "full_eval": {"drivetrack": [f"{c}.npz" for c in (CROSSING, ONCOMING, PARKED)]},
}
MOVED_MM = 3.0
FAST = ("--set", "http.retries=1", "--set", "http.backoff_s=0.01")


def captured(command, *args) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = command(list(args))
    return code, out.getvalue(), err.getvalue()


def load(path) -> dict[str, np.ndarray]:
    with np.load(path) as data:
        return dict(data)


@pytest.fixture(scope="module")
def splits_file(tmp_path_factory) -> str:
    path = tmp_path_factory.mktemp("splits") / "splits.json"
    path.write_text(json.dumps(SPLITS))
    return str(path)


@pytest.fixture(scope="module")
def published(sample_split, splits_file, tmp_path_factory):
    """(folder served as the release, its clips' planted figures). The clips are a release run's of
    the sample, changed as the module says; the parked car's is left out."""
    made = tmp_path_factory.mktemp("made")
    result = run_in_process(
        "drivetrack", "--input", sample_split[0], "--output", str(made), "--release", splits_file
    )
    assert result.returncode == 0, result.stderr[-3000:]
    folder = tmp_path_factory.mktemp("published")
    clips = folder / "release" / "drivetrack"
    clips.mkdir(parents=True)
    shutil.copy(made / "drivetrack" / f"{LEAD}.npz", clips)
    crossing = load(made / "drivetrack" / f"{CROSSING}.npz")
    flat = crossing["visibility"].reshape(-1).copy()
    flipped = np.arange(flat.size) % 10 == 0
    flat[flipped] = ~flat[flipped]
    crossing["visibility"] = flat.reshape(crossing["visibility"].shape)
    (clips / f"{CROSSING}.npz").write_bytes(encode_npz(crossing))
    oncoming = load(made / "drivetrack" / f"{ONCOMING}.npz")
    oncoming["tracks_XYZ"] = oncoming["tracks_XYZ"] + np.array([MOVED_MM / 1000.0, 0.0, 0.0])
    (clips / f"{ONCOMING}.npz").write_bytes(encode_npz(oncoming))
    assert (made / "drivetrack" / f"{PARKED}.npz").exists()  # made, but not published
    planted = {"crossing_visibility": 1.0 - flipped.sum() / flat.size}
    return folder, planted


@pytest.fixture(scope="module")
def server(published):
    with serve(published[0]) as running:
        yield running


def base(server) -> str:
    return f"{server.base_url}/release?token={TOKEN}"


@pytest.fixture(scope="module")
def regenerated(server, sample_split, splits_file, tmp_path_factory):
    """A release run of the sample re-annotating the served clips' queries, then ``audit compare``."""
    out = tmp_path_factory.mktemp("regenerated")
    run = run_in_process(
        "drivetrack",
        *("--input", sample_split[0], "--output", str(out), "--release", splits_file),
        *("--queries-from", base(server), *FAST),
    )
    assert run.returncode == 0, run.stderr[-3000:]
    run_sent = {name: server.sent(f"release/drivetrack/{name}.npz") for name in (LEAD, CROSSING, ONCOMING)}
    compared = captured(audit_main, "compare", base(server), str(out))
    return out, run, run_sent, compared


def rows(regenerated) -> dict[str, dict]:
    out = regenerated[0]
    report = json.loads((out / "compare.json").read_text())
    return {row["clip"][: -len(".npz")]: row for row in report["clips"]}


def test_the_agreement_is_exactly_what_was_planted(regenerated, published):
    code, stdout, stderr = regenerated[3]
    assert code == 0, stderr
    found = rows(regenerated)
    lead, crossing, oncoming, parked = (found[name] for name in (LEAD, CROSSING, ONCOMING, PARKED))
    assert (lead["query_frames_equal"], lead["visibility"], lead["median_mm"], lead["p95_mm"]) == (1, 1, 0, 0)
    assert lead["agrees"] is True and lead["aj_median"] == 1.0
    assert crossing["visibility"] == published[1]["crossing_visibility"]
    assert (crossing["query_frames_equal"], crossing["p95_mm"], crossing["agrees"]) == (1.0, 0.0, False)
    assert oncoming["median_mm"] == pytest.approx(MOVED_MM, abs=1e-6)
    assert oncoming["p95_mm"] == pytest.approx(MOVED_MM, abs=1e-6)
    assert (oncoming["visibility"], oncoming["agrees"]) == (1.0, False)
    # The run made no parked car (the reference holds none to re-annotate): its verdict says why, and
    # compare neither fetches it nor counts it.
    assert parked["status"] == "not_made" and "fetched_bytes" not in parked
    assert parked["error"] == "not made by the run: not_produced: --queries-from holds no clip of this name"


def test_a_clip_absent_from_the_release_is_a_verdict(regenerated):
    out, run = regenerated[:2]
    assert "release clips: 4 named, 3 written, 1 not produced, 0 input absent, 0 failed" in run.stdout
    verdicts = {row["clip"]: row for row in map(json.loads, (out / "release_drivetrack.jsonl").open())}
    assert verdicts[PARKED]["status"] == "not_produced"
    assert verdicts[PARKED]["reason"] == "--queries-from holds no clip of this name"


def frames_bytes(path) -> int:
    with zipfile.ZipFile(path) as archive:
        return archive.getinfo("images_jpeg_bytes.npy").file_size


def test_only_the_members_needed_are_fetched(regenerated, server, published):
    """The run reads each clip's queries; compare its queries, tracks, visibility, intrinsics and the
    start of its first JPEG: never the frames. Each figure is what the server sent for the clip."""
    run_sent = regenerated[2]
    found = rows(regenerated)
    for name in (LEAD, CROSSING, ONCOMING):
        path = published[0] / "release" / "drivetrack" / f"{name}.npz"
        sent = server.sent(f"release/drivetrack/{name}.npz") - run_sent[name]
        assert run_sent[name] < 10_000  # the zip's directory and queries_xyt
        assert sent < path.stat().st_size - frames_bytes(path)
        assert found[name]["fetched_bytes"] == sent
    assert (
        f"fetched {sum(found[n]['fetched_bytes'] for n in (LEAD, CROSSING, ONCOMING)):,} bytes"
        in (regenerated[3][1])
    )


def test_the_verdicts_gain_the_agreement_and_audit_release_shows_it(regenerated):
    out = regenerated[0]
    verdicts = {row["clip"]: row for row in map(json.loads, (out / "release_drivetrack.jsonl").open())}
    assert verdicts[LEAD]["agreement"]["agrees"] is True
    assert verdicts[CROSSING]["agreement"]["visibility"] == rows(regenerated)[CROSSING]["visibility"]
    assert verdicts[PARKED]["agreement"]["status"] == "not_made"
    code, printed, _ = captured(audit_main, "release", str(out))
    assert code == 0
    assert re.search(r"minival\s+1\s+1\s+1\s+0\s+0\n", printed)
    assert re.search(r"full_test\s+3\s+2\s+0\s+0\s+1\n", printed)
    least = printed.split("least agreeing")[1].splitlines()[1:3]
    assert least[0].strip().startswith(f"{CROSSING} (full_test): 1, 0.9")
    assert least[1].strip().startswith(f"{ONCOMING} (full_test): 1, 1, 3, 3")


def test_the_audit_page_shows_the_same_table(regenerated, tmp_path):
    out = regenerated[0]
    page = tmp_path / "page.html"
    code, _, stderr = captured(audit_main, "report", str(out), "--out", str(page))
    assert code == 0, stderr
    data = json.loads(re.search(r'id="audit-data">(.*?)</script>', page.read_text())[1].replace("<\\/", "</"))
    (source,) = data["sources"]
    agreement = source["agreement"]
    assert [row["agree"] for row in agreement["splits"]] == [1, 0, 1]
    assert [row["clip"] for row in agreement["least"]] == [CROSSING, ONCOMING]


def test_a_server_that_ignores_range_gives_the_same_figures(regenerated, published, tmp_path):
    out = regenerated[0]
    with serve(published[0], ranges=False) as whole:
        code, stdout, stderr = captured(
            audit_main,
            "compare",
            f"{whole.base_url}/release?token={TOKEN}",
            str(out),
            "--out",
            str(tmp_path / "c"),
        )
        sizes = {
            name: (published[0] / "release" / "drivetrack" / f"{name}.npz").stat().st_size
            for name in (LEAD, CROSSING, ONCOMING)
        }
        sent = {name: whole.sent(f"release/drivetrack/{name}.npz") for name in sizes}
    assert code == 0, stderr
    assert stderr.count("the server ignores Range requests") == 1
    report = json.loads((tmp_path / "c.json").read_text())
    again = {row["clip"][: -len(".npz")]: row for row in report["clips"]}
    for name, row in rows(regenerated).items():
        for key in ("status", "query_frames_equal", "visibility", "median_mm", "p95_mm", "aj_median", "oa"):
            assert again[name].get(key) == row.get(key), (name, key)
    assert sent == sizes  # each file read once, whole


def test_given_queries_read_alike_with_range_without_it_and_from_a_folder(server, published):
    local = given_queries(str(published[0] / "release"), "drivetrack", LEAD)
    np.testing.assert_array_equal(given_queries(base(server), "drivetrack", LEAD), local)
    with serve(published[0], ranges=False) as whole:
        np.testing.assert_array_equal(given_queries(f"{whole.base_url}/release", "drivetrack", LEAD), local)
    assert given_queries(base(server), "drivetrack", PARKED) is None


def fetch_error(url: str, config: HttpConfig) -> HttpError:
    with pytest.raises(HttpError) as caught:
        read_clip_file(url, keys=("queries_xyt",), client=HttpClient(config))
    assert TOKEN not in str(caught.value) and TOKEN not in caught.value.url
    return caught.value


QUICK = HttpConfig(retries=2, backoff_s=0.01)


def test_a_truncated_body_is_retried_and_one_truncated_on_every_try_fails(server):
    path = f"release/drivetrack/{LEAD}.npz"
    server.fail(path, "truncate")
    url = f"{server.base_url}/{path}?token={TOKEN}"
    arrays = read_clip_file(url, keys=("queries_xyt",), client=HttpClient(QUICK))
    assert arrays["queries_xyt"].shape[1] == 3
    server.fail(path, "truncate", "truncate", "truncate")
    error = fetch_error(url, QUICK)
    assert error.kind == "truncated"
    assert str(error).startswith("truncated: ") and str(error).endswith("after 3 tries")


def test_a_404_a_dead_server_and_a_stalled_one_each_say_so(published, server):
    assert (
        fetch_error(f"{server.base_url}/release/drivetrack/none.npz?token={TOKEN}", QUICK).kind == "not_found"
    )
    with serve(published[0], trickle_s=0.5) as slow:
        path = f"release/drivetrack/{LEAD}.npz"
        slow.fail(path, *["trickle"] * 8)
        stalled = fetch_error(
            f"{slow.base_url}/{path}?token={TOKEN}", HttpConfig(stall_s=1.0, stall_bytes_per_s=1 << 20)
        )
    assert stalled.kind == "stalled"
    assert str(stalled).startswith("stalled: ")
    with serve(published[0]) as gone:
        url = f"{gone.base_url}/release/drivetrack/{LEAD}.npz?token={TOKEN}"
    refused = fetch_error(url, QUICK)
    assert (refused.kind, str(refused)) == ("refused", "connection refused")
    again = fetch_error(url, QUICK)  # the host is left alone for a minute
    assert again.kind == "refused" and "not asked again" in str(again)


def test_compare_against_a_dead_server_scores_nothing_and_names_the_cause(regenerated, published, tmp_path):
    with serve(published[0]) as gone:
        url = f"{gone.base_url}/release?token={TOKEN}"
    code, stdout, stderr = captured(
        audit_main, "compare", url, str(regenerated[0]), "--out", str(tmp_path / "c")
    )
    assert code == 1
    assert "connection refused" in stderr
    assert TOKEN not in stdout + stderr


def test_no_output_holds_the_token(regenerated):
    out, run, _, (code, stdout, stderr) = regenerated
    assert TOKEN not in run.stdout + run.stderr + stdout + stderr
    for root, _, names in os.walk(out):
        for name in names:
            with open(os.path.join(root, name), "rb") as handle:
                assert TOKEN.encode() not in handle.read(), os.path.join(root, name)
