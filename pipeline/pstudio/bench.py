"""Panoptic Studio's benchmark entry. Unit: 3 cameras of a sequence annotated together (a group of the
graph), on a synthetic dome of 300,000 Gaussians x 27 cameras at 640x360 in Dynamic 3D Gaussians'
file layout. Default size: 30 frames, extrapolated to 3 x 150 frames; ``--full``: 150 frames
(writing them takes about 7 minutes the first time). Micro: full-frame against selected-pixel
depth renders, and one clip's annotation.

The scene: five people-sized ellipsoids (120,000 foreground Gaussians) walk on a floor inside a
dome wall (180,000 background Gaussians), for 150 frames, on one thread (numba's, as a benchmark
worker has).

Inputs (``prepare``): the scene seen by 27 cameras like a Dynamic 3D Gaussians training sequence,
written in its file layout (``data/<seq>/train_meta.json``, ``ims/``, ``seg/``,
``output/<exp>/<seq>/params.npz`` stored like ``np.savez``), read back by the real reader. Full
size: 150 frames, as Panoptic Studio sequences have (params.npz 1.7 GiB). Default size (``make
bench``): the same 300,000 Gaussians and 27 cameras for 30 frames: every per-frame cost
(projecting and rendering 300,000 Gaussians, one JPEG and 27 masks per frame, the frame's share of
params.npz) is the full sequence's; the report extrapolates the unit to 150 frames linearly. The
people walk the same half circle in 30 frames, so they move 5 times faster per frame (no bearing
on the cost). Images: grey studio with the people brighter, plus grain (the pipeline passes them
through); masks: the foreground centres drawn and dilated (``_mask_function``).

Floor (``floor``): ``train_meta.json``; the five members of ``params.npz`` the reader reads
(``np.load``), once; the group cameras' JPEGs and every camera's mask PNG at every frame (the
multi-view mask statistic reads them all), each decoded once, grey-level, as the reader decodes
them.

Micro (``micro``), on four cameras: the full-frame depth render time, the selected-pixel render
time for a clip's 400 candidate tracks (each the best of REPEATS runs, averaged over the timed
frames), their ratio, and the time to annotate one 150-frame clip (its masks drawn beforehand:
drawing one costs more than decoding a PNG).

Rules: the units run under the release's rules (``rules=release``: what regenerating the release
costs; a query attached to a centre at any distance, ``pstudio.max_attach_distance_m=0``, so the
nearest-centre search loses its prefilter); each 1-worker unit runs once more under the refined
rules (``rules=refined``, a plain run's), printed beside the unit's (``UnitSetup.variants``); the
table's JSON holds the peak memory of each (``release``, ``refined``).

Beam (``--beam``, ``beam_input``): whole groups of 3 cameras, as many as asked, the first cameras
of as few sequences as hold them, each the sequence's files linked under a name of its own: at the
default and full sizes one sequence for 2 workers (cameras 0-23), at the quick size (4 cameras,
one whole group) 8 (their masks the same bytes: a worker's mask cache serves them all). Each
worker decodes a sequence's masks once (about 2.9 s at the full size), on the first of its groups:
every group reads every camera's masks at every frame, and the workers are processes of their own.

The pipeline's modules are imported inside the functions, so that a floor process imports only
what its floor reads.
"""

from __future__ import annotations

import json
import os
import time
from typing import TYPE_CHECKING

import numpy as np

from pipeline.core.benchmark import UnitSetup, wall_and_cpu

if TYPE_CHECKING:
    from pipeline.pstudio.records import Gaussians, UnitInput, Views

# Per input frame on one core.
TARGETS = {"ms_per_frame": 100.0}
RELEASE_SHAPE = (400, (150, 150))  # the release's candidates per clip, (fewest, most) frames per clip
FIXED_IN_WORK = ()  # nothing a repeated run pays again: the unit runs once

# The scene.
WIDTH, HEIGHT, FRAMES, CAMERAS = 640, 360, 150, 4
REPEATS = 3  # runs of each render per timed frame; the fastest counts (the machine may be busy)
PEOPLE, PER_PERSON, FLOOR, WALL = 5, 24_000, 100_000, 80_000
# The inputs.
SEQUENCE = "dome"
EXPERIMENT = "bench"
FULL = {"frames": FRAMES, "per_person": PER_PERSON, "floor": FLOOR, "wall": WALL}
DEFAULT = dict(FULL, frames=30)
QUICK = {"frames": 12, "per_person": 1_000, "floor": 3_000, "wall": 2_000}
CAMERAS_FULL, CAMERAS_QUICK = 27, 4  # Panoptic Studio sequences: 27 training cameras
VERSION = "3"  # 2: masks projected with einsum (a few pixels may differ); 3: every mask distinct
RELEASE_UNITS = 156  # 6 sequences x about 26 cameras: one clip per (sequence, camera) unit


def prepare(workdir: str, size: str) -> UnitSetup:
    """The sequence of ``size`` written under ``workdir`` (once), and its units; numba's kernels
    compiled (or loaded from its cache)."""
    from pipeline.pstudio.units import CAMERAS_PER_GROUP as GROUP

    sizes = {"quick": QUICK, "default": DEFAULT, "full": FULL}[size]
    cameras = CAMERAS_QUICK if size == "quick" else CAMERAS_FULL
    folder = os.path.join(workdir, f"sequence_{size}")
    written = _write_once(folder, size, sizes, cameras)
    _warm_numba()
    return UnitSetup(
        source="pstudio",
        input_root=folder,
        units=[
            [[SEQUENCE, camera] for camera in range(first, first + GROUP)]
            for first in range(0, cameras - GROUP + 1, GROUP)
        ],
        overrides=["rules=release"],
        frames=GROUP * sizes["frames"],
        description=_description(folder, sizes, cameras, written),
        full_units=RELEASE_UNITS // GROUP,
        full_clips=RELEASE_UNITS,
        full_units_note=(
            f"156 clips = 156 (sequence, camera) units of {FULL['frames']} frames, in groups of "
            f"{GROUP} as the graph groups them (each group reads params.npz and decodes the masks; a "
            "worker's mask cache spares the later groups of a sequence the decoding: this leans high); "
            "scenes of 300,000 Gaussians assumed"
        ),
        size=size,
        extrapolate_frames=GROUP * FULL["frames"] if size == "default" else None,
        notes=_notes(size, sizes),
        variants={"the refined rules": ["rules=refined"]},
        rule_sets={"refined": "the refined rules"},
    )


def _write_once(folder: str, size: str, sizes: dict, cameras: int) -> float:
    """The sequence at ``sizes`` written into ``folder`` unless it is there; the seconds spent."""
    from pipeline.io.write_once import write_once

    version = f"{VERSION}-{sizes['frames']}f"  # a folder of other sizes is written again
    if not os.path.exists(os.path.join(folder, f".complete-v{version}")):
        print(f"writing the {size} sequence (once; later runs reuse it) ...", flush=True)
    started = time.perf_counter()
    write_once(folder, version, lambda staging: write_sequence(staging, sizes, cameras))
    return time.perf_counter() - started


def _description(folder: str, sizes: dict, cameras: int, written: float) -> list[str]:
    """The setup's description: the scene and its files, and what a unit is."""
    from pipeline.pstudio.units import CAMERAS_PER_GROUP as GROUP

    count = 5 * sizes["per_person"] + sizes["floor"] + sizes["wall"]
    params = os.path.join(folder, "output", EXPERIMENT, SEQUENCE, "params.npz")
    return [
        f"{count:,} Gaussians x {sizes['frames']} frames, {cameras} cameras at "
        f"{WIDTH}x{HEIGHT}; params.npz {os.path.getsize(params) / 2**30:.2f} GiB"
        + (f"; written in {written:.0f} s" if written > 1 else ""),
        f"unit = {GROUP} (sequence, camera) units annotated together, one group of the graph (one "
        "read of params.npz, each mask decoded once); a frame = one "
        f"camera's frame; the scaling set takes cameras 0-{GROUP - 1}, {GROUP}-{2 * GROUP - 1}, ... "
        "(distinct units)",
    ]


def _notes(size: str, sizes: dict) -> list[str]:
    warm = (
        "numba kernels compiled and cached before the timings (cache=True), and loaded in each unit "
        "process before its runs (numba's first calls, once per worker process: not counted), as a "
        "warm worker has them"
    )
    if size != "default":
        return [warm]
    return [
        warm,
        f"measured on {sizes['frames']} frames of the full scene (300,000 Gaussians, 27 "
        f"cameras); the {FULL['frames']}-frame unit is {FULL['frames']} x its per-frame "
        "cost (extrapolated); peak memory holds the 30 frames' means and rotations "
        "(8.4 MB a frame; 150 frames add about 1 GiB); a unit's 800 query attempts fall "
        f"on {sizes['frames']} frames instead of {FULL['frames']} (27 a frame instead of "
        "5.3), so its query pass costs more a frame (13.5-17 ms against 8.6-10.5 ms with "
        "5.3 a frame, 2026-11-26): this leans high; make bench-full measures 150 frames",
    ]


def write_sequence(root: str, sizes: dict, cameras: int) -> None:
    """The scene at ``sizes`` seen by ``cameras`` cameras, in Dynamic 3D Gaussians' layout under ``root``."""
    gaussians, views = synthetic_scene(
        0, sizes["frames"], sizes["per_person"], sizes["floor"], sizes["wall"], cameras
    )
    frames, count = gaussians.means.shape[:2]
    from pipeline.pstudio.sample import dynamic3dgs_files as files

    data = os.path.join(root, "data", SEQUENCE)
    mask_of = _mask_function(gaussians, views)
    rng = np.random.default_rng(0)
    k = [[[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]] for fx, fy, cx, cy in views.fx_fy_cx_cy.tolist()]
    meta: dict = {"w": views.width, "h": views.height, "k": [], "w2c": [], "fn": [], "cam_id": []}
    for t in range(frames):
        ids = [int(c) for c in views.camera_ids]
        meta["k"].append(k)
        meta["w2c"].append(views.w2c.tolist())
        meta["fn"].append([f"{c}/{t:06d}.jpg" for c in ids])
        meta["cam_id"].append(ids)
        for view, camera in enumerate(ids):
            mask = mask_of(view, t)
            # A stray pixel of its own (top-left corner, by camera and frame) makes every mask file
            # distinct, as a real sequence's are: the pipeline's mask cache is keyed by the bytes.
            mask[t % 8, view] = True
            image = np.where(mask, 170.0, 70.0)[..., None] + rng.normal(0, 5.0, (*mask.shape, 3))
            files.write_view(data, camera, t, np.clip(image, 0, 255).astype(np.uint8), mask)
    colours = np.where(gaussians.foreground[:, None], [0.8, 0.5, 0.4], [0.5, 0.5, 0.5]).astype(np.float32)
    seg = np.where(gaussians.foreground[:, None], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]).astype(np.float32)
    opacity = gaussians.opacities
    params = {
        "means3D": gaussians.means,
        "rgb_colors": np.broadcast_to(colours, (frames, count, 3)),  # per frame, as the real files store it
        "unnorm_rotations": gaussians.quaternions,
        "seg_colors": seg,
        "logit_opacities": np.log(opacity / (1 - opacity))[:, None].astype(np.float32),
        "log_scales": np.log(gaussians.scales).astype(np.float32),
        "cam_m": np.zeros((50, 3), np.float32),
        "cam_c": np.zeros((50, 3), np.float32),
    }
    files.write_meta_and_params(root, SEQUENCE, meta, params, EXPERIMENT)


def measure_fixed_cost(spec: dict, config) -> dict:
    """Called by ``benchmarks.worker`` before the runs: numba's first dispatch of the kernels
    (loading them from its cache, about 0.6 s here), once per worker process like the imports, so
    not a unit's cost (reported, not counted; at the default size the runs would otherwise carry it
    into the extrapolation five times over). first_calls_s / first_calls_cpu_s."""
    wall, cpu = time.perf_counter(), time.process_time()
    _warm_numba()
    return {"first_calls_s": time.perf_counter() - wall, "first_calls_cpu_s": time.process_time() - cpu}


def _warm_numba() -> None:
    """Compile (or load from numba's cache) the kernels once: the projection, the render and the
    nearest-centre search, on a tiny scene."""
    from pipeline.pstudio.nearest import nearest_centres
    from pipeline.pstudio.records import UnitInput
    from pipeline.pstudio.render import render_depth_at
    from pipeline.pstudio.splats import gaussian_constants
    from pipeline.pstudio.tracks import splats_in_view

    gaussians, views = synthetic_scene(0, 2, 50, 50, 50, 1)
    constants = gaussian_constants(gaussians.scales, gaussians.opacities)
    unit = UnitInput("warm", 0, views, gaussians, constants, [], lambda view, t: np.ones(1, np.uint8))
    points = np.array([[320.0, 180.0]])
    render_depth_at(splats_in_view(unit, 0, 0, points), points, np.array([10.0]))
    nearest_centres(gaussians.means[0], np.arange(3), np.zeros((1, 3)))


def floor(spec: dict) -> dict:
    """The read+decode floor of the unit's group of cameras (the module's docstring)."""
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

    wall, cpu = wall_and_cpu(read)
    return {"floor_s": wall, "floor_cpu_s": cpu, "floor_frames": frames}


def _drawn_masks(gaussians: Gaussians, views: Views):
    """``_mask_function``'s masks for every (view, t), drawn now and kept bit-packed; returns a
    ``UnitInput.packed_mask`` that reads them."""
    draw = _mask_function(gaussians, views)
    packed = [
        [np.packbits(draw(view, t)) for t in range(gaussians.num_frames)]
        for view in range(len(views.camera_ids))
    ]

    def packed_mask(view: int, t: int) -> np.ndarray:
        return packed[view][t]

    return packed_mask


def _best(function, *args):
    """(fastest of REPEATS calls in seconds, the last call's result)."""
    best = np.inf
    for _ in range(REPEATS):
        start = time.perf_counter()
        result = function(*args)
        best = min(best, time.perf_counter() - start)
    return best, result


def unit_of(fields: list):
    """The SequenceCamera of a spec's JSON fields."""
    from pipeline.pstudio.units import SequenceCamera

    return SequenceCamera(*fields)


def micro(frames: int) -> None:
    """Print render and annotation timings on the synthetic scene (``frames`` frames timed), on
    one numba thread."""
    import numba

    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        _micro(frames)
    finally:
        numba.set_num_threads(threads)


def _micro(frames: int) -> None:
    import cv2

    from pipeline.pstudio.records import UnitInput
    from pipeline.pstudio.splats import gaussian_constants

    started = time.perf_counter()
    gaussians, views = synthetic_scene()
    count = gaussians.means.shape[1]
    print(f"scene: {count:,} Gaussians x {FRAMES} frames, {CAMERAS} cameras at {WIDTH}x{HEIGHT}; one thread")
    jpeg = cv2.imencode(".jpg", np.zeros((HEIGHT, WIDTH, 3), np.uint8))[1].tobytes()
    constants = gaussian_constants(gaussians.scales, gaussians.opacities)
    masks = _drawn_masks(gaussians, views)
    unit = UnitInput("bench", 0, views, gaussians, constants, [jpeg] * FRAMES, masks)
    print(f"  built and its masks drawn in {time.perf_counter() - started:.1f} s")
    full = _renders(unit, frames)
    _annotation(unit, full)


def _renders(unit: UnitInput, frames: int) -> float:
    """Print the full-frame and selected-pixel render times over ``frames`` frames; the mean
    seconds of a full-frame render."""
    from pipeline.pstudio.render import render_depth_at, render_depth_image
    from pipeline.pstudio.tracks import splats_in_view

    def full_frame(t: int) -> tuple[np.ndarray, np.ndarray]:
        return render_depth_image(splats_in_view(unit, 0, t))

    def selected(t: int, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return render_depth_at(splats_in_view(unit, 0, t, points), points)

    rng = np.random.default_rng(1)
    render_depth_image(splats_in_view(unit, 0, 0))  # compile the kernels outside the timings
    full = sparse = 0.0
    timed = [int(t) for t in np.linspace(0, FRAMES - 1, frames)]
    for t in timed:
        elapsed, (depth, surface) = _best(full_frame, t)
        full += elapsed
        pixels = np.argwhere(surface)[rng.choice(int(surface.sum()), 400, replace=False)]
        points = pixels[:, ::-1] + 0.5
        elapsed, (sparse_depth, _) = _best(selected, t, points)
        sparse += elapsed
        assert np.array_equal(sparse_depth, depth[pixels[:, 0], pixels[:, 1]])
    print(f"depth render, mean over {len(timed)} frame(s) (projection of all Gaussians included):")
    print(f"  full frame ({WIDTH * HEIGHT:,} pixels): {1000 * full / len(timed):8.1f} ms/frame")
    print(f"  400 selected pixels:           {1000 * sparse / len(timed):8.1f} ms/frame")
    print(f"  speed-up of the selected-pixel path: {full / sparse:.1f}x (identical values at those pixels)")
    return full / len(timed)


def _annotation(unit: UnitInput, full_frame_s: float) -> None:
    """Print the time to annotate the unit's clip, and what full-frame renders would have cost."""
    from pipeline.pstudio.settings import PstudioConfig
    from pipeline.pstudio.tracks import candidate_clip
    from pipeline.settings.run_config import RunConfig
    from pipeline.sources import RunChoices

    config = RunConfig()
    start = time.perf_counter()
    clip = candidate_clip(unit, config.section(PstudioConfig), RunChoices.of(config, "pstudio"))
    elapsed = time.perf_counter() - start
    print(
        f"annotate one {FRAMES}-frame clip: {elapsed:.1f} s ({1000 * elapsed / FRAMES:.0f} ms/frame), "
        f"{clip.num_tracks} candidate tracks, visible {clip.visibility.mean():.0%} of (track, frame) pairs"
    )
    estimate = 2 * FRAMES * full_frame_s
    print(
        f"  (both passes over {FRAMES} frames with full-frame renders: about {estimate:.0f} s of rendering)"
    )


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
    from pipeline.pstudio.records import Gaussians

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
    _walk(means, quaternions, local, local_normals)
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


def _walk(means: np.ndarray, quaternions: np.ndarray, local: np.ndarray, local_normals: np.ndarray) -> None:
    """Into ``means`` [T, N, 3] and ``quaternions`` [T, N, 4]: the people (the first PEOPLE x K
    Gaussians, ``local`` [K, 3] points of one person, facing ``local_normals``) walking half a circle
    over the T frames."""
    frames, per_person = len(means), len(local)
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


def _cameras(count: int = CAMERAS) -> Views:
    from pipeline.pstudio.records import Views

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
    import cv2

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


def beam_input(setup: UnitSetup, folder: str, groups: int) -> list[str]:
    """``groups`` whole groups of ``CAMERAS_PER_GROUP`` cameras in ``folder``: the first cameras of as
    few sequences as hold them, each the setup's sequence under a name of its own
    (``<sequence>_<k>``): its ``data/`` and ``params.npz`` folders made of symbolic links to the
    files and folders of the setup's (a linked folder would not be listed: Beam's listing does not
    enter one). Returns the ``pipeline.run`` arguments, the cameras chosen by ``pstudio.cameras``."""
    from pipeline.pstudio.units import CAMERAS_PER_GROUP as GROUP

    cameras = CAMERAS_QUICK if setup.size == "quick" else CAMERAS_FULL
    sequences = -(-groups // (cameras // GROUP))
    per_sequence = -(-groups // sequences)
    for k in range(sequences):
        for kind in ("data", os.path.join("output", EXPERIMENT)):
            original = os.path.join(setup.input_root, kind, SEQUENCE)
            named = os.path.join(folder, kind, f"{SEQUENCE}_{k}")
            os.makedirs(named)
            for name in os.listdir(original):
                os.symlink(os.path.join(original, name), os.path.join(named, name))
    chosen = ",".join(str(camera) for camera in range(per_sequence * GROUP))
    return ["--input", folder, "--set", f"pstudio.cameras={chosen}"]
