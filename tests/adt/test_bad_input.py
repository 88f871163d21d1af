"""ADT bad input: one CLI run over the real excerpt (``good_M1292``) and one broken copy of it per case
(the unit ``<case>/chunk_0``); each broken copy fails alone with its InputError, the good one writes its clip.

V = video.vrs, D = depth_images_with_skeleton.vrs, S = segmentations_with_skeleton.vrs,
T = aria_trajectory.csv, O = scene_objects.csv; "line n" is the file's line (1 = header).

| case | how it is made | expected error (after ``<case>/chunk_0: ``) |
|---|---|---|
| video_truncated | V cut to 60% of its bytes | V is truncated or corrupt: the record at byte ... |
| video_junk | V overwritten with as many bytes of junk text | V is not a VRS file (...) |
| depth_truncated | D cut to half its bytes | D is truncated or corrupt: the record at byte ... |
| ids_zeroed | S zeroed after its 80-byte header | S is corrupt: the record header at byte 9983 is not valid |
| no_video | V absent | missing V |
| no_depth | D absent | missing D |
| no_instances | instances.json absent | missing instances.json |
| no_objects | O absent | missing O |
| metadata_malformed | metadata.json = ``{not json`` | metadata.json is not valid JSON (...) |
| objects_empty | O holds its header only | O has no row below its header |
| trajectory_nan | T line 3: tx_world_device = nan | T line 3 (tracking_timestamp_us=...): tx_world_device |
| | | is 'nan', not a finite number |
| objects_nan | O line 306 (dynamic): t_wo_x[m] = nan | O line 306 (object_uid=..., timestamp[ns]=...): |
| | | t_wo_x[m] is 'nan', not a finite number |
| trajectory_zero_quaternion | T line 4: q*_world_device = 0 | T line 4 (...): the quaternion |
| | | (qw_world_device, ...) has norm 0, not 1: not a rotation |
| objects_zero_quaternion | O line 2: q_wo_* = 0 | O line 2 (...): the quaternion (q_wo_w, ...) |
| | | has norm 0, not 1: not a rotation |
| trajectory_text | T line 2: qw_world_device = one | T line 2 (...): qw_world_device is 'one', not a number |
| objects_text | O line 307: t_wo_y[m] = 1.5m | O line 307 (...): t_wo_y[m] is '1.5m', not a number |
| no_window | T timestamps 10 s later | no RGB frame inside the ground-truth window [...] ns (3 RGB |
| | | frame(s) in video.vrs) |
| no_pose | O without the object under the first | object <id> has no pose at t=... ns |
| | frame's centre | |
"""

import functools
import os
import pathlib

import pytest

from tests.support.adt_excerpt import SAMPLE, SETTINGS, needs_excerpt
from tests.support.bad_input import assert_case_error, assert_only_these_units_failed
from tests.support.cli import run_in_process

VIDEO, DEPTH, IDS = "video.vrs", "depth_images_with_skeleton.vrs", "segmentations_with_skeleton.vrs"
TRAJECTORY, OBJECTS = "aria_trajectory.csv", "scene_objects.csv"
TRAJECTORY_Q = ("qw_world_device", "qx_world_device", "qy_world_device", "qz_world_device")
OBJECTS_Q = ("q_wo_w", "q_wo_x", "q_wo_y", "q_wo_z")

pytestmark = needs_excerpt


def replaced(name, content):
    """Replace the link ``name`` by a file holding ``content(the sample's bytes)``."""

    def make(sequence: pathlib.Path) -> None:
        data = content((SAMPLE / name).read_bytes())
        (sequence / name).unlink()
        (sequence / name).write_bytes(data)

    return make


def removed(name):
    return lambda sequence: (sequence / name).unlink()


def csv_lines(name, change):
    """The CSV with its lines (header first) passed through ``change``."""
    return replaced(name, lambda data: "".join(f"{x}\n" for x in change(data.decode().splitlines())).encode())


def cells(name, line, values):
    """The CSV with the cells of line ``line`` in ``values`` (column -> text) replaced."""

    def change(lines):
        header, row = lines[0].split(","), lines[line - 1].split(",")
        for column, value in values.items():
            row[header.index(column)] = value
        return [*lines[: line - 1], ",".join(row), *lines[line:]]

    return csv_lines(name, change)


def shifted_trajectory(lines):
    """Every trajectory timestamp (microseconds) 10 s later: no RGB frame inside the ground truth."""
    rows = [line.split(",") for line in lines[1:]]
    return [lines[0], *(",".join([r[0], str(int(r[1]) + 10_000_000), *r[2:]]) for r in rows)]


@functools.cache
def centre_object() -> int:
    """The object under the centre of the first frame inside the ground-truth window (fisheye ids)."""
    from projectaria_tools.core.stream_id import StreamId
    from projectaria_tools.projects import adt

    paths = adt.AriaDigitalTwinDataPathsProvider(str(SAMPLE)).get_datapaths_by_device_num(0, True)
    provider = adt.AriaDigitalTwinDataProvider(paths)
    stream = StreamId("214-1")
    start, end = provider.get_start_time_ns(), provider.get_end_time_ns()
    first = min(t for t in provider.get_aria_device_capture_timestamps_ns(stream) if start < t < end)
    ids = provider.get_segmentation_image_by_timestamp_ns(first, stream).data().to_numpy_array()
    return int(ids[ids.shape[0] // 2, ids.shape[1] // 2])


def without_centre_object(lines):
    kept = [lines[0], *(line for line in lines[1:] if not line.startswith(f"{centre_object()},"))]
    assert len(kept) < len(lines)
    return kept


# (case, how a linked copy of the excerpt is broken, substrings of its error)
CASES = [
    (
        "video_truncated",
        replaced(VIDEO, lambda d: d[: len(d) * 6 // 10]),
        [f"{VIDEO} is truncated or corrupt"],
    ),
    ("video_junk", replaced(VIDEO, lambda d: (b"junk " * len(d))[: len(d)]), [f"{VIDEO} is not a VRS file"]),
    ("depth_truncated", replaced(DEPTH, lambda d: d[: len(d) // 2]), [f"{DEPTH} is truncated or corrupt"]),
    (
        "ids_zeroed",
        replaced(IDS, lambda d: d[:80].ljust(len(d), b"\0")),
        [f"{IDS} is corrupt: the record header at byte 9983 is not valid"],
    ),
    ("no_video", removed(VIDEO), [f"no_video/chunk_0: missing {VIDEO}"]),
    ("no_depth", removed(DEPTH), [f"missing {DEPTH}"]),
    ("no_instances", removed("instances.json"), ["missing instances.json"]),
    ("no_objects", removed(OBJECTS), [f"missing {OBJECTS}"]),
    (
        "metadata_malformed",
        replaced("metadata.json", lambda d: b"{not json"),
        ["metadata.json is not valid JSON"],
    ),
    (
        "objects_empty",
        csv_lines(OBJECTS, lambda lines: lines[:1]),
        [f"{OBJECTS} has no row below its header"],
    ),
    (
        "trajectory_nan",
        cells(TRAJECTORY, 3, {"tx_world_device": "nan"}),
        [f"{TRAJECTORY} line 3 (tracking_timestamp_us=87551204238): tx_world_device is 'nan', not a finite"],
    ),
    (
        "objects_nan",
        cells(OBJECTS, 306, {"t_wo_x[m]": "nan"}),
        [
            f"{OBJECTS} line 306 (object_uid=4709930779068635, timestamp[ns]=87551170910700): "
            "t_wo_x[m] is 'nan', not a finite number"
        ],
    ),
    (
        "trajectory_zero_quaternion",
        cells(TRAJECTORY, 4, dict.fromkeys(TRAJECTORY_Q, "0")),
        [
            f"{TRAJECTORY} line 4 (tracking_timestamp_us=87551237566): the quaternion "
            f"({', '.join(TRAJECTORY_Q)}) has norm 0, not 1: not a rotation"
        ],
    ),
    (
        "objects_zero_quaternion",
        cells(OBJECTS, 2, dict.fromkeys(OBJECTS_Q, "0")),
        [
            f"{OBJECTS} line 2 (object_uid=5691266090916432, timestamp[ns]=-1): the quaternion "
            f"({', '.join(OBJECTS_Q)}) has norm 0, not 1: not a rotation"
        ],
    ),
    (
        "trajectory_text",
        cells(TRAJECTORY, 2, {"qw_world_device": "one"}),
        [f"{TRAJECTORY} line 2 (tracking_timestamp_us=87551170910): qw_world_device is 'one', not a number"],
    ),
    (
        "objects_text",
        cells(OBJECTS, 307, {"t_wo_y[m]": "1.5m"}),
        [
            f"{OBJECTS} line 307 (object_uid=4404207983027294, timestamp[ns]=87551170910700): "
            "t_wo_y[m] is '1.5m', not a number"
        ],
    ),
    (
        "no_window",
        csv_lines(TRAJECTORY, shifted_trajectory),
        ["no RGB frame inside the ground-truth window", "(3 RGB frame(s) in video.vrs)"],
    ),
    ("no_pose", csv_lines(OBJECTS, without_centre_object), ["has no pose at t="]),
]


@pytest.fixture(scope="module")
def bad_run(tmp_path_factory):
    """(output folder, failures by unit) of one run over the good sequence and one broken copy per
    case (symbolic links to the excerpt's files, the broken one replaced)."""
    root = tmp_path_factory.mktemp("bad_adt") / "adt"
    for name, make in [("good_M1292", None), *((case, make) for case, make, _ in CASES)]:
        (root / name).mkdir(parents=True)
        for entry in SAMPLE.iterdir():
            (root / name / entry.name).symlink_to(entry)
        if make:
            make(root / name)
    out = root.parent / "out"
    result = run_in_process("adt", "--input", str(root), "--output", str(out), *SETTINGS)
    expected = {f"{case}/chunk_0": needles for case, _, needles in CASES}
    return out, assert_only_these_units_failed(result, str(out), "adt", expected)


@pytest.mark.parametrize(
    "case, needles", [(case, needles) for case, _, needles in CASES], ids=[c[0] for c in CASES]
)
def test_a_bad_sequence_fails_alone_with_its_error(bad_run, case, needles):
    _, errors = bad_run
    assert_case_error(errors, f"{case}/chunk_0", needles)


def test_a_missing_pose_names_the_object(bad_run):
    _, errors = bad_run
    assert f"object {centre_object()} has no pose at t=" in errors["no_pose/chunk_0"]


def test_only_the_good_sequence_writes_a_clip(bad_run):
    out, _ = bad_run
    # Its v1 name drops the serial suffix M1292.
    assert sorted(os.listdir(out / "adt")) == ["good_0.npz"]
    assert sorted(os.listdir(out / "audit" / "adt")) == ["good_0.parquet"]
