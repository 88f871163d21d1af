"""DriveTrack's benchmark entry. Unit: one synthetic Waymo v2 segment's cameras FRONT, FRONT_LEFT and
FRONT_RIGHT at 1920x1280 in the real Parquet schema, with the TOP lidar 64x2650 and 4 short-range
lidars: the group the graph annotates together (one read of the lidar). Default size: 30 frames,
extrapolated to 3 x 199 camera frames; ``--full``: 199 frames. Micro: the occlusion decision for one
1920x1280 frame, ours against the DriveTrack generator's.

Inputs (``prepare``): the segment is written by the sample world's writer
(``pipeline/drivetrack/sample/waymo_world.py``). Full size: 199 frames (20 s at 10 Hz); the cameras' focal is
2055 px (the scene is ray cast at 480x320, resized up and given film grain so the JPEGs weigh about
what photographs do; the pipeline only passes them through); the TOP lidar's range image has
per-pixel poses and camera projections; and, as in real ``lidar`` and ``lidar_camera_projection``
files, the four short-range lidars (FRONT, SIDE_LEFT, SIDE_RIGHT, REAR, 200 x 600 each, no returns)
are in the same files. Real segments also hold SIDE_LEFT and SIDE_RIGHT camera images (not written
here: about 400 more JPEGs in ``camera_image``).

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

Rules: the units run under the release's rules (``rules=release``: what regenerating the release
costs); each 1-worker unit runs once more under the refined rules (``rules=refined``, a plain run's:
the refined visibility and undistorted frames), and once more with the refined visibility alone
(Waymo's frames kept, ``drivetrack.undistort_frames=false``), each time printed beside the unit's
(``UnitSetup.variants``); the table's JSON holds the peak memory of each (``release``, ``refined``,
``refined without undistorted frames``).

Beam (``--beam``, ``beam_input``): the segment's files hard-linked under other segment names, one
segment a group.

Warm-up: each process runs its unit once before the timed runs (``extra["warm_up"]``), so that the
timed runs are a worker's steady state, as in a run of many units: what only the first unit of a
process pays (numba's cache loads, about 0.5 s; under the refined rules also open3d's import, 1-1.6
s with the packages it imports) is printed apart and not counted (the extrapolation would carry it
6.6 times over).

Floor (``floor``): the columns the units read of every component file of the segment, streamed
with pyarrow 8 rows at a time as the reader does; the group cameras' JPEGs decoded to BGR
(``cv2.imdecode``, as the undistortion does); the TOP lidar's range images of ``lidar``,
``lidar_pose`` and ``lidar_camera_projection`` turned into arrays [H, W, C], once.

Micro (``micro``): ours is the nearest lidar point of the four integer pixels around each track
point; the generator's a dense NearestNDInterpolator depth map of the whole image, then the max of
the four pixels; on the same lidar points and track points, with the agreement of the decisions.

The pipeline's modules are imported inside the functions, so that a floor process imports only
what its floor reads.
"""

from __future__ import annotations

import functools
import os
import time

import numpy as np

from pipeline.core.benchmark import UnitSetup, wall_and_cpu

# Per input frame on one core; the peak memory of the unit's process.
TARGETS = {"ms_per_frame": 150.0, "peak_rss_gib": 2.5}
RELEASE_SHAPE = (1024, (24, 199))  # the release's candidates per clip, (fewest, most) frames per clip
FIXED_IN_WORK = ()  # nothing a repeated run pays again: the unit runs once

SEGMENT = "1000000000000000001_0_000_20_000"
FULL: dict = {
    "frames": 199,
    "width": 1920,
    "height": 1280,
    "columns": 2650,
    "short_range": (200, 600),
    "scale": 4,
}
DEFAULT = dict(FULL, frames=30)
QUICK: dict = {"frames": 30, "width": 480, "height": 320, "columns": 900, "short_range": (20, 60), "scale": 2}
FOCAL_AT_1920 = 2055.0
IMAGE_NOISE = 6.0
VERSION = "3"  # 2: the sample writer's lens distortion and rolling shutter; 3: side-camera vehicles
# TAPVid-3D's 2457 DriveTrack clips come from 250 Waymo segments (542 of their 750
# (segment, camera) pairs hold a released clip); the pipeline runs every (segment, camera) pair.
SEGMENTS = 250
RELEASE_CLIPS = 2457  # the release's DriveTrack clips, from those segments
CAMERAS = 3
WIDTH, HEIGHT, FOCAL = 1920, 1280, 2055.0  # the micro-benchmark's frame


@functools.cache
def _shape(pedestrian: bool):
    from pipeline.drivetrack.sample import driving_world as driving

    return driving.pedestrian_mesh() if pedestrian else driving.car_mesh()


def bench_world():
    """A street for 20 s: same-direction traffic, oncoming traffic, parked cars, a pedestrian."""
    from pipeline.drivetrack.sample import driving_world as driving

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


def prepare(workdir: str, size: str) -> UnitSetup:
    """The segment of ``size`` written under ``workdir`` (once), and its unit."""
    sizes = {"quick": QUICK, "default": DEFAULT, "full": FULL}[size]
    folder = os.path.join(workdir, f"segment_{size}")
    written = _write_segment(folder, size, sizes)
    return UnitSetup(
        source="drivetrack",
        input_root=folder,
        units=[[[SEGMENT, camera] for camera in range(1, CAMERAS + 1)]],
        overrides=["rules=release"],
        frames=CAMERAS * sizes["frames"],
        description=_description(folder, sizes, written),
        full_units=SEGMENTS,
        full_clips=RELEASE_CLIPS,
        full_units_note=(
            f"{SEGMENTS} segments of {CAMERAS} cameras: the release's 2457 clips come from 250 segments "
            "(3.3 clips per camera); each priced like this one"
        ),
        size=size,
        extrapolate_frames=CAMERAS * FULL["frames"] if size == "default" else None,
        variants={
            "the refined rules": ["rules=refined"],
            "the refined visibility alone": ["rules=refined", "drivetrack.undistort_frames=false"],
        },
        rule_sets={
            "refined": "the refined rules",
            "refined without undistorted frames": "the refined visibility alone",
        },
        extra={"warm_up": True},
        notes=[
            f"measured on a {sizes['frames']}-frame segment with the full segment's sensors and image "
            f"sizes; the {FULL['frames']}-frame segment is {CAMERAS} x {FULL['frames']} camera frames x "
            "the per-frame cost (extrapolated); its clips cover 3.7 clip frames per camera frame, the "
            "full segment's 3.6 (2026-11-23)"
        ]
        if size == "default"
        else [],
    )


def _write_segment(folder: str, size: str, sizes: dict) -> float:
    """The street's segment at ``sizes`` written into ``folder`` unless it is there; the seconds
    spent."""
    from pipeline.drivetrack.sample import waymo_world as waymo
    from pipeline.io.write_once import write_once

    focal = FOCAL_AT_1920 * sizes["width"] / 1920
    models = waymo.camera_models(
        sizes["width"], sizes["height"], np.array([focal, focal, sizes["width"] / 2, sizes["height"] / 2])
    )
    version = f"{VERSION}-{sizes['frames']}f"  # a folder of other sizes is written again
    if not os.path.exists(os.path.join(folder, f".complete-v{version}")):
        print(f"writing the {size} segment (once; later runs reuse it) ...", flush=True)
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
    return time.perf_counter() - started


def _description(folder: str, sizes: dict, written: float) -> list[str]:
    """The setup's description: the segment's files, and what a unit is."""
    jpeg_mib = os.path.getsize(os.path.join(folder, "camera_image", f"{SEGMENT}.parquet")) / 2**20
    jpeg_kib = jpeg_mib * 1024 / (3 * sizes["frames"])
    files_mib = (
        sum(os.path.getsize(os.path.join(root, name)) for root, _, names in os.walk(folder) for name in names)
        / 2**20
    )
    short = "x".join(map(str, sizes["short_range"]))
    return [
        f"one Waymo v2 segment, {sizes['frames']} frames; cameras FRONT, FRONT_LEFT, FRONT_RIGHT at "
        f"{sizes['width']}x{sizes['height']} (camera_image file {jpeg_mib:.0f} MiB, {jpeg_kib:.0f} KiB "
        f"per JPEG); TOP lidar "
        f"64x{sizes['columns']} + 4 short-range lidars {short} (no returns); {files_mib:.0f} MiB of "
        f"Parquet" + (f"; written in {written:.0f} s" if written > 1 else ""),
        f"unit = the segment's {CAMERAS} (segment, camera) units as the graph groups them (one read "
        "of the lidar); a frame = one camera's frame; the scaling set repeats the group (same input, "
        "separate outputs)",
    ]


def measure_fixed_cost(spec: dict, config) -> dict:
    """Nothing apart: the unit's warm-up run (``extra["warm_up"]``) pays what only a worker's first
    unit pays (numba's cache loads, open3d's import under the refined rules), before the timed runs."""
    return {}


def floor(spec: dict) -> dict:
    """The read+decode floor of the unit's group of cameras (the module's docstring)."""
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

    wall, cpu = wall_and_cpu(read)
    return {"floor_s": wall, "floor_cpu_s": cpu, "floor_frames": frames}


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


def unit_of(fields: list):
    """The SegmentCamera of a spec's JSON fields."""
    from pipeline.drivetrack.units import SegmentCamera

    return SegmentCamera(*fields)


def micro(frames: int) -> None:
    """Print the occlusion-decision timings, ours and the generator's, over ``frames`` frames."""
    from pipeline.core.visibility import passes_relative_depth_test
    from pipeline.drivetrack.visibility import dense_nearest_depth, max4_from_dense, nearest_depth_max4

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


def beam_input(setup: UnitSetup, folder: str, groups: int) -> list[str]:
    """``groups`` segments in ``folder``: each component file of the setup's segment hard-linked under
    as many segment names (the segment's context number counted up), each segment a group of its
    three cameras. The reader takes a segment's name from its files' names and never reads the
    ``key.segment_context_name`` column. Returns the ``pipeline.run`` arguments."""
    context, rest = SEGMENT.split("_", 1)
    names = [f"{int(context) + k}_{rest}" for k in range(groups)]
    for component in os.listdir(setup.input_root):
        if not os.path.isdir(os.path.join(setup.input_root, component)):
            continue  # write_once's marker
        os.makedirs(os.path.join(folder, component))
        for name in names:
            os.link(
                os.path.join(setup.input_root, component, f"{SEGMENT}.parquet"),
                os.path.join(folder, component, f"{name}.parquet"),
            )
    return ["--input", folder]
