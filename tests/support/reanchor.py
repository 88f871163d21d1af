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


def _float32_transforms(matrices: np.ndarray) -> pa.Array:
    flat = pa.array(matrices.reshape(-1).astype(np.float32))
    return pa.FixedSizeListArray.from_arrays(flat, 16)


def _moved_transforms(table: pa.Table, name: str, moved: np.ndarray) -> pa.Table:
    values = table.column(name).combine_chunks().flatten().to_numpy(zero_copy_only=False)
    matrices = moved @ values.astype(np.float64).reshape(-1, 4, 4)
    return table.set_column(table.schema.get_field_index(name), name, _float32_transforms(matrices))


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
