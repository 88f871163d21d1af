"""DriveTrack benchmark inputs (``prepare``): one synthetic Waymo Open v2 segment at the real
sensors' sizes, written in the real Parquet schema by the sample world's writer
(``pipeline/samples/waymo_world.py``).

Full size (``--full``): 199 frames (20 s at 10 Hz); FRONT, FRONT_LEFT and FRONT_RIGHT cameras at 1920x1280
(focal 2055 px; the scene is ray cast at 480x320, resized up and given film grain so the JPEGs
weigh about what photographs do; the pipeline only passes them through); TOP lidar range image
64 x 2650 with per-pixel poses and camera projections; and, as in real ``lidar`` and
``lidar_camera_projection`` files, the four short-range lidars (FRONT, SIDE_LEFT, SIDE_RIGHT,
REAR, 200 x 600 each, no returns) in the same files. Real segments also hold SIDE_LEFT and
SIDE_RIGHT camera images (not written here: about 400 more JPEGs in ``camera_image``).

Default size (``make bench``): the same street, sensors and image sizes, for the first 30 frames
(3 s; a clip needs 24 contiguous frames), written in a minute or two instead of ten: every per-frame
cost (a 1920x1280 JPEG, a 64 x 2650 TOP range image with its poses and projections, the
short-range lidars' rows) is the full segment's, only the frame count differs; the report
extrapolates the unit to 3 x 199 camera frames linearly. Its clips cover 3.7 clip frames per
camera frame, the full segment's 3.6 (each clip frame costs a few ms).

The street: the ego drives 158 m on a nearly straight road past traffic in both directions
and parked cars, with a service road on each side where two cars keep pace, so the FRONT
camera's unit yields several clips and each side camera's a few (the release's FRONT units
average 6.3 clips, every unit 3.3: its side units 1.8).
"""

from __future__ import annotations

import functools
import os
import time

import numpy as np

from benchmarks.units import UnitSetup

SEGMENT = "1000000000000000001_0_000_20_000"
FULL = {"frames": 199, "width": 1920, "height": 1280, "columns": 2650, "short_range": (200, 600), "scale": 4}
DEFAULT = dict(FULL, frames=30)
QUICK = {"frames": 30, "width": 480, "height": 320, "columns": 900, "short_range": (20, 60), "scale": 2}
FOCAL_AT_1920 = 2055.0
IMAGE_NOISE = 6.0
VERSION = "3"  # 2: the sample writer's lens distortion and rolling shutter; 3: side-camera vehicles
# TAPVid-3D's 2457 DriveTrack clips come from 250 Waymo segments (542 of their 750
# (segment, camera) pairs hold a released clip); the pipeline runs every (segment, camera) pair.
SEGMENTS = 250
CAMERAS = 3


@functools.cache
def _shape(pedestrian: bool):
    from pipeline.samples import driving_world as driving

    return driving.pedestrian_mesh() if pedestrian else driving.car_mesh()


def bench_world():
    """A street for 20 s: same-direction traffic, oncoming traffic, parked cars, a pedestrian."""
    from pipeline.samples import driving_world as driving

    class Actor(driving.Actor):
        """The sample's actor with its mesh built once (``Actor.shape`` builds it at every call,
        e.g. for each pose; the meshes are never modified): the same files, written faster."""

        def shape(self):
            return _shape(self.pedestrian)

    actor = Actor
    grey = (0.55, 0.55, 0.6)
    vehicles = [
        # id (22 characters like Waymo's), start (x, y), heading, speed m/s
        ("lead_same_lane_AAAAAAA", (20.0, 0.0), 0.0, 8.0),
        ("left_lane_slower_BBBBB", (14.0, 3.6), 0.0, 7.6),
        ("right_lane_faster_CCCC", (30.0, -3.6), 0.0, 9.0),
        ("left_lane_far_DDDDDDDD", (48.0, 3.6), 0.0, 6.5),
        ("oncoming_first_EEEEEEE", (95.0, 7.4), np.pi, 10.0),
        ("oncoming_second_FFFFFF", (190.0, 7.2), np.pi, 9.0),
        ("oncoming_third_GGGGGGG", (255.0, 7.4), np.pi, 8.0),
        ("parked_right_1_HHHHHHH", (45.0, -7.0), 0.02, 0.0),
        ("parked_right_2_IIIIIII", (85.0, -7.2), -0.03, 0.0),
        ("parked_right_3_JJJJJJJ", (125.0, -7.0), 0.0, 0.0),
        ("parked_left_1_KKKKKKKK", (70.0, 10.5), 0.01, 0.0),
        ("parked_left_2_LLLLLLLL", (140.0, 10.8), 0.0, 0.0),
        # On a service road on each side, keeping pace with the ego: the FRONT_LEFT and FRONT_RIGHT
        # cameras' vehicles (the release's side-camera units average 1.8 clips).
        ("service_left_near_NNNN", (12.0, 13.5), 0.0, 8.0),
        ("service_left_far_OOOOO", (20.0, 13.5), 0.0, 8.1),
        ("service_right_near_PPP", (12.0, -13.5), 0.0, 8.0),
        ("service_right_far_QQQQ", (20.0, -13.5), 0.0, 7.9),
    ]
    actors = [
        actor(name, 1, start, heading, speed, tuple(np.roll(grey, i) * (0.6 + 0.04 * i)))
        for i, (name, start, heading, speed) in enumerate(vehicles)
    ]
    actors.append(actor("pedestrian_walker_MMMM", 2, (60.0, -5.5), np.pi / 2, 1.2, (0.9, 0.5, 0.4), True))
    return driving.DrivingWorld(actors=actors, ego=driving.Ego(speed=8.0, yaw_rate=0.001))


def prepare(workdir: str, quick: bool, full: bool = False) -> UnitSetup:
    tag = "quick" if quick else "full" if full else "default"
    sizes = {"quick": QUICK, "default": DEFAULT, "full": FULL}[tag]
    from pipeline.samples import waymo_world as waymo
    from pipeline.samples.write_once import write_once

    focal = FOCAL_AT_1920 * sizes["width"] / 1920
    models = waymo.camera_models(
        sizes["width"], sizes["height"], np.array([focal, focal, sizes["width"] / 2, sizes["height"] / 2])
    )
    folder = os.path.join(workdir, f"segment_{tag}")
    version = f"{VERSION}-{sizes['frames']}f"  # a folder of other sizes is written again
    if not os.path.exists(os.path.join(folder, f".complete-v{version}")):
        print(f"writing the {tag} segment (once; later runs reuse it) ...", flush=True)
    started = time.perf_counter()
    write_once(
        folder,
        version,
        lambda staging: waymo.write_split(
            staging,
            SEGMENT,
            sizes["frames"],
            bench_world(),
            models=models,
            lidar_columns=sizes["columns"],
            short_range_lidars=sizes["short_range"],
            render_scale=sizes["scale"],
            image_noise=IMAGE_NOISE,
            keep_points=False,
        ),
    )
    written = time.perf_counter() - started
    jpeg_mib = os.path.getsize(os.path.join(folder, "camera_image", f"{SEGMENT}.parquet")) / 2**20
    jpeg_kib = jpeg_mib * 1024 / (3 * sizes["frames"])
    files_mib = (
        sum(os.path.getsize(os.path.join(root, name)) for root, _, names in os.walk(folder) for name in names)
        / 2**20
    )
    short = "x".join(map(str, sizes["short_range"]))
    return UnitSetup(
        source="drivetrack",
        input_root=folder,
        units=[[[SEGMENT, camera] for camera in range(1, CAMERAS + 1)]],
        overrides=[],
        frames=CAMERAS * sizes["frames"],
        description=[
            f"one Waymo v2 segment, {sizes['frames']} frames; cameras FRONT, FRONT_LEFT, FRONT_RIGHT at "
            f"{sizes['width']}x{sizes['height']} (camera_image file {jpeg_mib:.0f} MiB, {jpeg_kib:.0f} KiB "
            f"per JPEG); TOP lidar "
            f"64x{sizes['columns']} + 4 short-range lidars {short} (no returns); {files_mib:.0f} MiB of "
            f"Parquet" + (f"; written in {written:.0f} s" if written > 1 else ""),
            f"unit = the segment's {CAMERAS} (segment, camera) units as the graph groups them (one read "
            "of the lidar); a frame = one camera's frame; the scaling set repeats the group (same input, "
            "separate outputs)",
        ],
        full_units=SEGMENTS,
        full_units_note=(
            f"{SEGMENTS} segments of {CAMERAS} cameras: the release's 2457 clips come from 250 segments "
            "(3.3 clips per camera); each priced like this one"
        ),
        size=tag,
        extrapolate_frames=CAMERAS * FULL["frames"] if tag == "default" else None,
        notes=[
            f"measured on a {sizes['frames']}-frame segment with the full segment's sensors and image "
            f"sizes; the {FULL['frames']}-frame segment is {CAMERAS} x {FULL['frames']} camera frames x "
            "the per-frame cost (extrapolated); its clips cover 3.7 clip frames per camera frame, the "
            "full segment's 3.6 (2026-11-23)"
        ]
        if tag == "default"
        else [],
    )


def measure_fixed_cost(spec: dict, config) -> dict:
    """Called by ``benchmarks.worker`` before the runs: numba's first dispatch of the camera model
    and of the occlusion and depth lookups (loading them from its cache), once per worker process
    like the imports, so not a unit's cost (reported, not counted; the extrapolation would carry it
    6.6 times over). The first camera's records are read first, untimed, to call the camera model
    with the types a unit calls it with. first_calls_s / first_calls_cpu_s."""
    from pipeline.drivetrack.annotate import load_units, unit_camera
    from pipeline.drivetrack.visibility import camera_occluded_lidar, nearest_depth_max4

    segment, camera = spec["unit"][0]
    (unit,) = load_units(spec["input_root"], segment, [camera])
    rng = np.random.default_rng(0)
    size = np.array([unit.calibration.width, unit.calibration.height], np.float64)
    world = unit.frames.world_from_vehicle_at_exposure[0][:3, 3] + rng.normal(0, 20.0, (64, 3))
    pixels, depth = rng.uniform(0, size, (64, 2)), rng.uniform(5.0, 50.0, 64)
    wall, cpu = time.perf_counter(), time.process_time()
    unit_camera(unit, config).project(0, world)
    camera_occluded_lidar(pixels, depth, config.drivetrack.occlusion_margin)
    nearest_depth_max4(pixels, depth, pixels[:4], int(size[0]), int(size[1]))
    return {"first_calls_s": time.perf_counter() - wall, "first_calls_cpu_s": time.process_time() - cpu}
