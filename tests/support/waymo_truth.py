"""Where the sample world's points truly appear in its cameras, computed here without the pipeline:
cv2.projectPoints for the lens, the ego's exact pose (its analytic arc, not the files' velocity)
at the instant the rolling shutter reads the point's own pixel, iterated to a fixed point."""

from __future__ import annotations

import cv2
import numpy as np

from pipeline.drivetrack.sample.waymo_world import (
    DISTORTION,
    FIRST_TIMESTAMP_MICROS,
    FX_FY_CX_CY,
    HEIGHT,
    READOUT_S,
    SHUTTER_DIRECTIONS,
    WIDTH,
    frame_time,
    world_from_camera,
)

# OpenCV camera axes from the Waymo camera axes (x forward, y left, z up), written out here
# rather than taken from the pipeline.
OPENCV_FROM_WAYMO = np.array([[0, -1, 0, 0], [0, 0, -1, 0], [1, 0, 0, 0], [0, 0, 0, 1.0]])


def world_from_cv(world, camera: int, times) -> np.ndarray:
    """OpenCV-axes camera poses [..., 4, 4] at times [...] seconds."""
    return world_from_camera(world, camera, times) @ np.linalg.inv(OPENCV_FROM_WAYMO)


def sensor_pixels(camera: int, points: np.ndarray) -> np.ndarray:
    """Pixels [N, 2] (centres at +0.5) of camera points [N, 3] (OpenCV axes, z > 0) through the lens."""
    fx, fy, cx, cy = FX_FY_CX_CY
    matrix = np.array([[fx, 0, cx - 0.5], [0, fy, cy - 0.5], [0, 0, 1.0]])  # OpenCV: centres at integers
    pixels = cv2.projectPoints(points.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), matrix, DISTORTION[camera])
    return pixels[0].reshape(-1, 2) + 0.5


def pinhole_pixels(points: np.ndarray) -> np.ndarray:
    fx, fy, cx, cy = FX_FY_CX_CY
    return np.stack([fx * points[:, 0] / points[:, 2] + cx, fy * points[:, 1] / points[:, 2] + cy], 1)


def read_offset(camera: int, pixels: np.ndarray) -> np.ndarray:
    """Seconds after the frame time at which pixels [N, 2] are read: the principal point at the frame
    time, the far edge READOUT_S later along the camera's readout direction."""
    size, axis, sign = {1: (HEIGHT, 1, 1), 2: (WIDTH, 0, 1), 3: (HEIGHT, 1, -1)}[SHUTTER_DIRECTIONS[camera]]
    coordinate = np.clip(pixels[:, axis], 0, size)
    return sign * READOUT_S * (coordinate - FX_FY_CX_CY[2 + axis]) / size


def seen(world, camera: int, frame: int, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World points [N, 3] as the camera sees them at a frame: camera points [N, 3] (OpenCV axes) at
    the instant each is read, their sensor pixels [N, 2] (NaN behind the camera), and the camera's
    position then [N, 3]. The instant is iterated until it no longer changes."""
    offsets = np.zeros(len(points))
    for _ in range(30):
        pose = world_from_cv(world, camera, frame_time(frame) + offsets)
        local = np.einsum("nji,nj->ni", pose[:, :3, :3], points - pose[:, :3, 3])
        front = local[:, 2] > 0
        pixels = np.full((len(points), 2), np.nan)
        pixels[front] = sensor_pixels(camera, local[front])
        previous, offsets = offsets, np.where(front, read_offset(camera, np.nan_to_num(pixels, nan=0.0)), 0.0)
        if np.abs(offsets - previous).max(initial=0.0) < 1e-12:
            break
    return local, pixels, pose[:, :3, 3]


def world_points(world, camera: int, frame: int, points: np.ndarray) -> np.ndarray:
    """The inverse: world points [N, 3] of camera points [N, 3] seen at a frame (each was read at the
    instant its own sensor pixel says)."""
    pose = world_from_cv(
        world, camera, frame_time(frame) + read_offset(camera, sensor_pixels(camera, points))
    )
    return np.einsum("nij,nj->ni", pose[:, :3, :3], points) + pose[:, :3, 3]


def inside(pixels: np.ndarray) -> np.ndarray:
    """[N] True for pixels [N, 2] inside the sample's frames."""
    return (pixels[:, 0] >= 0) & (pixels[:, 0] < WIDTH) & (pixels[:, 1] >= 0) & (pixels[:, 1] < HEIGHT)


def true_tracks(world, clip, camera: int, undistorted: bool = True):
    """Truth for a clip whose frame-0 tracks name its points: each track's surface point as the
    camera sees it [T, N, 3] (OpenCV axes, at the instant it is read), where it appears in the
    stored frames [T, N, 2] (undistorted, or as the sensor took them), its body-frame point [N, 3],
    true visibility [T, N] by ray casting from the camera at that instant, and the object id."""
    object_id = clip.name.split(f"_{camera}_", 1)[1]
    actor = world.actors[object_id]
    first = (int(clip.frame_ids[0]) - FIRST_TIMESTAMP_MICROS) // 100_000
    body_from_world = np.linalg.inv(actor.world_from_body(frame_time(first)))
    body = world_points(world, camera, first, clip.tracks_xyz[0]) @ body_from_world[:3, :3].T
    body += body_from_world[:3, 3]
    positions, pixels, visible = [], [], []
    for i in range(clip.num_frames):
        t = frame_time(first + i)
        pose = actor.world_from_body(t)
        points_world = body @ pose[:3, :3].T + pose[:3, 3]
        points, sensor, eyes = seen(world, camera, first + i, points_world)
        stored = pinhole_pixels(points) if undistorted else sensor
        in_view = (points[:, 2] > 0) & inside(np.nan_to_num(sensor, nan=-1.0)) & inside(stored)
        positions.append(points)
        pixels.append(stored)
        visible.append(in_view & world.unobstructed(t, eyes, points_world))
    return np.stack(positions), np.stack(pixels), body, np.stack(visible), object_id
