"""DriveTrack speed figures: the occlusion decision for one 1920x1280 frame, ours (nearest lidar point of the
four integer pixels around each track point) against the DriveTrack generator's (a dense
NearestNDInterpolator depth map of the whole image, then the max of the four pixels), on the
same lidar points and track points, with the agreement of the decisions.
"""

from __future__ import annotations

import time

import numpy as np

from pipeline.core.visibility import passes_relative_depth_test
from pipeline.drivetrack.visibility import dense_nearest_depth, max4_from_dense, nearest_depth_max4

WIDTH, HEIGHT, FOCAL = 1920, 1280, 2055.0


def synthetic_frame(seed: int = 0, tracks: int = 1024):
    """A TOP-lidar-like scan of a street seen by a 1920x1280 camera: 64 scan lines, one return
    per 0.136 degrees of azimuth, depths from a ground plane with box-shaped vehicles; and
    track points on those vehicles, some behind others. Returns (lidar uv [M, 2], lidar z [M],
    track uv [N, 2], track z [N])."""
    rng = np.random.default_rng(seed)
    elevation = np.deg2rad(np.linspace(2.4, -17.6, 64))
    azimuth = np.deg2rad(np.arange(-25.0, 25.0, 0.136))
    el, az = np.meshgrid(elevation, azimuth, indexing="ij")
    height = 2.0
    ground = np.where(el < 0, height / np.tan(-np.minimum(el, -1e-3)), 80.0)
    depth = np.minimum(ground, 80.0) * np.cos(az)
    for _ in range(12):  # vehicles: boxes in angle with a constant depth
        centre, half = rng.uniform(-0.4, 0.4), rng.uniform(0.02, 0.08)
        distance = rng.uniform(6.0, 50.0)
        top = np.arctan((1.6 - height) / distance)
        inside = (np.abs(az - centre) < half) & (el < top) & (el > -np.arctan(height / distance))
        depth = np.where(inside & (distance < depth), distance, depth)
    u = FOCAL * np.tan(az) + WIDTH / 2
    v = -FOCAL * np.tan(el) / np.cos(az) + HEIGHT / 2
    keep = (u >= 0) & (u < WIDTH) & (v >= 0) & (v < HEIGHT)
    lidar_uv = np.stack([u[keep], v[keep]], 1)
    lidar_z = depth[keep]
    pick = rng.choice(len(lidar_z), size=tracks)
    track_uv = lidar_uv[pick] + rng.normal(0, 3.0, size=(tracks, 2))
    track_z = lidar_z[pick] * rng.choice([1.0, 1.3, 2.0], size=tracks, p=[0.7, 0.2, 0.1])
    return lidar_uv, lidar_z, np.clip(track_uv, 0, [WIDTH - 1, HEIGHT - 1]), track_z


def best_of(repeats: int, function, *args):
    times, result = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        result = function(*args)
        times.append(time.perf_counter() - start)
    return min(times), result


def run(frames: int) -> None:
    """Print the occlusion-decision timings, ours and the generator's, over ``frames`` frames."""
    ours_total = theirs_total = 0.0
    agree = total = 0
    for seed in range(frames):
        lidar_uv, lidar_z, track_uv, track_z = synthetic_frame(seed)
        ours_time, ours = best_of(3, nearest_depth_max4, lidar_uv, lidar_z, track_uv, WIDTH, HEIGHT)

        def generator(uv=lidar_uv, z=lidar_z, queries=track_uv):
            return max4_from_dense(dense_nearest_depth(uv, z, WIDTH, HEIGHT), queries)

        theirs_time, theirs = best_of(1, generator)
        ours_total += ours_time
        theirs_total += theirs_time
        ours_visible = passes_relative_depth_test(track_z, ours, 0.05)
        theirs_visible = passes_relative_depth_test(track_z, theirs, 0.05)
        agree += int((ours_visible == theirs_visible).sum())
        total += len(track_z)
        if seed == 0:
            print(
                f"per frame: {len(lidar_z)} lidar points in the image, {len(track_z)} track points, "
                f"{(~ours_visible).mean():.1%} occluded"
            )
    print(f"occlusion decision at {WIDTH}x{HEIGHT}, mean over {frames} frame(s):")
    print(f"  ours (4-pixel nearest-lidar lookup): {1000 * ours_total / frames:9.2f} ms/frame")
    print(f"  DriveTrack generator (dense map):    {1000 * theirs_total / frames:9.2f} ms/frame")
    print(
        f"  speed-up: {theirs_total / ours_total:.1f}x   identical decisions: {agree}/{total} "
        f"({agree / total:.2%})"
    )
