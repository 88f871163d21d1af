"""Waymo input integrity: one row per key in every component, and key columns of the right type.

The table-driven cases (tests/drivetrack/test_bad_input.py) run them through the pipeline; these
check, on the reader, what a table of cases cannot show cheaply: exact copies in every component
give the clean segment's clips byte for byte, a repeat is found wherever it lies in a lidar file,
and "exact" means equal bits.
"""

from __future__ import annotations

import os

import numpy as np
import pyarrow as pa
import pytest

from pipeline.core.errors import InputError
from pipeline.drivetrack import columns as C
from pipeline.drivetrack.reader import SegmentReader
from pipeline.drivetrack.sample.waymo_world import SEGMENT, timestamp
from tests.drivetrack.test_bad_input import LEAD_CAR, T, as_strings, repeat_row, retyped, set_cells
from tests.support.cli import clip_bytes, run_in_process


def change(split: str, component: str, edit) -> None:
    edit(os.path.join(split, component, f"{SEGMENT}.parquet"))


def test_exact_copies_give_the_clean_clips_byte_for_byte(split_copy, reference_run, tmp_path):
    copies = {
        C.CAMERA_IMAGE: {"camera": 1, "frame": T},
        C.CAMERA_CALIBRATION: {"camera": 1},
        C.LIDAR: {"laser": 1, "frame": T},
        C.LIDAR_POSE: {"laser": 1, "frame": T},
        C.LIDAR_CAMERA_PROJECTION: {"laser": 1, "frame": T},
        C.LIDAR_CALIBRATION: {"laser": 1},
        C.LIDAR_BOX: {"object": LEAD_CAR, "frame": T},
        C.LIDAR_CAMERA_SYNCED_BOX: {"object": LEAD_CAR, "frame": T},
        C.VEHICLE_POSE: {"frame": T},
    }
    assert set(copies) == set(C.COMPONENTS)
    for component, keys in copies.items():
        change(split_copy, component, repeat_row(**keys))
    out = str(tmp_path / "out")
    # Camera 1 reads every component (camera 2 has no vehicle, so it never reads the lidar).
    only_camera_1 = ("--set", "drivetrack.cameras=1")
    result = run_in_process("drivetrack", "--input", split_copy, "--output", out, *only_camera_1)
    assert result.returncode == 0, result.stderr[-3000:]
    camera_1 = f"tapvid3d_{SEGMENT}_1_"
    reference = clip_bytes(reference_run("drivetrack"), "drivetrack")
    clean = {name: data for name, data in reference.items() if name.startswith(camera_1)}
    assert clean
    assert clip_bytes(out, "drivetrack") == clean


@pytest.mark.parametrize(
    "component, values",
    [
        (C.LIDAR, C.LIDAR_RANGE_VALUES),
        (C.LIDAR_POSE, C.LIDAR_POSE_VALUES),
        (C.LIDAR_CAMERA_PROJECTION, C.PROJECTION_VALUES),
    ],
)
def test_a_lidar_repeat_after_the_asked_frames_is_found(split_copy, component, values):
    # The repeat of frame 0 is the file's last row: streaming alone would stop at the first row.
    first = timestamp(0)
    plus_one = {values: lambda cells: [v + 1 for v in cells]}
    change(split_copy, component, repeat_row(plus_one, laser=1, frame=first))
    reader = SegmentReader(split_copy, SEGMENT)
    assert next(reader.top_lidar_frames([T])).timestamp == T  # only the frames asked for are checked
    with pytest.raises(InputError) as error:
        next(reader.top_lidar_frames([first]))
    assert str(error.value) == (
        f"{component}/{SEGMENT}.parquet: laser 1 at timestamp {first} appears in 2 rows with different "
        f"values ({values} differs)"
    )


def test_a_copy_is_exact_in_bits(split_copy):
    frame = timestamp(3)
    nan = {C.WORLD_FROM_VEHICLE: lambda _: [np.nan] * 16}
    change(split_copy, C.VEHICLE_POSE, set_cells(nan, frame=frame))
    change(split_copy, C.VEHICLE_POSE, repeat_row(frame=frame))
    poses = SegmentReader(split_copy, SEGMENT).vehicle_poses()  # NaN equals NaN: an exact copy
    assert len(poses) == 40
    assert np.isnan(poses[frame]).all()
    negative_zero = lambda m: [-0.0 if i == 12 else v for i, v in enumerate(m)]  # noqa: E731
    change(split_copy, C.VEHICLE_POSE, repeat_row({C.WORLD_FROM_VEHICLE: negative_zero}, frame=T))
    with pytest.raises(InputError, match=f"vehicle_pose/{SEGMENT}.parquet: timestamp {T} appears in 2 rows"):
        SegmentReader(split_copy, SEGMENT).vehicle_poses()


def test_every_row_of_a_repeated_key_is_counted(split_copy):
    change(split_copy, C.LIDAR_BOX, repeat_row(object=LEAD_CAR, frame=T))
    change(split_copy, C.LIDAR_BOX, repeat_row({C.BOX_TYPE: lambda kind: kind + 1}, object=LEAD_CAR, frame=T))
    with pytest.raises(InputError) as error:
        SegmentReader(split_copy, SEGMENT).box_labels()
    assert str(error.value) == (
        f"lidar_box/{SEGMENT}.parquet: object '{LEAD_CAR}' at timestamp {T} appears in 3 rows with "
        f"different values ({C.BOX_TYPE} differs)"
    )


@pytest.mark.parametrize(
    "component, column, kind, read",
    [
        (C.LIDAR, C.LASER_NAME, pa.string(), lambda reader: next(reader.top_lidar_frames([T]))),
        (C.LIDAR_CALIBRATION, C.LASER_NAME, pa.float64(), lambda reader: reader.lidar_calibration()),
        (C.CAMERA_CALIBRATION, C.CAMERA_NAME, pa.string(), lambda reader: reader.camera_calibration(1)),
        (C.LIDAR_CAMERA_SYNCED_BOX, C.TIMESTAMP, pa.string(), lambda reader: reader.box_labels()),
    ],
)
def test_a_key_column_of_the_wrong_type_is_named(split_copy, component, column, kind, read):
    change(split_copy, component, as_strings(column) if kind == pa.string() else retyped(column, kind))
    with pytest.raises(InputError) as error:
        read(SegmentReader(split_copy, SEGMENT))
    label = f"{component}/{SEGMENT}.parquet"
    assert str(error.value) == f"{label}: column {column} has type {kind}, expected an integer"


def test_a_null_key_is_named(split_copy):
    change(split_copy, C.LIDAR_BOX, set_cells({C.OBJECT_ID: lambda _: None}, object=LEAD_CAR, frame=T))
    with pytest.raises(InputError) as error:
        SegmentReader(split_copy, SEGMENT).box_labels()
    assert str(error.value) == f"lidar_box/{SEGMENT}.parquet: column {C.OBJECT_ID} has 1 null value(s)"
