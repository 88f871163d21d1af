"""Fetching an ADT sequence from a download-URLs JSON: the real excerpt laid out as ADT serves it
(tests/support/adt_server.py), planned, fetched over HTTP with faults, checked and cleaned away."""

import hashlib
import json
import math
import os
import pathlib

import pytest

from benchmarks.file_server import serve
from pipeline.adt import download
from pipeline.adt.download import fetch_sequence, is_url_file, plan_download, read_url_file
from pipeline.adt.reader import SequenceReader, required_files
from pipeline.core.errors import InputError
from pipeline.core.sizes import format_bytes
from pipeline.settings.run_config import HttpConfig
from tests.support.adt_excerpt import SAMPLE, needs_excerpt
from tests.support.adt_server import GROUPS, write_layout

pytestmark = needs_excerpt
SEQUENCE = SAMPLE.name
FAST = {"http": HttpConfig(retries=2, backoff_s=0.001)}
NEEDED = required_files(True)


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    folder = tmp_path_factory.mktemp("served")
    with serve(folder) as server:
        yield server, write_layout(SAMPLE, SEQUENCE, folder, server.base_url)


@pytest.fixture
def server(served):
    served[0].reset()
    return served[0]


@pytest.fixture
def layout(served):
    return served[1]


@pytest.fixture
def scratch(tmp_path):
    return tmp_path / "scratch"  # not made: fetch_sequence makes it


def plan(url_file, needed=NEEDED):
    return plan_download(read_url_file(str(url_file)), SEQUENCE, needed)


def fetch_error(url_file, scratch, needed=NEEDED, **options) -> str:
    with pytest.raises(InputError) as caught:
        with fetch_sequence(plan(url_file, needed), str(scratch), **{**FAST, **options}):
            pass
    assert os.listdir(scratch) == [], "the scratch folder must be left empty"
    message = str(caught.value)
    assert "\n" not in message
    return message


def sha256(path) -> str:
    return hashlib.sha256(pathlib.Path(path).read_bytes()).hexdigest()


def files_under(folder) -> set[str]:
    return {
        os.path.relpath(os.path.join(root, name), folder).replace(os.sep, "/")
        for root, _, names in os.walk(folder)
        for name in names
    }


def test_is_url_file(layout, tmp_path):
    (tmp_path / "notes.txt").write_text(layout.url_file.read_text())
    assert is_url_file(str(layout.url_file))
    assert not is_url_file(str(SAMPLE))
    assert not is_url_file(str(SAMPLE / "metadata.json"))  # JSON, but no sequences
    assert not is_url_file(str(tmp_path / "notes.txt"))


@pytest.mark.parametrize("skeleton", [True, False])
def test_plan_takes_the_groups_holding_the_needed_files(layout, skeleton):
    suffix = "_with_skeleton" if skeleton else ""
    got = plan(layout.url_file, required_files(skeleton))
    truth = (
        "aria_trajectory.csv",
        "scene_objects.csv",
        "3d_bounding_box.csv",
        "instances.json",
        "metadata.json",
    )
    expected = {
        "depth": (f"depth_images{suffix}.vrs",),
        "segmentation": (f"segmentations{suffix}.vrs",),
        "main_groundtruth": truth,
        "main_vrs": ("video.vrs",),
    }
    assert {g.name: g.files for g in got.groups} == expected
    # Zips largest first (depth 6.0 MB, segmentation 0.4, ground truth 0.2), the recording last.
    assert [g.name for g in got.groups] == ["depth", "segmentation", "main_groundtruth", "main_vrs"]
    for group in got.groups:
        entry = layout.entry(group.name)
        assert (group.url, group.sha1, group.size) == (
            entry["download_url"],
            entry["sha1sum"],
            entry["file_size_bytes"],
        )
        assert group.is_recording == (group.name == "main_vrs")
    assert got.download_bytes == sum(layout.entry(g)["file_size_bytes"] for g in expected)
    depth = layout.entry("depth")["file_size_bytes"]
    assert got.peak_bytes == depth + math.ceil(1.1 * depth)  # the depth zip and its VRS files


def test_plan_of_other_files(layout):
    assert [(g.name, g.files) for g in plan(layout.url_file, ["synthetic_video.vrs"]).groups] == [
        ("synthetic", ("synthetic_video.vrs",))
    ]
    (mps,) = plan(layout.url_file, ["mps/eye_gaze/general_eye_gaze.csv"]).groups
    assert (mps.name, mps.folder) == ("mps_eye_gaze", "mps/eye_gaze")


def test_plan_refuses_what_the_url_file_lacks(layout):
    with pytest.raises(InputError, match=f"^{SEQUENCE}: nowhere.vrs is in no data group of "):
        plan(layout.url_file, ["video.vrs", "nowhere.vrs"])
    no_depth = layout.variant("no-depth", "depth")
    with pytest.raises(InputError, match=f"^{SEQUENCE}: data group depth .holding depth_images.vrs. has no"):
        plan(no_depth, required_files(False))
    with pytest.raises(InputError, match="no sequence 'other'"):
        plan_download(read_url_file(str(layout.url_file)), "other", ["video.vrs"])


def test_peak_bytes_rule(tmp_path):
    def url_file(sizes):
        sequences = {
            "s": {
                group: {
                    "download_url": f"http://h/{group}",
                    "filename": group,
                    "sha1sum": "0" * 40,
                    "file_size_bytes": size,
                }
                for group, size in sizes.items()
            }
        }
        config = {
            "main": {"recording": "video.vrs", "mps": "None"},
            "data_groups": {"a": ["a.vrs"], "b": ["b.csv"]},
        }
        path = tmp_path / "urls.json"
        path.write_text(json.dumps({"sequences": sequences, "sequence_config": config}))
        return read_url_file(str(path))

    # A zip's needed VRS files take at most 1.1 times the zip, text 20 times; each zip is deleted
    # once unpacked, the recording (main_vrs) is kept as it is.
    files = ["video.vrs", "a.vrs", "b.csv"]
    small_first = plan_download(url_file({"main_vrs": 7, "b": 1, "a": 100}), "s", files)
    assert [g.name for g in small_first.groups] == ["a", "b", "main_vrs"]
    # a: its zip and files 100 + 110; then b beside a's files: 110 + 1 + 20; then 110 + 20 + 7
    assert (small_first.download_bytes, small_first.peak_bytes) == (108, 210)
    recording_heavy = plan_download(url_file({"main_vrs": 50, "a": 10, "b": 5}), "s", files)
    assert recording_heavy.peak_bytes == 161  # all kept: 11 + 100 + 50


@pytest.mark.parametrize("skeleton", [True, False])
def test_fetch_gives_exactly_the_needed_files(layout, server, scratch, skeleton):
    with fetch_sequence(plan(layout.url_file, required_files(skeleton)), str(scratch), **FAST) as folder:
        assert os.path.basename(folder) == SEQUENCE
        assert os.path.dirname(os.path.dirname(folder)) == str(scratch)
        assert files_under(folder) == set(required_files(skeleton))
        for name in required_files(skeleton):
            assert sha256(os.path.join(folder, name)) == sha256(SAMPLE / name), name
        if skeleton:  # the layout is what the ADT reader expects
            reader = SequenceReader(folder, True, 40_000_000)
            try:
                assert len(reader.frame_timestamps()) == 2
            finally:
                reader.close()
    assert os.listdir(scratch) == []
    assert server.requests(layout.filename("synthetic")) == 0


def test_fetch_puts_mps_files_in_their_folder(layout, server, scratch):
    needed = ["mps/eye_gaze/general_eye_gaze.csv", "mps/eye_gaze/summary.json"]
    with fetch_sequence(plan(layout.url_file, needed), str(scratch), **FAST) as folder:
        assert files_under(folder) == set(needed)
        assert all(sha256(os.path.join(folder, name)) == sha256(SAMPLE / name) for name in needed)


@pytest.mark.parametrize("status", ["500", "429", "503"])
def test_a_passing_server_error_is_retried(layout, server, scratch, status):
    server.fail(layout.filename("depth"), status)
    with fetch_sequence(plan(layout.url_file), str(scratch), **FAST) as folder:
        assert sha256(os.path.join(folder, "depth_images_with_skeleton.vrs")) == sha256(
            SAMPLE / "depth_images_with_skeleton.vrs"
        )
    assert server.requests(layout.filename("depth")) == 2
    assert os.listdir(scratch) == []


def test_a_lasting_server_error_fails_after_the_retries(layout, server, scratch):
    server.fail(layout.filename("segmentation"), "500", "500", "500")
    message = fetch_error(layout.url_file, scratch)
    assert message == f"{SEQUENCE}: data group segmentation: HTTP 500 after 3 tries"
    assert server.requests(layout.filename("segmentation")) == 3


def test_dropped_connections_are_retried(layout, server, scratch):
    server.fail(layout.filename("main_groundtruth"), "drop", "drop")
    with fetch_sequence(plan(layout.url_file), str(scratch), **FAST) as folder:
        assert sha256(os.path.join(folder, "scene_objects.csv")) == sha256(SAMPLE / "scene_objects.csv")
    assert server.requests(layout.filename("main_groundtruth")) == 3


@pytest.mark.parametrize("fault", ["truncate", "short"])
def test_a_body_cut_short_is_resumed_where_it_stopped(layout, server, scratch, fault):
    """Cut short under a full Content-Length (the connection breaks) or with none (a quiet end): the
    next request asks for the rest only (Range), so the file's bytes are sent once, but for the
    unfinished read (at most a chunk, 1 MiB) the broken connection took with it."""
    server.fail(layout.filename("depth"), fault)
    size = layout.entry("depth")["file_size_bytes"]
    with fetch_sequence(plan(layout.url_file), str(scratch), **FAST) as folder:
        assert sha256(os.path.join(folder, "depth_images_with_skeleton.vrs")) == sha256(
            SAMPLE / "depth_images_with_skeleton.vrs"
        )
    assert server.requests(layout.filename("depth")) == 2
    assert size <= server.sent(layout.filename("depth")) < size + (1 << 20)


@pytest.mark.parametrize("fault, tail", [("truncate", " (connection broken)"), ("short", "")])
def test_a_body_cut_short_on_every_try_is_an_error(layout, server, scratch, fault, tail):
    server.fail(layout.filename("depth"), fault, fault, fault)
    size = layout.entry("depth")["file_size_bytes"]
    message = fetch_error(layout.url_file, scratch)
    assert message.startswith(f"{SEQUENCE}: data group depth: truncated: got ")
    got = int(message.split("got ")[1].split(" of ")[0])
    assert size // 2 < got < size  # each try got half of what was left
    assert message.endswith(f" of {size} bytes{tail} after 3 tries")
    assert server.requests(layout.filename("depth")) == 3


def test_a_body_longer_than_the_url_files_size_is_an_error(layout, server, scratch):
    server.fail(layout.filename("segmentation"), "long")
    size = layout.entry("segmentation")["file_size_bytes"]
    message = fetch_error(layout.url_file, scratch)
    assert message == f"{SEQUENCE}: data group segmentation: too long: more than the {size} bytes expected"


def test_a_wrong_sha1_is_an_error(layout, server, scratch):
    real = layout.entry("main_vrs")["sha1sum"]
    url_file = layout.variant("bad-sha1", "main_vrs", sha1sum="ab" * 20)
    message = fetch_error(url_file, scratch)
    assert message == f"{SEQUENCE}: data group main_vrs: sha1 mismatch (expected {'ab' * 20}, got {real})"


def test_a_size_other_than_the_url_files_is_an_error(layout, server, scratch):
    size = layout.entry("segmentation")["file_size_bytes"]
    url_file = layout.variant("bad-size", "segmentation", file_size_bytes=size + 1)
    message = fetch_error(url_file, scratch)
    assert message == (
        f"{SEQUENCE}: data group segmentation: size mismatch: "
        f"Content-Length {size}, {size + 1} bytes expected"
    )


def test_a_missing_file_is_http_404(layout, server, scratch):
    url_file = layout.variant("gone", "main_groundtruth", download_url=f"{layout.base_url}/gone.zip")
    assert fetch_error(url_file, scratch) == f"{SEQUENCE}: data group main_groundtruth: HTTP 404"


def test_the_server_gone_fails_at_once(tmp_path, scratch):
    """A refused connection is not retried (the host is left alone for a minute)."""
    with serve(tmp_path) as gone:
        layout = write_layout(SAMPLE, SEQUENCE, tmp_path, gone.base_url, mps=False)
        gone.stop()
        message = fetch_error(layout.url_file, scratch)
    assert message == f"{SEQUENCE}: data group depth: connection refused"


def test_no_room_in_the_scratch_folder(layout, server, scratch):
    url_file = layout.variant("huge", "depth", file_size_bytes=10**18)
    message = fetch_error(url_file, scratch)
    assert message.startswith(f"{SEQUENCE}: fetching it needs up to 2100000.0 TB in {scratch}, which has ")
    assert server.requests(layout.filename("depth")) == 0


def ground_truth(**extra: bytes) -> dict[str, bytes]:
    return {**{name: (SAMPLE / name).read_bytes() for name in GROUPS["main_groundtruth"]}, **extra}


def test_a_zip_member_leaving_the_folder_is_refused(layout, server, scratch, tmp_path):
    entry = layout.add_zip("evil.zip", ground_truth(**{"../evil": b"escaped"}))
    message = fetch_error(layout.variant("evil", "main_groundtruth", entry), scratch)
    assert message == (
        f"{SEQUENCE}: data group main_groundtruth: "
        "unsafe member '../evil' in the zip (absolute or with '..'), refused"
    )
    absolute = layout.add_zip("absolute.zip", ground_truth(**{"/tmp/evil": b"escaped"}))
    assert "unsafe member '/tmp/evil'" in fetch_error(
        layout.variant("abs", "main_groundtruth", absolute), scratch
    )
    assert not (tmp_path / "evil").exists()
    assert not list(tmp_path.rglob("evil"))


def test_a_needed_file_unpacking_beyond_the_estimate_fails_in_one_line(layout, server, scratch):
    """A small zip whose scene_objects.csv unpacks to 60 MiB (a CSV of one repeated row) exceeds what
    the scratch estimate allows the zip (20 times its size for text): refused before unpacking,
    naming the file, the scratch folder left empty."""
    header = (SAMPLE / "scene_objects.csv").read_bytes().split(b"\n", 1)[0] + b"\n"
    row = (SAMPLE / "scene_objects.csv").read_bytes().split(b"\n")[1] + b"\n"
    bomb = header + row * ((60 << 20) // len(row))
    entry = layout.add_zip("bomb.zip", ground_truth(**{"scene_objects.csv": bomb}))
    assert entry["file_size_bytes"] * 20 < len(bomb)
    message = fetch_error(layout.variant("bomb", "main_groundtruth", entry), scratch)
    assert message.startswith(f"{SEQUENCE}: data group main_groundtruth: its needed files unpack to ")
    assert f"(scene_objects.csv: {format_bytes(len(bomb))})" in message
    assert message.endswith(
        f"the scratch estimate allows a {format_bytes(entry['file_size_bytes'])} zip of them; refused"
    )


def test_an_unneeded_member_is_never_unpacked(layout, server, scratch):
    entry = layout.add_zip("extra.zip", ground_truth(**{"zeros.bin": bytes(100 << 20)}))
    with fetch_sequence(
        plan(layout.variant("extra", "main_groundtruth", entry)), str(scratch), **FAST
    ) as folder:
        assert "zeros.bin" not in files_under(folder)
        assert sum(os.path.getsize(os.path.join(folder, name)) for name in files_under(folder)) < 20 << 20


def test_the_peak_estimate_bounds_what_the_excerpt_takes(layout, server, scratch, monkeypatch):
    """The most the scratch folder held, sampled after every group's file is written and unpacked,
    is within the plan's peak_bytes."""
    planned = plan(layout.url_file)
    held = []
    unpack = download._unpack

    def measured(path, group, folder):
        unpack(path, group, folder)
        held.append(
            sum(os.path.getsize(os.path.join(root, n)) for root, _, ns in os.walk(scratch) for n in ns)
        )

    monkeypatch.setattr(download, "_unpack", measured)
    with fetch_sequence(planned, str(scratch), **FAST):
        pass
    assert 0 < max(held) <= planned.peak_bytes


def test_a_zip_lacking_a_needed_file_is_an_error(layout, server, scratch):
    members = ground_truth()
    del members["scene_objects.csv"]
    url_file = layout.variant("lacking", "main_groundtruth", layout.add_zip("lacking.zip", members))
    assert (
        fetch_error(url_file, scratch)
        == f"{SEQUENCE}: data group main_groundtruth: the zip holds no scene_objects.csv"
    )


def test_a_group_that_is_no_zip_is_an_error(layout, server, scratch):
    url_file = layout.variant("not-zip", "segmentation", layout.entry("main_vrs"))
    message = fetch_error(url_file, scratch)
    assert message == f"{SEQUENCE}: data group segmentation: cannot unpack the zip: File is not a zip file"


def test_ctrl_c_in_the_body_leaves_the_scratch_folder_empty(layout, server, scratch):
    with pytest.raises(KeyboardInterrupt):
        with fetch_sequence(plan(layout.url_file), str(scratch), **FAST) as folder:
            assert os.path.isfile(os.path.join(folder, "video.vrs"))
            raise KeyboardInterrupt
    assert os.listdir(scratch) == []


def test_ctrl_c_while_unpacking_leaves_the_scratch_folder_empty(layout, server, scratch, monkeypatch):
    def interrupted(path, group, folder):
        assert os.path.getsize(path) == group.size  # the zip is there, beside the sequence folder
        raise KeyboardInterrupt

    monkeypatch.setattr(download, "_unpack", interrupted)
    with pytest.raises(KeyboardInterrupt):
        with fetch_sequence(plan(layout.url_file), str(scratch), **FAST):
            pytest.fail("the body must not run")
    assert os.listdir(scratch) == []


BAD_URL_FILES = {
    "not JSON": ("{not json", "not JSON"),
    "a list": ("[1, 2]", "the top level is a list, not an object"),
    "no sequences": ('{"sequence_config": {}}', "no 'sequences' key, not an ADT URL file"),
    "sequences a list": (
        '{"sequences": [], "sequence_config": {}}',
        "'sequences' must be a dict, not list",
    ),
    "no download_url": (
        {"s": {"main_vrs": {"filename": "v.vrs", "sha1sum": "0" * 40, "file_size_bytes": 1}}},
        "'sequences/s/main_vrs' has no 'download_url'",
    ),
    "bad sha1": (
        {"s": {"main_vrs": {"download_url": "http://h/v", "sha1sum": "xyz", "file_size_bytes": 1}}},
        "'sequences/s/main_vrs': 'sha1sum' must be 40 hex digits, not 'xyz'",
    ),
    "no size": (
        {"s": {"main_vrs": {"download_url": "http://h/v", "sha1sum": "0" * 40}}},
        "'file_size_bytes' must be a byte count, not None",
    ),
    "file URL": (
        {
            "s": {
                "main_vrs": {"download_url": "file:///etc/passwd", "sha1sum": "0" * 40, "file_size_bytes": 1}
            }
        },
        "the download URL is not http:// or https://",
    ),
    "escaping file": (
        {"s": {}},
        "'sequence_config/data_groups/gt': '../x.csv' is not a plain relative file name",
    ),
}


@pytest.mark.parametrize("case", BAD_URL_FILES)
def test_malformed_url_files_are_one_line_errors(tmp_path, case):
    content, expected = BAD_URL_FILES[case]
    if isinstance(content, dict):
        groups = {"gt": ["../x.csv"]} if case == "escaping file" else {"gt": ["a.csv"]}
        config = {"main": {"recording": "video.vrs", "mps": "None"}, "data_groups": groups}
        content = json.dumps({"sequences": content, "sequence_config": config})
    path = tmp_path / "urls.json"
    path.write_text(content)
    with pytest.raises(InputError) as caught:
        read_url_file(str(path))
    message = str(caught.value)
    assert message.startswith(f"{path}: ")
    assert expected in message
    assert "\n" not in message


def test_an_oversized_url_file_is_refused_unread(tmp_path, monkeypatch):
    monkeypatch.setattr(download, "MAX_URL_FILE_BYTES", 100)
    path = tmp_path / "urls.json"
    path.write_text(json.dumps({"sequences": {}, "sequence_config": {}, "pad": "x" * 100}))
    with pytest.raises(InputError, match=r"larger than 100 B, not an ADT URL file"):
        read_url_file(str(path))


def test_format_bytes():
    assert [format_bytes(n) for n in (0, 999, 1000, 12_345_678, 1_700_000_000_000)] == [
        "0 B",
        "999 B",
        "1.0 kB",
        "12.3 MB",
        "1.7 TB",
    ]
