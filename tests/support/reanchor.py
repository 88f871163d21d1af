"""Re-anchor a Waymo v2 split: move its world frame by a rigid transform, storing every world-frame
transform as float32 (``fixed_size_list<float>[16]``), as a far-from-origin segment's would be.

World-frame data in a segment: ``vehicle_pose`` world_from_vehicle, ``camera_image`` pose (and the
global-frame linear velocity), and ``lidar_pose``'s per-pixel vehicle poses. Boxes, range images,
calibrations and ``lidar_camera_projection`` live in vehicle, sensor or pixel frames: unchanged.
"""

from __future__ import annotations

import os
import shutil

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from pipeline.core.geometry import rotation_from_roll_pitch_yaw

POSE = "[CameraImageComponent].pose.transform"
VELOCITY = "[CameraImageComponent].velocity.linear_velocity."
WORLD_FROM_VEHICLE = "[VehiclePoseComponent].world_from_vehicle.transform"
PIXEL_POSES = "[LiDARPoseComponent].range_image_return1.values"


def anchor(yaw: float, translation) -> np.ndarray:
    """new_world_from_old_world [4, 4]: a rotation about z by ``yaw`` then ``translation`` [3]."""
    c, s = np.cos(yaw), np.sin(yaw)
    matrix = np.eye(4)
    matrix[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    matrix[:3, 3] = translation
    return matrix


def _moved_transforms(table: pa.Table, name: str, moved: np.ndarray, dtype=np.float32) -> pa.Table:
    """The table with its transform column ``name`` moved by ``moved`` ([4, 4], or one [R, 4, 4] per
    row) and stored as ``fixed_size_list<dtype>[16]``."""
    values = table.column(name).combine_chunks().flatten().to_numpy(zero_copy_only=False)
    matrices = moved @ values.astype(np.float64).reshape(-1, 4, 4)
    column = pa.FixedSizeListArray.from_arrays(pa.array(matrices.reshape(-1).astype(dtype)), 16)
    return table.set_column(table.schema.get_field_index(name), name, column)


def _moved_pixel_poses(values: np.ndarray, moved: np.ndarray) -> np.ndarray:
    """Per-pixel (roll, pitch, yaw, x, y, z) [M, 6] moved into the new world, as float32."""
    poses = values.astype(np.float64)
    rotation = moved[:3, :3] @ rotation_from_roll_pitch_yaw(poses[:, 0], poses[:, 1], poses[:, 2])
    out = np.empty_like(poses)
    out[:, 0] = np.arctan2(rotation[:, 2, 1], rotation[:, 2, 2])
    out[:, 1] = -np.arcsin(np.clip(rotation[:, 2, 0], -1.0, 1.0))
    out[:, 2] = np.arctan2(rotation[:, 1, 0], rotation[:, 0, 0])
    out[:, 3:] = poses[:, 3:] @ moved[:3, :3].T + moved[:3, 3]
    return out.astype(np.float32)


def reanchor_split(source: str, target: str, moved: np.ndarray) -> None:
    """Copy the split folder ``source`` to ``target`` with its world moved by ``moved`` [4, 4]."""
    shutil.copytree(source, target)
    for path in sorted(os.listdir(os.path.join(target, "vehicle_pose"))):
        file = os.path.join(target, "vehicle_pose", path)
        pq.write_table(_moved_transforms(pq.read_table(file), WORLD_FROM_VEHICLE, moved), file)
    for path in sorted(os.listdir(os.path.join(target, "camera_image"))):
        file = os.path.join(target, "camera_image", path)
        table = _moved_transforms(pq.read_table(file), POSE, moved)
        if VELOCITY + "x" in table.column_names:
            velocity = np.stack([table.column(VELOCITY + k).to_numpy() for k in "xyz"], 1) @ moved[:3, :3].T
            for i, k in enumerate("xyz"):
                index = table.schema.get_field_index(VELOCITY + k)
                table = table.set_column(index, VELOCITY + k, pa.array(velocity[:, i].astype(np.float32)))
        pq.write_table(table, file)
    for path in sorted(os.listdir(os.path.join(target, "lidar_pose"))):
        file = os.path.join(target, "lidar_pose", path)
        table = pq.read_table(file)
        column = table.column(PIXEL_POSES).combine_chunks()
        values = _moved_pixel_poses(column.flatten().to_numpy().reshape(-1, 6), moved)
        moved_column = pa.ListArray.from_arrays(column.offsets, pa.array(values.reshape(-1)))
        table = table.set_column(table.schema.get_field_index(PIXEL_POSES), PIXEL_POSES, moved_column)
        pq.write_table(table, file)


BOX_CENTRES = ("[LiDARBoxComponent].box.center.", "[LiDARCameraSyncedBoxComponent].camera_synced_box.center.")


def _nudges(rng: np.random.Generator, count: int, metres: float) -> np.ndarray:
    """[count, 4, 4] translations by ``metres`` in random directions."""
    directions = rng.normal(size=(count, 3))
    nudges = np.repeat(np.eye(4)[None], count, axis=0)
    nudges[:, :3, 3] = metres * directions / np.linalg.norm(directions, axis=1, keepdims=True)
    return nudges


def nudge_split(source: str, target: str, metres: float, seed: int = 0) -> None:
    """Copy the split folder ``source`` to ``target`` with every pose moved by ``metres`` in its own
    random direction: each frame's vehicle pose with its camera images' poses and its lidar's
    per-pixel poses (one nudge per frame, so the ego stays one rigid body), and each box of
    ``lidar_box`` and ``lidar_camera_synced_box`` on its own. Transforms stay float64."""
    rng = np.random.default_rng(seed)
    shutil.copytree(source, target)
    frame_nudge: dict[int, np.ndarray] = {}

    def nudges_of(stamps: np.ndarray) -> np.ndarray:
        for stamp in stamps.tolist():
            if stamp not in frame_nudge:
                frame_nudge[stamp] = _nudges(rng, 1, metres)[0]
        return np.stack([frame_nudge[stamp] for stamp in stamps.tolist()])

    def files(component: str) -> list[str]:
        folder = os.path.join(target, component)
        return [os.path.join(folder, name) for name in sorted(os.listdir(folder))]

    def nudged(table: pa.Table, name: str) -> pa.Table:
        stamps = table.column("key.frame_timestamp_micros").to_numpy()
        return _moved_transforms(table, name, nudges_of(stamps), np.float64)

    for file in files("vehicle_pose"):
        pq.write_table(nudged(pq.read_table(file), WORLD_FROM_VEHICLE), file)
    for file in files("camera_image"):
        pq.write_table(nudged(pq.read_table(file), POSE), file)
    for file in files("lidar_pose"):
        table = pq.read_table(file)
        column = table.column(PIXEL_POSES).combine_chunks()
        values = column.flatten().to_numpy().astype(np.float64).reshape(-1, 6)
        stamps = table.column("key.frame_timestamp_micros").to_numpy()
        rows = np.repeat(np.arange(len(stamps)), np.diff(column.offsets.to_numpy()) // 6)
        values[:, 3:] += nudges_of(stamps)[rows, :3, 3]
        nudged_column = pa.ListArray.from_arrays(
            column.offsets, pa.array(values.reshape(-1).astype(np.float32))
        )
        table = table.set_column(table.schema.get_field_index(PIXEL_POSES), PIXEL_POSES, nudged_column)
        pq.write_table(table, file)
    for component, prefix in zip(("lidar_box", "lidar_camera_synced_box"), BOX_CENTRES, strict=True):
        for file in files(component):
            table = pq.read_table(file)
            moves = _nudges(rng, table.num_rows, metres)[:, :3, 3]
            for i, axis in enumerate("xyz"):
                index = table.schema.get_field_index(prefix + axis)
                centre = table.column(prefix + axis).to_numpy() + moves[:, i]
                table = table.set_column(index, prefix + axis, pa.array(centre, pa.float64()))
            pq.write_table(table, file)
