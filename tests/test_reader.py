"""The Waymo v2 reader: both transform encodings, and clear errors for bad files."""

import os

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from pipeline.core.errors import InputError
from pipeline.drivetrack.reader import SegmentReader, list_segments, transforms_from_column
from pipeline.samples.waymo_world import SEGMENT, camera_to_vehicle


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
    assert len(frames.jpegs) == 40 and (np.diff(frames.timestamps) == 100_000).all()
    boxes = reader.box_labels()
    assert set(boxes.object_ids) and boxes.lidar_boxes.shape[1] == 7
    lidar = next(reader.top_lidar_frames([int(frames.timestamps[0])]))
    assert lidar.range_image.shape == (64, 900) and lidar.pixel_pose.shape == (64, 900, 6)


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
