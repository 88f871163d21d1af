"""The Waymo v2 reader: both transform encodings, and clear errors for bad files."""

import os

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from pipeline.core.errors import InputError
from pipeline.drivetrack import columns as C
from pipeline.drivetrack.annotate import unit_camera
from pipeline.drivetrack.reader import SegmentReader, list_segments, transforms_from_column
from pipeline.drivetrack.sample.waymo_world import SEGMENT, camera_to_vehicle
from tests.support.units import drivetrack_input


@pytest.mark.parametrize(
    "kind", [pa.list_(pa.float32(), 16), pa.list_(pa.float64()), pa.list_(pa.float64(), 16)]
)
def test_transform_encodings_are_row_major(kind):
    matrix = np.arange(16, dtype=np.float64).reshape(4, 4)
    column = pa.array([matrix.ravel().tolist(), (matrix + 1).ravel().tolist()], kind)
    np.testing.assert_array_equal(transforms_from_column(column, "test"), [matrix, matrix + 1])


def test_transform_of_wrong_length_or_type_is_refused():
    with pytest.raises(InputError, match="15 values"):
        transforms_from_column(pa.array([[0.0] * 15], pa.list_(pa.float64())), "x")
    with pytest.raises(InputError, match="expected a list"):
        transforms_from_column(pa.array(["not a matrix"]), "x")


def test_reads_the_sample_segment(sample_split):
    reader = SegmentReader(sample_split[0], SEGMENT)
    assert list_segments(sample_split[0]) == [SEGMENT]
    calibration = reader.camera_calibration(1)
    # Stored as fixed_size_list<float>[16]: float32 rounding only.
    np.testing.assert_allclose(calibration.camera_to_vehicle, camera_to_vehicle(1), atol=1e-6)
    assert (calibration.width, calibration.height) == (480, 320)
    frames = reader.camera_frames(2)
    assert len(frames.jpegs) == 40
    assert (np.diff(frames.timestamps) == 100_000).all()
    boxes = reader.box_labels()
    assert set(boxes.object_ids)
    assert boxes.lidar_boxes.shape[1] == 7
    lidar = next(reader.top_lidar_frames([int(frames.timestamps[0])]))
    assert lidar.range_image.shape == (64, 900)
    assert lidar.pixel_pose.shape == (64, 900, 6)


def test_missing_file_and_column_and_truncation_are_named(split_copy):
    os.remove(os.path.join(split_copy, "lidar", f"{SEGMENT}.parquet"))
    reader = SegmentReader(split_copy, SEGMENT)
    with pytest.raises(InputError, match=f"missing component file lidar/{SEGMENT}.parquet"):
        next(reader.top_lidar_frames([0]))
    path = os.path.join(split_copy, "vehicle_pose", f"{SEGMENT}.parquet")
    table = pq.read_table(path).rename_columns(
        ["key.segment_context_name", "key.frame_timestamp_micros", "pose"]
    )
    pq.write_table(table, path)
    with pytest.raises(InputError, match=r"vehicle_pose/.*missing column.*world_from_vehicle"):
        reader.vehicle_poses()
    path = os.path.join(split_copy, "lidar_box", f"{SEGMENT}.parquet")
    with open(path, "r+b") as handle:
        handle.truncate(os.path.getsize(path) // 2)
    with pytest.raises(InputError, match=r"lidar_box/.*unreadable Parquet"):
        reader.box_labels()


def test_empty_split_folder_is_explained(tmp_path):
    (tmp_path / "camera_image").mkdir()
    with pytest.raises(InputError, match="no segments"):
        list_segments(str(tmp_path))


def test_rolling_shutter_columns_are_read_where_present(split_copy):
    path = os.path.join(split_copy, C.CAMERA_IMAGE, f"{SEGMENT}.parquet")
    table = pq.read_table(path)
    reader = SegmentReader(split_copy, SEGMENT)
    assert reader.camera_calibration(2).rolling_shutter_direction == 2
    motion = reader.camera_frames(2).motion
    readout = motion.readout_done - motion.trigger - motion.shutter
    np.testing.assert_allclose(readout, 0.030, atol=1e-6)
    assert motion.linear_velocity.shape == (40, 3)
    assert (motion.angular_velocity[:, 2] > 0).all()
    # A null cell: that frame has no record (global shutter there); the others keep theirs.
    trigger = C.IMAGE_SHUTTER[1]
    values = table.column(trigger).to_pylist()
    values[0] = None
    index = table.schema.get_field_index(trigger)
    pq.write_table(table.set_column(index, trigger, pa.array(values, pa.float64())), path)
    frames = SegmentReader(split_copy, SEGMENT).camera_frames(table.column(C.CAMERA_NAME)[0].as_py())
    assert np.isnan(frames.motion.trigger[0])
    assert np.isfinite(frames.motion.trigger[1:]).all()
    # A column missing: no rolling shutter at all.
    pq.write_table(table.drop_columns([trigger]), path)
    assert SegmentReader(split_copy, SEGMENT).camera_frames(2).motion is None


def test_bad_rolling_shutter_values_are_named(split_copy):
    path = os.path.join(split_copy, C.CAMERA_IMAGE, f"{SEGMENT}.parquet")
    table = pq.read_table(path)
    done = C.IMAGE_SHUTTER[2]
    index = table.schema.get_field_index(done)
    early = np.asarray(table.column(done)) - 1.0  # readout done before the trigger
    pq.write_table(table.set_column(index, done, pa.array(early)), path)
    stamp = int(np.asarray(table.column(C.TIMESTAMP))[0])
    camera = table.column(C.CAMERA_NAME)[0].as_py()
    with pytest.raises(
        InputError, match=rf"camera_image/{SEGMENT} camera {camera} frame {stamp}: rolling shutter"
    ):
        unit_camera(drivetrack_input(split_copy, SEGMENT, camera))
    nan = np.asarray(table.column(done)).copy()
    nan[3] = np.nan
    pq.write_table(table.set_column(index, done, pa.array(nan)), path)
    with pytest.raises(
        InputError, match=rf"camera_image/{SEGMENT} camera \d: column .*readout_done_time holds NaN"
    ):
        SegmentReader(split_copy, SEGMENT).camera_frames(int(table.column(C.CAMERA_NAME)[3].as_py()))
