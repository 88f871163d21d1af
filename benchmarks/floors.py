"""The read+decode floor of one unit: the bare cost of reading and decoding the unit's inputs,
nothing else (no checks, no annotation, no output), measured in a benchmark worker process
(``python -m benchmarks.worker`` with ``spec["mode"] == "floor"``: fresh, single-threaded, bound
to one CPU like the unit's own processes). The report divides the unit's time by it (CPU times
of these single-threaded pinned processes: their wall times on an idle machine).

drivetrack (a group: the segment's cameras): the columns the units read of every component file
  of the segment, streamed with pyarrow 8 rows at a time as the reader does; the group cameras'
  JPEGs decoded to BGR (``cv2.imdecode``, as the undistortion does); the TOP lidar's range images
  of ``lidar``, ``lidar_pose`` and ``lidar_camera_projection`` turned into arrays [H, W, C], once.
pstudio (a group: cameras of one sequence): ``train_meta.json``; the five members of
  ``params.npz`` the reader reads (``np.load``), once; the group cameras' JPEGs and every camera's
  mask PNG at every frame (the multi-view mask statistic reads them all), each decoded once,
  grey-level, as the reader decodes them.
adt: opening the sequence with projectaria-tools (``AriaDigitalTwinDataProvider``, once, cold)
  and its frame timestamps, then the chunk's RGB, depth and segmentation frames read from the
  VRS files ``repeat`` times, as the unit's runs read them, then closing it; the report
  extrapolates it to a 300-frame unit like the unit itself (its share of a group's opening and
  closing + 300 x per-frame read).

Each returns floor_s / floor_cpu_s (the whole floor at the measured size) and floor_frames;
adt also floor_open_s / floor_open_cpu_s (the opening and closing, inside floor_s) and
floor_open_share (a unit's share of it: a group of chunks opens and closes the sequence once).
"""

from __future__ import annotations

import json
import os
import time

import numpy as np


def _timed(function, *args) -> tuple[float, float]:
    wall, cpu = time.perf_counter(), time.process_time()
    function(*args)
    return time.perf_counter() - wall, time.process_time() - cpu


def drivetrack(spec: dict) -> dict:
    import cv2
    import pyarrow as pa
    import pyarrow.compute as pc
    import pyarrow.parquet as pq

    from pipeline.drivetrack import columns as C

    (segment,), cameras = {s for s, _ in spec["unit"]}, [c for _, c in spec["unit"]]
    frames = 0

    def path(component: str) -> str:
        return os.path.join(spec["input_root"], component, f"{segment}.parquet")

    def batches(component: str, columns: list[str]):
        yield from pq.ParquetFile(path(component)).iter_batches(batch_size=8, columns=columns)

    def read() -> None:
        nonlocal frames
        small = {
            C.CAMERA_CALIBRATION: [C.CAMERA_NAME, *C.CAM_INTRINSICS, *C.CAM_DISTORTION, C.CAM_EXTRINSIC],
            C.LIDAR_CALIBRATION: [C.LASER_NAME, C.LIDAR_EXTRINSIC, C.BEAM_INCLINATION_VALUES],
            C.VEHICLE_POSE: [C.TIMESTAMP, C.WORLD_FROM_VEHICLE],
            C.LIDAR_BOX: [C.TIMESTAMP, C.OBJECT_ID, C.BOX_TYPE, *C.BOX_FIELDS],
            C.LIDAR_CAMERA_SYNCED_BOX: [C.TIMESTAMP, C.OBJECT_ID, C.MOST_VISIBLE_CAMERA],
        }
        for component, names in small.items():
            pq.read_table(path(component), columns=names)
        for batch in batches(C.CAMERA_IMAGE, [C.TIMESTAMP, C.CAMERA_NAME, C.IMAGE_JPEG, C.IMAGE_POSE]):
            names = batch.column(C.CAMERA_NAME)
            rows = batch.filter(pc.is_in(names, pa.array(cameras, names.type)))
            for jpeg in rows.column(C.IMAGE_JPEG).to_pylist():
                cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
                frames += 1
        for component, values, shape in (
            (C.LIDAR, C.LIDAR_RANGE_VALUES, C.LIDAR_RANGE_SHAPE),
            (C.LIDAR_POSE, C.LIDAR_POSE_VALUES, C.LIDAR_POSE_SHAPE),
            (C.LIDAR_CAMERA_PROJECTION, C.PROJECTION_VALUES, C.PROJECTION_SHAPE),
        ):
            for batch in batches(component, [C.TIMESTAMP, C.LASER_NAME, values, shape]):
                rows = batch.filter(pc.equal(batch.column(C.LASER_NAME), C.TOP_LASER))
                for row in range(rows.num_rows):
                    dims = rows.column(shape)[row].values.to_numpy()
                    rows.column(values)[row].values.to_numpy(zero_copy_only=False).reshape(dims)

    wall, cpu = _timed(read)
    return {"floor_s": wall, "floor_cpu_s": cpu, "floor_frames": frames}


def pstudio(spec: dict) -> dict:
    import cv2

    (sequence,), cameras = {s for s, _ in spec["unit"]}, [c for _, c in spec["unit"]]
    root = spec["input_root"]
    data = os.path.join(root, "data", sequence)
    outputs = os.path.join(root, "output")
    params = [os.path.join(outputs, e, sequence, "params.npz") for e in sorted(os.listdir(outputs))][0]
    members = ("means3D", "unnorm_rotations", "log_scales", "logit_opacities", "seg_colors")
    frames = 0

    def read_file(name: str) -> bytes:
        with open(name, "rb") as f:
            return f.read()

    def decode(name: str) -> None:
        cv2.imdecode(np.frombuffer(read_file(name), np.uint8), cv2.IMREAD_GRAYSCALE)

    def read() -> None:
        nonlocal frames
        meta = json.loads(read_file(os.path.join(data, "train_meta.json")))
        views = [meta["cam_id"][0].index(camera) for camera in cameras]
        with np.load(params, allow_pickle=False) as archive:
            for name in members:
                archive[name]
        for t, names in enumerate(meta["fn"]):
            for view in views:
                decode(os.path.join(data, "ims", names[view]))
            for name in names:
                decode(os.path.join(data, "seg", name.rsplit(".", 1)[0] + ".png"))
            frames = len(views) * (t + 1)

    wall, cpu = _timed(read)
    return {"floor_s": wall, "floor_cpu_s": cpu, "floor_frames": frames}


def adt(spec: dict) -> dict:
    from pipeline.adt.frames import open_reader
    from pipeline.adt.units import CHUNKS_PER_GROUP
    from pipeline.core.config import with_overrides
    from pipeline.settings import RunConfig

    config = with_overrides(RunConfig(), spec["overrides"])
    ((sequence, chunk),) = spec["unit"]
    opened = {}

    def open_sequence() -> None:
        reader = open_reader(sequence, config)
        opened["reader"], opened["stamps"] = reader, reader.frame_timestamps()

    open_wall, open_cpu = _timed(open_sequence)
    reader = opened["reader"]
    size = config.adt.chunk_frames
    stamps = opened["stamps"][chunk * size : (chunk + 1) * size]
    repeat = spec.get("repeat", 1)

    def read() -> None:
        for _ in range(repeat):
            for timestamp in stamps:
                reader.rgb(timestamp)
                reader.depth_mm(timestamp)
                reader.ids(timestamp)

    wall, cpu = _timed(read)
    close_wall, close_cpu = _timed(reader.close)
    return {
        "floor_s": open_wall + wall + close_wall,
        "floor_cpu_s": open_cpu + cpu + close_cpu,
        "floor_frames": len(stamps) * repeat,
        "floor_open_s": open_wall + close_wall,
        "floor_open_cpu_s": open_cpu + close_cpu,
        "floor_open_share": 1.0 / CHUNKS_PER_GROUP,  # a group of chunks opens and closes the sequence once
    }


def measure(spec: dict) -> dict:
    """The floor of ``spec``'s unit (``benchmarks.units`` builds the spec)."""
    return {"drivetrack": drivetrack, "pstudio": pstudio, "adt": adt}[spec["source"]](spec)
