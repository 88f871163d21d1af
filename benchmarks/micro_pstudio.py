"""Panoptic Studio speed figures on a synthetic 300,000-Gaussian dome scene at 640x360, on one
thread (numba's, as a benchmark worker has).

Five people-sized ellipsoids (120,000 foreground Gaussians) walk on a floor inside a dome wall
(180,000 background Gaussians), for 150 frames, seen by four cameras. Prints the full-frame
depth render time, the selected-pixel render time for a clip's 400 candidate tracks (each the
best of REPEATS runs, averaged over the timed frames), their ratio, and the time to annotate one
150-frame clip (its masks drawn beforehand: drawing one costs more than decoding a PNG).
"""

from __future__ import annotations

import time

import cv2
import numba
import numpy as np

from pipeline.pstudio.records import Gaussians, UnitInput, Views
from pipeline.pstudio.render import render_depth_at, render_depth_image
from pipeline.pstudio.tracks import annotate_unit, splats_in_view
from pipeline.settings import RunConfig

WIDTH, HEIGHT, FRAMES, CAMERAS = 640, 360, 150, 4
REPEATS = 3  # runs of each render per timed frame; the fastest counts (the machine may be busy)
PEOPLE, PER_PERSON, FLOOR, WALL = 5, 24_000, 100_000, 80_000


def _sphere(count: int, rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=(count, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _quaternion_z(normals: np.ndarray, yaw: float = 0.0) -> np.ndarray:
    """Quaternions [K, 4] turning local z onto unit normals [K, 3], then yawing by ``yaw``."""
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, normals)
    w = 1.0 + normals @ z
    q = np.concatenate([w[:, None], axis], axis=1)
    q[w < 1e-6] = [0.0, 1.0, 0.0, 0.0]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    yaw_q = np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])
    w1, v1 = yaw_q[0], yaw_q[1:]
    w2, v2 = q[:, 0], q[:, 1:]
    return np.concatenate(
        [(w1 * w2 - v2 @ v1)[:, None], w1 * v2 + w2[:, None] * v1 + np.cross(v1, v2)], axis=1
    )


def synthetic_scene(
    seed: int = 0,
    frames: int = FRAMES,
    per_person: int = PER_PERSON,
    floor_count: int = FLOOR,
    wall_count: int = WALL,
    cameras: int = CAMERAS,
) -> tuple[Gaussians, Views]:
    """The 300,000-Gaussian scene: means [150, N, 3] and quaternions as float32, like params.npz.

    The sizes are parameters (the defaults give that scene); with more than 4 cameras they
    stand at three heights around the dome, like Panoptic Studio's (27 training cameras)."""
    rng = np.random.default_rng(seed)
    axes = np.array([0.22, 0.16, 0.85])
    unit = _sphere(per_person, rng)
    local, local_normals = unit * axes, unit / axes
    local_normals /= np.linalg.norm(local_normals, axis=1, keepdims=True)
    floor = np.concatenate([rng.uniform(-4, 4, (floor_count, 2)), np.zeros((floor_count, 1))], axis=1)
    angle = rng.uniform(0, 2 * np.pi, wall_count)
    wall = np.stack([4.5 * np.cos(angle), 4.5 * np.sin(angle), rng.uniform(0, 3, wall_count)], axis=1)
    wall_normals = -wall * [1, 1, 0] / 4.5
    background = np.concatenate([floor, wall])
    background_q = np.concatenate(
        [_quaternion_z(np.tile([0.0, 0.0, 1.0], (floor_count, 1))), _quaternion_z(wall_normals)]
    )
    people = PEOPLE * per_person
    count = people + floor_count + wall_count
    means = np.empty((frames, count, 3), np.float32)
    quaternions = np.empty((frames, count, 4), np.float32)
    means[:, people:] = background
    quaternions[:, people:] = background_q
    for t in range(frames):
        for p in range(PEOPLE):
            phase = 2 * np.pi * (p / PEOPLE + t / frames / 2)
            yaw = phase + np.pi / 2
            c, s = np.cos(yaw), np.sin(yaw)
            rotation = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
            centre = [1.6 * np.cos(phase), 1.6 * np.sin(phase), 0.9]
            block = slice(p * per_person, (p + 1) * per_person)
            means[t, block] = local @ rotation.T + centre
            quaternions[t, block] = _quaternion_z(local_normals, yaw)
    scales = np.concatenate(
        [
            np.tile([0.006, 0.006, 0.001], (people, 1)),
            np.tile([0.018, 0.018, 0.002], (floor_count, 1)),
            np.tile([0.024, 0.024, 0.002], (wall_count, 1)),
        ]
    )
    opacities = np.full(count, 0.9)
    foreground = np.arange(count) < people
    views = _cameras(cameras)
    return Gaussians(means, quaternions, scales, opacities, foreground), views


def _cameras(count: int = CAMERAS) -> Views:
    w2c = []
    for k in range(count):
        a = 2 * np.pi * k / count + 0.3
        height = 1.7 if count <= CAMERAS else (1.7, 1.1, 2.3)[k % 3]
        eye = np.array([3.8 * np.cos(a), 3.8 * np.sin(a), height])
        forward = -eye * [1, 1, 0] / np.linalg.norm(eye[:2]) + [0, 0, -0.25]
        forward /= np.linalg.norm(forward)
        right = np.cross(forward, [0, 0, 1.0])
        right /= np.linalg.norm(right)
        rotation = np.stack([right, np.cross(forward, right), forward])
        transform = np.eye(4)
        transform[:3, :3], transform[:3, 3] = rotation, -rotation @ eye
        w2c.append(transform)
    intrinsics = np.tile([420.0, 420.0, 320.0, 180.0], (count, 1))
    return Views(np.arange(count), intrinsics, np.stack(w2c), WIDTH, HEIGHT)


def _mask_function(gaussians: Gaussians, views: Views):
    """Foreground masks: the foreground centres drawn into each view and dilated by 3 px.

    (einsum, not ``@``: BLAS's threads made this ten times slower on a busy machine.)"""
    foreground = np.nonzero(gaussians.foreground)[0]

    def mask(view: int, t: int) -> np.ndarray:
        centres = gaussians.means[t, foreground].astype(np.float64)
        points = np.einsum("nj,ij->ni", centres, views.w2c[view, :3, :3]) + views.w2c[view, :3, 3]
        fx, fy, cx, cy = views.fx_fy_cx_cy[view]
        u = np.round(fx * points[:, 0] / points[:, 2] + cx).astype(np.int64)
        v = np.round(fy * points[:, 1] / points[:, 2] + cy).astype(np.int64)
        inside = (points[:, 2] > 0) & (u >= 0) & (u < WIDTH) & (v >= 0) & (v < HEIGHT)
        image = np.zeros((HEIGHT, WIDTH), np.uint8)
        image[v[inside], u[inside]] = 1
        return cv2.dilate(image, np.ones((7, 7), np.uint8)) > 0

    return mask


def _drawn_masks(gaussians: Gaussians, views: Views):
    """``_mask_function``'s masks for every (view, t), drawn now and kept bit-packed; returns a
    ``UnitInput.mask`` that reads them."""
    draw = _mask_function(gaussians, views)
    packed = [
        [np.packbits(draw(view, t)) for t in range(gaussians.num_frames)]
        for view in range(len(views.camera_ids))
    ]

    def mask(view: int, t: int) -> np.ndarray:
        return np.unpackbits(packed[view][t], count=WIDTH * HEIGHT).view(np.bool_).reshape(HEIGHT, WIDTH)

    return mask


def _best(function, *args):
    """(fastest of REPEATS calls in seconds, the last call's result)."""
    best = np.inf
    for _ in range(REPEATS):
        start = time.perf_counter()
        result = function(*args)
        best = min(best, time.perf_counter() - start)
    return best, result


def _full_frame(unit: UnitInput, t: int) -> tuple[np.ndarray, np.ndarray]:
    return render_depth_image(splats_in_view(unit, 0, t))


def _selected(unit: UnitInput, t: int, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return render_depth_at(splats_in_view(unit, 0, t, points), points)


def run(frames: int) -> None:
    """Print render and annotation timings on the synthetic scene (``frames`` frames timed), on
    one numba thread."""
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        _run(frames)
    finally:
        numba.set_num_threads(threads)


def _run(frames: int) -> None:
    started = time.perf_counter()
    gaussians, views = synthetic_scene()
    count = gaussians.means.shape[1]
    print(f"scene: {count:,} Gaussians x {FRAMES} frames, {CAMERAS} cameras at {WIDTH}x{HEIGHT}; one thread")
    jpeg = cv2.imencode(".jpg", np.zeros((HEIGHT, WIDTH, 3), np.uint8))[1].tobytes()
    unit = UnitInput("bench", 0, views, gaussians, [jpeg] * FRAMES, _drawn_masks(gaussians, views))
    print(f"  built and its masks drawn in {time.perf_counter() - started:.1f} s")
    rng = np.random.default_rng(1)
    render_depth_image(splats_in_view(unit, 0, 0))  # compile the kernels outside the timings
    full = sparse = 0.0
    timed = [int(t) for t in np.linspace(0, FRAMES - 1, frames)]
    for t in timed:
        elapsed, (depth, surface) = _best(_full_frame, unit, t)
        full += elapsed
        pixels = np.argwhere(surface)[rng.choice(int(surface.sum()), 400, replace=False)]
        points = pixels[:, ::-1] + 0.5
        elapsed, (sparse_depth, _) = _best(_selected, unit, t, points)
        sparse += elapsed
        assert np.array_equal(sparse_depth, depth[pixels[:, 0], pixels[:, 1]])
    print(f"depth render, mean over {len(timed)} frame(s) (projection of all Gaussians included):")
    print(f"  full frame ({WIDTH * HEIGHT:,} pixels): {1000 * full / len(timed):8.1f} ms/frame")
    print(f"  400 selected pixels:           {1000 * sparse / len(timed):8.1f} ms/frame")
    print(f"  speed-up of the selected-pixel path: {full / sparse:.1f}x (identical values at those pixels)")
    config = RunConfig()
    start = time.perf_counter()
    (clip,) = annotate_unit(unit, config)
    elapsed = time.perf_counter() - start
    print(
        f"annotate one {FRAMES}-frame clip: {elapsed:.1f} s ({1000 * elapsed / FRAMES:.0f} ms/frame), "
        f"{clip.num_tracks} candidate tracks, visible {clip.visibility.mean():.0%} of (track, frame) pairs"
    )
    estimate = 2 * FRAMES * full / len(timed)
    print(
        f"  (both passes over {FRAMES} frames with full-frame renders: about {estimate:.0f} s of rendering)"
    )
