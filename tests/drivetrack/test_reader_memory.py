"""Reading ``camera_image`` holds at most one row group's JPEG column beside the unit's own JPEGs,
whatever the file's row-group layout: measured in a fresh process (pyarrow's pool peak and the
traced Python peak) on a file of random "JPEGs" of known size, five cameras, three of them read.

Decoding a row group is pyarrow's: the column it decodes (in its pool, with a few MiB of its own
buffers) from the pages it reads through the Python stream (traced: Python bytes). Anything of ours
that copied the column (a filter, a concatenation, a conversion of every row) would add a group's
or the file's JPEGs to one peak or the other."""

import json
import os
import subprocess
import sys

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from pipeline.drivetrack import columns as C

SEGMENT = "memory_segment"
FRAMES, CAMERAS, READ = 24, 5, [1, 2, 3]
JPEG_BYTES = 512 * 1024
MIB = 1 << 20
# What pyarrow's reader holds beside the column it decodes (measured: 5-11 MiB).
READER_BUFFERS = 16 * MIB

MEASURE = """
import json, sys, tracemalloc
import pyarrow as pa
from pipeline.drivetrack.reader import SegmentReader
tracemalloc.start()
frames = SegmentReader(sys.argv[1], sys.argv[2]).cameras_frames(json.loads(sys.argv[3]))
_, python_peak = tracemalloc.get_traced_memory()
print(json.dumps({
    "arrow_peak": pa.default_memory_pool().max_memory(),
    "python_peak": python_peak,
    "frames": [len(f.jpegs) for f in frames],
    "first": [f.jpegs[0][:8].hex() for f in frames],
}))
"""


def _write(folder: str, row_group_rows: int) -> None:
    """A camera_image file: FRAMES x CAMERAS rows, each a random JPEG_BYTES payload whose first 8
    bytes name its camera and frame, in row groups of ``row_group_rows``."""
    rng = np.random.default_rng(0)
    rows = [(t, c) for t in range(FRAMES) for c in range(1, CAMERAS + 1)]
    payloads = []
    for t, c in rows:
        body = rng.bytes(JPEG_BYTES)
        payloads.append(bytes([c, t]) + b"jpeg.." + body[8:])
    identity = np.eye(4).ravel().tolist()
    table = pa.table(
        {
            C.SEGMENT: pa.array([SEGMENT] * len(rows)),
            C.TIMESTAMP: pa.array([1000 * (t + 1) for t, _ in rows], pa.int64()),
            C.CAMERA_NAME: pa.array([c for _, c in rows], pa.int8()),
            C.IMAGE_JPEG: pa.array(payloads, pa.binary()),
            C.IMAGE_POSE: pa.array([identity] * len(rows), pa.list_(pa.float64(), 16)),
        }
    )
    os.makedirs(os.path.join(folder, C.CAMERA_IMAGE))
    path = os.path.join(folder, C.CAMERA_IMAGE, f"{SEGMENT}.parquet")
    pq.write_table(table, path, row_group_size=row_group_rows, compression="none")


@pytest.mark.parametrize("row_group_rows", [FRAMES * CAMERAS, 10], ids=["one_row_group", "many_row_groups"])
def test_camera_image_is_read_with_one_copy_of_a_row_group(tmp_path, row_group_rows):
    _write(str(tmp_path), row_group_rows)
    done = subprocess.run(
        [sys.executable, "-c", MEASURE, str(tmp_path), SEGMENT, json.dumps(READ)],
        capture_output=True,
        text=True,
        check=True,
    )
    found = json.loads(done.stdout)
    assert found["frames"] == [FRAMES] * len(READ)
    assert found["first"] == [bytes([c, 0]).hex() + b"jpeg..".hex() for c in READ]
    group_jpegs = min(row_group_rows, FRAMES * CAMERAS) * JPEG_BYTES
    kept_jpegs = FRAMES * len(READ) * JPEG_BYTES
    # One decoded row group (its JPEG column and a few numbers a row), with pyarrow's buffers.
    assert found["arrow_peak"] <= 1.05 * group_jpegs + READER_BUFFERS, found
    # The JPEGs of the cameras read, once, as Python bytes, and one group's pages as read.
    assert found["python_peak"] <= 1.05 * (kept_jpegs + group_jpegs) + 4 * MIB, found
