"""DriveTrack on bad input: each bad segment fails its own units, and only those, with a clear InputError.

One pipeline run over the good sample segment and one copy of it per case (segment S =
``bad_<case>``), each with one defect. T is frame 5's timestamp, F another frame's; the lead car
is a vehicle assigned to camera 1. "fails" lists the cameras whose units must fail: camera 2 has
no vehicle, so it never reads the lidar, and lidar defects fail cameras 1 and 3 only.

| case | how it is made | expected error | fails |
|---|---|---|---|
| truncated | vehicle_pose file cut in half | vehicle_pose/S.parquet: unreadable Parquet (...) | all |
| string_column | lidar_box center.x as strings | lidar_box/S: column ...box.center.x has type string | all |
| no_column | camera_calibration minus width | camera_calibration/S.parquet: missing column(s) [...] | all |
| no_lidar | lidar file deleted | missing component file lidar/S.parquet | all |
| no_calibration | camera_calibration deleted | missing component file camera_calibration/S.parquet | all |
| nan_pose | vehicle_pose of frame 3: NaN | vehicle_pose/S frame F: world_from_vehicle contains NaN | all |
| singular | camera 1 extrinsic: R = 0 | camera_calibration/S camera 1: extrinsic ... not orthonormal | 1 |
| zero_boxes | both box files: 0 rows | lidar_box/S.parquet: no 3D boxes (0 rows); ... | all |
| empty_range | TOP range image at T: [0, 0, 4] | lidar/S TOP frame T: empty range image | 1, 3 |
| no_returns | TOP range image at T: all -1 | lidar/S TOP frame T: no returns (every range <= 0) | 1, 3 |
| beam_count | 63 TOP beam inclinations | lidar/S TOP frame F: lidar_calibration holds 63 beam ... | 1, 3 |
| corrupt_jpeg | camera 1 JPEG at T cut in half | camera_image/S camera 1 frame T: corrupt JPEG (...) | 1 |
| nan_box | lead car box at T: NaN | lidar_box/S object <id> frame T: NaN or infinity in the box | 1 |
| camera_gap | camera 1 frame 10 deleted | camera_image/S camera 1: no image for frame F (1 of 40 ...) | 1 |
| shifted_time | camera 1 timestamps + 1 us | camera_image/S camera 1 frame F: no vehicle_pose row ... | 1 |
| dup_box | lead car box at T repeated, x + 1 | lidar_box/S.parquet: object '<id>' at timestamp T 2x | all |
| dup_box_same | lead car box at T repeated as is | none: the copy is dropped (checked below) | none |
| dup_synced | lead car synced box at T repeated | lidar_camera_synced_box/S.parquet: object ... 2x | all |
| dup_pose | vehicle_pose of frame 3 repeated, moved | vehicle_pose/S.parquet: timestamp F 2x | all |
| dup_lidar | TOP range image at T repeated, + 1 m | lidar/S.parquet: laser 1 at timestamp T 2x | 1, 3 |
| dup_image | camera 1 JPEG at T repeated, cut | camera_image/S.parquet: camera 1 at timestamp T 2x | 1 |
| dup_calibration | camera 1 calibration repeated, f_u + 1 | camera_calibration/S.parquet: camera 1 2x | 1 |
| string_camera | key.camera_name as strings | camera_image/S.parquet: column ... type string | all |
| int_object | lidar_box key.laser_object_id as int64 | lidar_box/S.parquet: column ... type int64 | all |
| float_time | vehicle_pose timestamps as doubles | vehicle_pose/S.parquet: column ... type double | all |

2x: "appears in 2 rows with different values (<column> differs)". A key column of the wrong type
gives "column <name> has type <type>, expected an integer" (object ids: "a string").

The copies are byte copies of the sample's files (their ``key.segment_context_name`` still names
the sample; the pipeline takes a segment's name from its file names), which keeps this test fast.
"""

from __future__ import annotations

import dataclasses
import os
import shutil
from collections.abc import Callable

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest

from pipeline.drivetrack import columns as C
from pipeline.drivetrack.reader import SegmentReader
from pipeline.drivetrack.sample.waymo_world import SEGMENT, timestamp
from tests.support.bad_input import assert_case_error, assert_only_these_units_failed, failures_by_unit
from tests.support.cli import run_in_process

T = timestamp(5)
LEAD_CAR = "lead_car_AAAAAAAAAAAAAAAAAAAAAA"
GOOD_CLIPS = 4
KEYS = {"camera": C.CAMERA_NAME, "laser": C.LASER_NAME, "frame": C.TIMESTAMP, "object": C.OBJECT_ID}


def _rows(table: pa.Table, **keys) -> np.ndarray:
    """[R] True on the rows whose key columns (camera, laser, frame, object) hold the given values."""
    rows = np.ones(table.num_rows, bool)
    for key, value in keys.items():
        rows &= np.asarray(table.column(KEYS[key]).to_pylist()) == value
    return rows


def rewrite(edit: Callable[[pa.Table], pa.Table]) -> Callable[[str], None]:
    """A change rewriting a Parquet file with ``edit`` applied to its table."""

    def change(path: str) -> None:
        pq.write_table(edit(pq.read_table(path)), path)

    return change


def _edited_row(table: pa.Table, row: int, values: dict[str, Callable]) -> pa.Table:
    """Row ``row`` of ``table`` as a table, each column of ``values`` set to ``values[column](old cell)``."""
    cell = table.slice(row, 1)
    for column, value in values.items():
        new = pa.array([value(cell.column(column)[0].as_py())], table.schema.field(column).type)
        cell = cell.set_column(table.schema.get_field_index(column), column, new)
    return cell


def set_cells(values: dict[str, Callable], **keys) -> Callable[[str], None]:
    """A change setting each column of ``values`` to ``values[column](old cell)`` on the rows matching
    ``keys``; the other rows are kept as they are (cheap on the large range-image columns)."""

    def edit(table: pa.Table) -> pa.Table:
        pieces, start = [], 0
        for row in np.nonzero(_rows(table, **keys))[0]:
            pieces += [table.slice(start, row - start), _edited_row(table, row, values)]
            start = row + 1
        return pa.concat_tables([*pieces, table.slice(start)])

    return rewrite(edit)


def repeat_row(values: dict[str, Callable] | None = None, **keys) -> Callable[[str], None]:
    """A change appending another row for the first row matching ``keys``: a copy of it with each
    column of ``values`` set to ``values[column](old cell)`` (an exact copy without ``values``)."""

    def edit(table: pa.Table) -> pa.Table:
        row = np.nonzero(_rows(table, **keys))[0][0]
        return pa.concat_tables([table, _edited_row(table, row, values or {})])

    return rewrite(edit)


def as_strings(column: str) -> Callable[[str], None]:
    def edit(table: pa.Table) -> pa.Table:
        cells = pa.array([str(v) for v in table.column(column).to_pylist()])
        return table.set_column(table.schema.get_field_index(column), column, cells)

    return rewrite(edit)


def retyped(column: str, kind: pa.DataType) -> Callable[[str], None]:
    """A change storing a key column as ``kind``: integers as doubles, object ids as their index."""

    def edit(table: pa.Table) -> pa.Table:
        cells = table.column(column).combine_chunks()
        cells = pc.dictionary_encode(cells).indices if pa.types.is_string(cells.type) else cells
        return table.set_column(table.schema.get_field_index(column), column, cells.cast(kind))

    return rewrite(edit)


def moved(matrix: list[float]) -> list[float]:
    """A row-major 4x4 transform moved 0.5 m along x."""
    return [v + 0.5 if i == 3 else v for i, v in enumerate(matrix)]


def truncate(path: str) -> None:
    with open(path, "r+b") as handle:
        handle.truncate(os.path.getsize(path) // 2)


def zero_rotation(matrix: list[float]) -> list[float]:
    return [0.0 if i < 12 and i % 4 < 3 else v for i, v in enumerate(matrix)]


@dataclasses.dataclass(frozen=True)
class Case:
    name: str
    components: tuple[str, ...]
    change: Callable[[str], None]  # applied to each component file of the case's segment
    cameras: tuple[int, ...]  # the units that must fail
    expected: tuple[str, ...]  # substrings of their error, "{seg}" standing for the segment

    @property
    def segment(self) -> str:
        return f"bad_{self.name}"


CASES = [
    Case(
        "truncated",
        (C.VEHICLE_POSE,),
        truncate,
        (1, 2, 3),
        ("vehicle_pose/{seg}.parquet: unreadable Parquet",),
    ),
    Case(
        "string_column",
        (C.LIDAR_BOX,),
        as_strings(C.BOX_FIELDS[0]),
        (1, 2, 3),
        (f"lidar_box/{{seg}}: column {C.BOX_FIELDS[0]} has type string, expected numbers",),
    ),
    Case(
        "no_column",
        (C.CAMERA_CALIBRATION,),
        rewrite(lambda table: table.drop_columns([C.CAM_WIDTH])),
        (1, 2, 3),
        ("camera_calibration/{seg}.parquet: missing column(s)", C.CAM_WIDTH),
    ),
    Case(
        "no_lidar",
        (C.LIDAR,),
        os.remove,
        (1, 2, 3),
        ("missing component file lidar/{seg}.parquet",),
    ),
    Case(
        "no_calibration",
        (C.CAMERA_CALIBRATION,),
        os.remove,
        (1, 2, 3),
        ("missing component file camera_calibration/{seg}.parquet",),
    ),
    Case(
        "nan_pose",
        (C.VEHICLE_POSE,),
        set_cells({C.WORLD_FROM_VEHICLE: lambda _: [np.nan] * 16}, frame=timestamp(3)),
        (1, 2, 3),
        (f"vehicle_pose/{{seg}} frame {timestamp(3)}: world_from_vehicle contains NaN",),
    ),
    Case(
        "singular",
        (C.CAMERA_CALIBRATION,),
        set_cells({C.CAM_EXTRINSIC: zero_rotation}, camera=1),
        (1,),
        ("camera_calibration/{seg} camera 1: extrinsic rotation part is not orthonormal",),
    ),
    Case(
        "zero_boxes",
        (C.LIDAR_BOX, C.LIDAR_CAMERA_SYNCED_BOX),
        rewrite(lambda table: table.slice(0, 0)),
        (1, 2, 3),
        ("lidar_box/{seg}.parquet: no 3D boxes (0 rows)",),
    ),
    Case(
        "empty_range",
        (C.LIDAR,),
        set_cells(
            {C.LIDAR_RANGE_VALUES: lambda _: [], C.LIDAR_RANGE_SHAPE: lambda _: [0, 0, 4]}, laser=1, frame=T
        ),
        (1, 3),
        (f"lidar/{{seg}} TOP frame {T}: empty range image",),
    ),
    Case(
        "no_returns",
        (C.LIDAR,),
        set_cells({C.LIDAR_RANGE_VALUES: lambda values: [-1.0] * len(values)}, laser=1, frame=T),
        (1, 3),
        (f"lidar/{{seg}} TOP frame {T}: no returns (every range <= 0)",),
    ),
    Case(
        "beam_count",
        (C.LIDAR_CALIBRATION,),
        set_cells({C.BEAM_INCLINATION_VALUES: lambda values: values[:-1]}, laser=1),
        (1, 3),
        (
            "lidar/{seg} TOP frame",
            "lidar_calibration holds 63 beam inclinations for a range image of 64 rows",
        ),
    ),
    Case(
        "corrupt_jpeg",
        (C.CAMERA_IMAGE,),
        set_cells({C.IMAGE_JPEG: lambda jpeg: jpeg[: len(jpeg) // 2]}, camera=1, frame=T),
        (1,),
        (f"camera_image/{{seg}} camera 1 frame {T}: corrupt JPEG",),
    ),
    Case(
        "nan_box",
        (C.LIDAR_BOX,),
        set_cells({C.BOX_FIELDS[0]: lambda _: np.nan}, object=LEAD_CAR, frame=T),
        (1,),
        (f"lidar_box/{{seg}} object {LEAD_CAR} frame {T}: NaN or infinity in the box",),
    ),
    Case(
        "camera_gap",
        (C.CAMERA_IMAGE,),
        rewrite(lambda table: table.filter(pa.array(~_rows(table, camera=1, frame=timestamp(10))))),
        (1,),
        (f"camera_image/{{seg}} camera 1: no image for frame {timestamp(10)} (1 of 40 frames)",),
    ),
    Case(
        "shifted_time",
        (C.CAMERA_IMAGE,),
        set_cells({C.TIMESTAMP: lambda stamp: stamp + 1}, camera=1),
        (1,),
        (f"camera_image/{{seg}} camera 1 frame {timestamp(0) + 1}: no vehicle_pose row at this timestamp",),
    ),
    Case(
        "dup_box",
        (C.LIDAR_BOX,),
        repeat_row({C.BOX_FIELDS[0]: lambda x: x + 1.0}, object=LEAD_CAR, frame=T),
        (1, 2, 3),
        (
            f"lidar_box/{{seg}}.parquet: object '{LEAD_CAR}' at timestamp {T} appears in 2 rows with "
            f"different values ({C.BOX_FIELDS[0]} differs)",
        ),
    ),
    Case("dup_box_same", (C.LIDAR_BOX,), repeat_row(object=LEAD_CAR, frame=T), (), ()),
    Case(
        "dup_synced",
        (C.LIDAR_CAMERA_SYNCED_BOX,),
        repeat_row({C.SYNCED_BOX_FIELDS[0]: lambda x: x + 1.0}, object=LEAD_CAR, frame=T),
        (1, 2, 3),
        (
            f"lidar_camera_synced_box/{{seg}}.parquet: object '{LEAD_CAR}' at timestamp {T} appears in 2 "
            "rows with different values",
        ),
    ),
    Case(
        "dup_pose",
        (C.VEHICLE_POSE,),
        repeat_row({C.WORLD_FROM_VEHICLE: moved}, frame=timestamp(3)),
        (1, 2, 3),
        (
            f"vehicle_pose/{{seg}}.parquet: timestamp {timestamp(3)} appears in 2 rows with different "
            f"values ({C.WORLD_FROM_VEHICLE} differs)",
        ),
    ),
    Case(
        "dup_lidar",
        (C.LIDAR,),
        repeat_row({C.LIDAR_RANGE_VALUES: lambda values: [v + 1.0 for v in values]}, laser=1, frame=T),
        (1, 3),
        (
            f"lidar/{{seg}}.parquet: laser 1 at timestamp {T} appears in 2 rows with different values "
            f"({C.LIDAR_RANGE_VALUES} differs)",
        ),
    ),
    Case(
        "dup_image",
        (C.CAMERA_IMAGE,),
        repeat_row({C.IMAGE_JPEG: lambda jpeg: jpeg[: len(jpeg) // 2]}, camera=1, frame=T),
        (1,),
        (f"camera_image/{{seg}}.parquet: camera 1 at timestamp {T} appears in 2 rows with different values",),
    ),
    Case(
        "dup_calibration",
        (C.CAMERA_CALIBRATION,),
        repeat_row({C.CAM_INTRINSICS[0]: lambda f: f + 1.0}, camera=1),
        (1,),
        ("camera_calibration/{seg}.parquet: camera 1 appears in 2 rows with different values",),
    ),
    Case(
        "string_camera",
        (C.CAMERA_IMAGE,),
        as_strings(C.CAMERA_NAME),
        (1, 2, 3),
        (f"camera_image/{{seg}}.parquet: column {C.CAMERA_NAME} has type string, expected an integer",),
    ),
    Case(
        "int_object",
        (C.LIDAR_BOX,),
        retyped(C.OBJECT_ID, pa.int64()),
        (1, 2, 3),
        (f"lidar_box/{{seg}}.parquet: column {C.OBJECT_ID} has type int64, expected a string",),
    ),
    Case(
        "float_time",
        (C.VEHICLE_POSE,),
        retyped(C.TIMESTAMP, pa.float64()),
        (1, 2, 3),
        (f"vehicle_pose/{{seg}}.parquet: column {C.TIMESTAMP} has type double, expected an integer",),
    ),
]


@pytest.fixture(scope="module")
def bad_run(sample_split, tmp_path_factory):
    """(split folder, output folder, completed process) of one run over the good segment and every case."""
    split = str(tmp_path_factory.mktemp("bad_drivetrack") / "split")
    shutil.copytree(sample_split[0], split)
    for case in CASES:
        for component in C.COMPONENTS:
            shutil.copyfile(
                os.path.join(split, component, f"{SEGMENT}.parquet"),
                os.path.join(split, component, f"{case.segment}.parquet"),
            )
        for component in case.components:
            case.change(os.path.join(split, component, f"{case.segment}.parquet"))
    out = split + "_out"
    return split, out, run_in_process("drivetrack", "--input", split, "--output", out)


def expected_failures() -> dict[str, list[str]]:
    """Failing unit -> substrings of its error, every case's."""
    return {
        f"{case.segment}/camera_{camera}": [needle.format(seg=case.segment) for needle in case.expected]
        for case in CASES
        for camera in case.cameras
    }


def test_only_the_cases_units_fail_and_every_clip_validates(bad_run):
    _, out, result = bad_run
    assert_only_these_units_failed(result, out, "drivetrack", expected_failures())
    assert "failure(s): see" in result.stderr


@pytest.mark.parametrize("case", CASES, ids=lambda case: case.name)
def test_a_case_fails_its_units_with_a_clear_error(bad_run, case):
    _, out, _ = bad_run
    errors, expected = failures_by_unit(out, "drivetrack"), expected_failures()
    for camera in case.cameras:
        unit = f"{case.segment}/camera_{camera}"
        assert_case_error(errors, unit, expected[unit])


def test_good_units_write_all_their_clips(bad_run):
    _, out, _ = bad_run
    names = os.listdir(os.path.join(out, "drivetrack"))

    def clips(segment: str, camera: int) -> int:
        return sum(name.startswith(f"tapvid3d_{segment}_{camera}_") for name in names)

    good = {camera: clips(SEGMENT, camera) for camera in (1, 2, 3)}
    assert sum(good.values()) == GOOD_CLIPS
    for case in CASES:
        written = {camera: clips(case.segment, camera) for camera in (1, 2, 3)}
        assert written == {c: 0 if c in case.cameras else good[c] for c in (1, 2, 3)}, case.name


def test_an_exact_copy_of_a_row_is_dropped(bad_run):
    """dup_box_same reads as the clean segment, bit for bit (its units wrote all their clips, above);
    a clip's bytes also depend on the segment's name, which seeds the query sampling, so clip files
    are compared with the clean segment's in tests/drivetrack/test_integrity.py, under one name."""
    split, _, _ = bad_run
    clean, copied = (SegmentReader(split, segment).box_labels() for segment in (SEGMENT, "bad_dup_box_same"))
    for field in dataclasses.fields(clean):
        a, b = getattr(clean, field.name), getattr(copied, field.name)
        same = a.tolist() == b.tolist() if a.dtype == object else a.tobytes() == b.tobytes()
        assert a.dtype == b.dtype, field.name
        assert a.shape == b.shape, field.name
        assert same, field.name
