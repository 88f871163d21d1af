"""The TOP lidar: Waymo range images to 3D points and surface normals (the dataset's own convention),
and what the lidar says about a unit's clips, read in one pass over the frames they need (shared by
the cameras of a segment annotated together): per camera frame, the depth samples the occlusion
test reads and each object's points; for the refined visibility, each object's surface and the
footprints of the sweeps around each frame (``RefinedEvidence``).

Normals come from each pixel's neighbours on the same beam (columns) and in the same column (rows),
fixed by the scan, not by which other points exist, so a normal never depends on a point cloud's
density or on where the world's origin lies (a nearest-neighbour estimate flips on single scan
lines). A lidar point is attached to its object through the lidar box (same capture time as the
points); the clip later carries it to each frame with the camera-synced box."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numba
import numpy as np

from pipeline.core.errors import InputError
from pipeline.core.geometry import invert_se3, rotation_from_roll_pitch_yaw, transform_points
from pipeline.drivetrack.camera_model import UnitCamera
from pipeline.drivetrack.cell_grid import CellGrid
from pipeline.drivetrack.footprints import (
    BoxMotions,
    FrameFootprints,
    FrameOccluders,
    SweepFootprints,
    field_edge_rows,
    frame_footprints,
    likely_reach,
    moved,
    object_regions,
    row_spacings,
    serving_returns,
    sweep_footprints,
)
from pipeline.drivetrack.object_surface import consistent_triangles, surface_triangles
from pipeline.drivetrack.objects import ObjectRun, box_poses, inside_box
from pipeline.drivetrack.parallax import camera_occluded_lidar
from pipeline.drivetrack.records import LidarCalibration, LidarFrame, UnitInput
from pipeline.drivetrack.visibility import depth_grid


def beam_inclinations(calibration: LidarCalibration, height: int, what: str = "lidar") -> np.ndarray:
    """Inclination per range-image row [H] in radians, row 0 the highest beam.

    Uses the stored per-beam values when present, else a uniform spread between min and max.
    ``what`` names the range image in errors.
    """
    if calibration.inclinations is not None:
        if calibration.inclinations.shape != (height,):
            raise InputError(
                f"{what}: lidar_calibration holds {calibration.inclinations.size} beam inclinations "
                f"for a range image of {height} rows"
            )
        inclinations = calibration.inclinations
    else:
        rows = np.arange(height)
        span = calibration.inclination_max - calibration.inclination_min
        inclinations = calibration.inclination_min + (rows + 0.5) / height * span
    return inclinations[::-1].astype(np.float64)


def sensor_points(
    range_image: np.ndarray, lidar_to_vehicle: np.ndarray, inclinations: np.ndarray
) -> np.ndarray:
    """Every pixel of a range image [H, W] as a point [H, W, 3] in the lidar frame (whatever its
    range); column j looks along azimuth ``(2 (W - j - 0.5) / W - 1) pi - atan2(E[1,0], E[0,0])``."""
    width = range_image.shape[1]
    az_correction = np.arctan2(lidar_to_vehicle[1, 0], lidar_to_vehicle[0, 0])
    ratio = (width - np.arange(width) - 0.5) / width
    azimuth = (2.0 * ratio - 1.0) * np.pi - az_correction
    incl, az = inclinations[:, None], azimuth[None, :]
    r = range_image.astype(np.float64)
    return np.stack([r * np.cos(az) * np.cos(incl), r * np.sin(az) * np.cos(incl), r * np.sin(incl)], -1)


def range_image_to_vehicle(
    range_image: np.ndarray, lidar_to_vehicle: np.ndarray, inclinations: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Points of the returns with range > 0 in the vehicle frame at firing time.

    Args:
      range_image: [H, W] ranges in metres (<= 0 means no return).
      lidar_to_vehicle: [4, 4] lidar extrinsic.
      inclinations: [H] per row, row 0 the highest beam (see ``beam_inclinations``).
    Returns:
      points [M, 3] in row-major order of the kept pixels, and kept [H, W] bool.
    """
    kept = range_image > 0
    sensor = sensor_points(range_image, lidar_to_vehicle, inclinations)[kept]
    return sensor @ lidar_to_vehicle[:3, :3].T + lidar_to_vehicle[:3, 3], kept


@dataclasses.dataclass(frozen=True)
class TopSweep:
    """A TOP sweep in the world: points [M, 3] of the kept pixels (range > 0, row-major), kept
    [H, W], their flat pixel indices [M] (row * W + column), and what their normals need: the
    lidar-frame grid [H, W, 3] of every pixel, the ranges [H, W], the world-from-lidar rotations
    [P, 3, 3] of the sweep's poses (world-from-vehicle @ vehicle-from-lidar) with the pose of each
    kept point [M] (``kept_poses``)."""

    points: np.ndarray
    kept: np.ndarray
    pixels: np.ndarray
    grid: np.ndarray
    ranges: np.ndarray
    world_from_lidar: np.ndarray
    pose_of_point: np.ndarray

    def normals(self, index: np.ndarray) -> np.ndarray:
        """Unit world-frame normals [K, 3], facing the lidar, of the kept points ``index`` [K]."""
        return self.to_world(index, range_image_normals(self.grid, self.ranges, self.pixels[index]))

    def beams(self, index: np.ndarray) -> np.ndarray:
        """Unit world-frame directions [K, 3] from the lidar to the kept points ``index`` [K]."""
        pixels = self.pixels[index]
        return self.to_world(index, self.grid.reshape(-1, 3)[pixels] / self.ranges.ravel()[pixels, None])

    def to_world(self, index: np.ndarray, vectors: np.ndarray) -> np.ndarray:
        """Lidar-frame directions [K, 3] at the kept points ``index`` [K] turned to the world."""
        vectors = np.ascontiguousarray(vectors, np.float64)
        return turned(vectors, self.world_from_lidar, self.pose_of_point[index])


def kept_poses(
    pixel_pose: np.ndarray, kept: np.ndarray, what: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World-from-vehicle rotations [P, 3, 3] and translations [P, 3] of the poses the kept pixels
    [H, W] were fired at, and the pose of each kept pixel [M] (row-major), from the pixel poses
    [H, W, 6]. Where each column holds one pose (the TOP lidar fires a column at once), P is the
    number of columns with a kept pixel: the same numbers as per pixel, H times fewer; else P = M."""
    if np.all(pixel_pose == pixel_pose[:1]):
        used = kept.any(axis=0)
        poses = pixel_pose[0, used].astype(np.float64)  # [C, 6], the columns with a kept pixel
        pose_of_point = (np.cumsum(used) - 1)[np.flatnonzero(kept) % kept.shape[1]]
    else:
        poses = pixel_pose[kept].astype(np.float64)
        pose_of_point = np.arange(len(poses))
    if not np.isfinite(poses).all():
        raise InputError(f"{what}: per-pixel lidar pose contains NaN or infinity")
    rotation = rotation_from_roll_pitch_yaw(poses[:, 0], poses[:, 1], poses[:, 2])
    return rotation, np.ascontiguousarray(poses[:, 3:6]), pose_of_point


@numba.njit(cache=True, nogil=True)
def posed_points(points, rotations, translations, pose_of_point):
    """Points [M, 3] moved by their poses: rotations[k] @ p + translations[k], k = pose_of_point[m]
    ([P, 3, 3], [P, 3], [M]), without gathering a rotation per point. Each row's products are
    summed as NumPy's einsum("mij,mj->mi") sums them, (x + z) + y: the same bits (NumPy 2.4's
    order; tests/drivetrack/test_shortcuts.py compares with einsum itself)."""
    out = np.empty_like(points)
    for m in range(points.shape[0]):
        k = pose_of_point[m]
        x, y, z = points[m, 0], points[m, 1], points[m, 2]
        for i in range(3):
            rotated = (rotations[k, i, 0] * x + rotations[k, i, 2] * z) + rotations[k, i, 1] * y
            out[m, i] = rotated + translations[k, i]
    return out


@numba.njit(cache=True, nogil=True)
def turned(vectors, rotations, which):
    """Vectors [K, 3] turned by rotations [R, 3, 3], rotations[which[k]] @ vectors[k] (which [K]):
    the bits of NumPy's einsum("kij,kj->ki") over the gathered rotations, summed as ``posed_points``
    sums."""
    out = np.empty_like(vectors)
    for m in range(vectors.shape[0]):
        k = which[m]
        x, y, z = vectors[m, 0], vectors[m, 1], vectors[m, 2]
        for i in range(3):
            out[m, i] = (rotations[k, i, 0] * x + rotations[k, i, 2] * z) + rotations[k, i, 1] * y
    return out


def top_lidar_world_points(
    range_image: np.ndarray,
    pixel_pose: np.ndarray,
    calibration: LidarCalibration,
    what: str,
) -> TopSweep:
    """The world points of a TOP range image [H, W] with its pixel poses [H, W, 6].

    A pixel pose is (roll, pitch, yaw, x, y, z): the vehicle's pose in the world when that pixel
    was fired (the TOP lidar's rolling-shutter correction), rotation Rz(yaw) Ry(pitch) Rx(roll).
    """
    if not np.isfinite(range_image).all():
        raise InputError(f"{what}: range image contains NaN or infinity")
    if pixel_pose.shape[:2] != range_image.shape:
        raise InputError(
            f"{what}: lidar_pose shape {pixel_pose.shape[:2]} != range image {range_image.shape}"
        )
    extrinsic = calibration.lidar_to_vehicle
    inclinations = beam_inclinations(calibration, range_image.shape[0], what)
    kept = range_image > 0
    if not kept.any():
        raise InputError(f"{what}: no returns (every range <= 0)")
    grid = sensor_points(range_image, extrinsic, inclinations)
    points = grid[kept] @ extrinsic[:3, :3].T + extrinsic[:3, 3]
    rotations, translations, pose_of_point = kept_poses(pixel_pose, kept, what)
    world = posed_points(points, rotations, translations, pose_of_point)
    ranges = range_image.astype(np.float64)
    world_from_lidar = rotations @ extrinsic[:3, :3]
    return TopSweep(world, kept, np.flatnonzero(kept), grid, ranges, world_from_lidar, pose_of_point)


# A neighbour lies on the same surface when its range differs by at most this fraction of the
# pixel's own: a plane seen at 85 degrees incidence differs by ~8% between neighbouring columns of
# the TOP lidar at any range, a car in front of a wall by far more.
MAX_RANGE_JUMP = 0.2


def range_image_normals(points: np.ndarray, ranges: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """Unit normals [K, 3] facing the lidar at the range image's pixels [K] (flat indices), in the
    frame of ``points`` [H, W, 3] (each pixel's return, lidar at the origin), for ranges [H, W]
    (<= 0: no return): the cross product of the offsets to a row neighbour and a column neighbour
    on the same surface. A pixel lacking either gets the direction back to the lidar (which saw the
    surface from there)."""
    points, ranges = np.ascontiguousarray(points, np.float64), np.ascontiguousarray(ranges, np.float64)
    normals = np.empty((len(pixels), 3))
    _normals(points, ranges, np.asarray(pixels, np.int64), MAX_RANGE_JUMP, normals)
    return normals


@numba.njit(cache=True, nogil=True)
def _normals(points, ranges, pixels, max_jump, normals):
    """normals [K, 3] (``range_image_normals``) of pixels [K]. Each pixel's neighbour along the rows
    and along the columns: either side, the nearer in range (the earlier on ties), on the same
    surface (a range step of at most ``max_jump`` of its own range); the image's edges have none
    beyond them (the columns' seam joins the sweep's first and last instants). Sums in NumPy's order
    (np.linalg.norm's (x + y) + z, einsum's (x + z) + y): the bits of the array expressions."""
    height, width = ranges.shape
    offsets = np.empty((2, 3))
    for k in range(len(pixels)):
        row, col = pixels[k] // width, pixels[k] % width
        here = ranges[row, col]
        both = True
        for axis in range(2):
            best_jump = np.inf
            offsets[axis, 0] = offsets[axis, 1] = offsets[axis, 2] = 0.0
            for step in (-1, 1):
                r, c = (row + step, col) if axis == 0 else (row, col + step)
                there = ranges[r, c] if 0 <= r < height and 0 <= c < width else 0.0
                jump = abs(there - here)
                if there > 0 and here > 0 and jump <= max_jump * here and jump < best_jump:
                    for i in range(3):
                        offsets[axis, i] = points[r, c, i] - points[row, col, i]
                    best_jump = jump
            both = both and best_jump < np.inf
        ax, ay, az = offsets[0, 0], offsets[0, 1], offsets[0, 2]
        bx, by, bz = offsets[1, 0], offsets[1, 1], offsets[1, 2]
        nx, ny, nz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
        length = np.sqrt((nx * nx + ny * ny) + nz * nz)
        px, py, pz = points[row, col, 0], points[row, col, 1], points[row, col, 2]
        distance = max(np.sqrt((px * px + py * py) + pz * pz), 1e-12)
        tx, ty, tz = -px / distance, -py / distance, -pz / distance
        if both and length > 0:
            nx, ny, nz = nx / length, ny / length, nz / length
        else:
            nx, ny, nz = tx, ty, tz
        if (nx * tx + nz * tz) + ny * ty < 0:
            nx, ny, nz = -nx, -ny, -nz
        normals[k, 0], normals[k, 1], normals[k, 2] = nx, ny, nz


@dataclasses.dataclass(frozen=True)
class BodyPoints:
    """An object's lidar points in one camera frame's sweep (those inside its shrunk box), in the
    sweep's row-major order: points [K, 3] (box frame), normals [K, 3] unit normals facing the lidar
    (box frame), pixels [K] int64 range-image pixel (row * W + column) of each point, which with the
    frame's timestamp names the point."""

    points: np.ndarray
    normals: np.ndarray
    pixels: np.ndarray


@dataclasses.dataclass
class LidarEvidence:
    """Per camera frame: lidar depth samples in the image, and each object's body points.

    depth_uv[t]: [M, 2] pixels; depth_z[t]: [M] camera z; bodies[object][t]: the object's
    ``BodyPoints`` in frame t's sweep (absent: the frame's sweep was not read for it).
    """

    depth_uv: dict[int, np.ndarray]
    depth_z: dict[int, np.ndarray]
    bodies: dict[str, dict[int, BodyPoints]]
    depth_grids: dict[int, CellGrid | None] = dataclasses.field(default_factory=dict)
    refined: RefinedEvidence | None = None

    def depth_grid(self, t: int) -> CellGrid | None:
        """The lookup of frame t's depth pixels (``visibility.depth_grid``), built at the first clip
        that reads it."""
        if t not in self.depth_grids:
            self.depth_grids[t] = depth_grid(self.depth_uv[t])
        return self.depth_grids[t]


@dataclasses.dataclass(frozen=True)
class KeptSweep:
    """A TOP sweep as read, kept between the refined visibility's two passes over the lidar (the
    second places it in the world again, ``placed``): its range image [H, W] and pixel poses
    [H, W, 6] (where every row holds the same poses, one row broadcast: H times smaller), and per
    camera name the returns the lidar projects into it (bit-packed over the kept pixels [M])."""

    timestamp: int
    range_image: np.ndarray
    pixel_pose: np.ndarray
    in_camera: dict[int, np.ndarray]
    kept_count: int

    @staticmethod
    def of(lidar: LidarFrame, sweep: TopSweep, in_camera: dict[int, np.ndarray]) -> KeptSweep:
        """The sweep of ``lidar`` (placed as ``sweep``) as the cameras need it again: ``in_camera``,
        camera name -> [M] bool over the kept pixels (``seen_by_camera``)."""
        pose = lidar.pixel_pose
        if np.all(pose == pose[:1]):  # the TOP lidar fires a column at once
            pose = np.broadcast_to(pose[:1].copy(), pose.shape)
        else:
            pose = pose.copy()
        packed = {camera: np.packbits(seen) for camera, seen in in_camera.items()}
        return KeptSweep(lidar.timestamp, lidar.range_image.copy(), pose, packed, len(sweep.points))

    def placed(self, calibration: LidarCalibration, what: str) -> TopSweep:
        """The sweep in the world, as the first pass placed it (``top_lidar_world_points``)."""
        return top_lidar_world_points(self.range_image, self.pixel_pose, calibration, what)

    def seen_by(self, camera: int) -> np.ndarray:
        """[K] the kept-point indices of the returns the lidar projects into ``camera``."""
        return np.flatnonzero(np.unpackbits(self.in_camera[camera], count=self.kept_count))


@dataclasses.dataclass
class RefinedEvidence:
    """What the refined visibility reads of a camera's sweeps (``refined_visibility``), gathered by
    the first pass over the lidar: body_views[object][t]: [K, 3] unit directions (box frame) from
    each body point to the lidar of its sweep (the side of the surface the sweep saw);
    surfaces[object][t]: the object's surface in that sweep, (points [K, 3] box frame, triangles
    [M, 3]) (``object_surface``); labels: object id -> its footprints' label; the camera's pass and
    its objects' motions; sweeps: lidar timestamp -> ``KeptSweep`` (shared by the cameras of a pass).

    The second pass (``stream_occluders``) fills footprints[t]: source (-1, 0, 1) -> the footprints
    of the sweep of frame t + source seen in camera frame t (``footprints.frame_footprints``), and
    hands each frame's, once its sweeps are all in, joined (``FrameOccluders``) to the clips."""

    body_views: dict[str, dict[int, np.ndarray]]
    surfaces: dict[str, dict[int, tuple[np.ndarray, np.ndarray]]]
    labels: dict[str, int]
    item: CameraPass
    motions: BoxMotions
    sweeps: dict[int, KeptSweep]
    footprints: dict[int, dict[int, FrameFootprints]] = dataclasses.field(default_factory=dict)
    regions: dict[int, tuple[np.ndarray, np.ndarray]] = dataclasses.field(default_factory=dict)

    def frame_regions(self, t: int) -> tuple[np.ndarray, np.ndarray]:
        """The image regions of the objects the camera tracks at camera frame t
        (``footprints.object_regions``), found at the first sweep that serves the frame."""
        if t not in self.regions:
            boxes = [
                (run.world_from_box[t - run.start], run.lidar_boxes[t - run.start])
                for run in self.item.runs
                if run.start <= t < run.stop
            ]
            self.regions[t] = object_regions(self.item.camera, t, boxes)
        return self.regions[t]

    def settled(self, t: int) -> FrameOccluders:
        """Frame t's footprints, its sweeps all in, joined and binned; the parts and the frame's
        regions let go of."""
        self.regions.pop(t, None)
        return FrameOccluders(self.footprints.pop(t))


def depth_samples(
    world: np.ndarray, camera: UnitCamera, t: int, occlusion_margin: float, parallax_cleanup: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """Pixels [M, 2] in the stored frame t and camera depths [M] of the lidar points [P, 3]
    (world) that the camera sees: in view, and with ``parallax_cleanup`` not hidden from it by a
    nearer lidar point."""
    seen = camera.project(t, world)
    uv, z = seen.pixels[seen.in_view], seen.points[seen.in_view, 2]
    if not parallax_cleanup:
        return uv, z
    kept = ~camera_occluded_lidar(uv, z, occlusion_margin)
    return uv[kept], z[kept]


def box_points(
    points_vehicle: np.ndarray, box: np.ndarray, shrink: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Which points [P, 3] (vehicle frame) lie inside a lidar box [7] shrunk by ``shrink`` metres:
    their index [K], those points in the box frame [K, 3], and box_from_vehicle [4, 4]."""
    box_from_vehicle = invert_se3(box_poses(box))
    # Only points within ``reach`` (the circumscribed sphere's radius and a metre) of the centre in
    # x and y can be inside: the others are never carried into the box frame (same numbers).
    reach = np.linalg.norm(np.abs(box[3:6] - shrink)) / 2.0 + 1.0
    near = _near(points_vehicle, float(box[0]), float(box[1]), float(reach))
    local = transform_points(box_from_vehicle, points_vehicle[near])
    inside = inside_box(local, box[3:6], shrink)
    return near[inside], local[inside], box_from_vehicle


@numba.njit(cache=True, nogil=True)
def _near(points, x, y, reach):
    """[K] ascending indices of the points [P, 3] within ``reach`` of (x, y) in x and in y."""
    near = np.empty(len(points), np.int64)
    count = 0
    for i in range(len(points)):
        if abs(points[i, 0] - x) <= reach and abs(points[i, 1] - y) <= reach:
            near[count] = i
            count += 1
    return near[:count].copy()


@dataclasses.dataclass(frozen=True)
class CameraPass:
    """One camera's share of a pass over the lidar: its unit, the object runs it tracks, its
    camera model and the vehicle pose per camera frame [T, 4, 4] (``camera_model.frame_poses``)."""

    unit: UnitInput
    runs: list[ObjectRun]
    camera: UnitCamera
    world_from_frame: np.ndarray

    @property
    def needed(self) -> list[int]:
        """The camera frames its clips span, sorted."""
        return sorted({t for run in self.runs for t in range(run.start, run.stop)})


def gather_lidar_cameras(
    passes: list[CameraPass],
    shrink: float,
    occlusion_margin: float,
    *,
    parallax_cleanup: bool = True,
    refined: bool = False,
    depth: bool = True,
) -> list[LidarEvidence]:
    """One pass over the TOP lidar frames any of one segment's cameras needs, each frame decoded and
    placed in the world once for all of them: each camera's in-box points, its depth samples
    (``depth_samples``) unless ``depth`` is false (the refined visibility reads none), and with
    ``refined`` what the refined visibility reads of its own objects (``RefinedEvidence``; the
    footprints of the others come in a second pass over the sweeps kept, ``stream_occluders``)."""
    users = _users(passes)
    evidence = [LidarEvidence({}, {}, {run.object_id: {} for run in item.runs}) for item in passes]
    if not passes:
        return evidence
    kept: dict[int, KeptSweep] = {}  # shared by the cameras' refined evidence
    cameras = {item.unit.camera for item in passes}
    for item, found in zip(passes, evidence, strict=True):
        if refined:
            moving = BoxMotions(item.unit, item.world_from_frame)
            labels = {run.object_id: moving.label(run.object_id) for run in item.runs}
            surfaces: dict[str, dict[int, tuple[np.ndarray, np.ndarray]]]
            surfaces = {run.object_id: {} for run in item.runs}
            found.refined = RefinedEvidence(_per_object(item), surfaces, labels, item, moving, kept)
    first = passes[0].unit
    stamps = sorted(users)
    for stamp, lidar in zip(stamps, first.lidar_frames(stamps), strict=True):
        what = f"lidar/{first.segment} TOP frame {lidar.timestamp}"
        sweep = top_lidar_world_points(lidar.range_image, lidar.pixel_pose, first.lidar_calibration, what)
        seen = {camera: seen_by_camera(lidar.camera_projection, sweep.kept, camera) for camera in cameras}
        if refined:
            kept[stamp] = KeptSweep.of(lidar, sweep, seen)
            spacing = _spacing(first.lidar_calibration, lidar.range_image.shape[0], what)
        in_vehicle = _in_vehicle(sweep)
        for i, t in users[stamp]:
            frame = (t, seen[passes[i].unit.camera], sweep, in_vehicle(passes[i].world_from_frame[t]))
            depth_rule = (occlusion_margin, parallax_cleanup, depth)
            in_camera, bodies = _camera_frame(passes[i], evidence[i], *frame, shrink, *depth_rule)
            found_refined = evidence[i].refined
            if found_refined is not None:
                own = (in_camera, bodies, in_vehicle(passes[i].world_from_frame[t]))
                _refined_bodies(found_refined, t, sweep, spacing, *own)
    return evidence


def stream_occluders(
    evidence: list[LidarEvidence], consumers: list[Callable[[int, FrameOccluders], None]]
) -> None:
    """The refined visibility's second pass, over the sweeps its first kept (``gather_lidar_cameras``
    with ``refined``), each placed in the world again once for all the cameras: per camera, the
    footprints of each sweep in the frames it serves; each camera frame's, once the sweeps of the
    frame and of its neighbours are in, go to its camera's consumer (``consumers[i](t, occluders)``)
    and are let go of. Only a few frames' footprints are ever held."""
    refined = [_refined(found) for found in evidence]
    if not refined:
        return
    passes = [found.item for found in refined]
    first = passes[0].unit
    users = _users(passes)
    sweeps = refined[0].sweeps  # shared by the cameras of the pass
    for stamp in sorted(users):
        kept = sweeps.pop(stamp)
        what = f"lidar/{first.segment} TOP frame {kept.timestamp}"
        sweep = kept.placed(first.lidar_calibration, what)
        spacing = _spacing(first.lidar_calibration, kept.range_image.shape[0], what)
        in_vehicle = _in_vehicle(sweep)
        for i, t in users[stamp]:
            found = refined[i]
            in_camera = kept.seen_by(found.item.unit.camera)
            _sweep_footprints(found, t, sweep, spacing, in_camera, in_vehicle(found.item.world_from_frame[t]))
            if t - 1 in found.footprints:  # its sweeps t - 2, t - 1 and t are all in
                consumers[i](t - 1, found.settled(t - 1))
    for found, consume in zip(refined, consumers, strict=True):
        for t in sorted(found.footprints):
            consume(t, found.settled(t))


def _refined(found: LidarEvidence) -> RefinedEvidence:
    """A camera's refined evidence (``gather_lidar_cameras`` with ``refined`` gathers it)."""
    if found.refined is None:
        raise ValueError("the refined visibility's second pass needs gather_lidar_cameras(refined=True)")
    return found.refined


def seen_by_camera(projection: np.ndarray, kept: np.ndarray, camera: int) -> np.ndarray:
    """[M] bool over the kept pixels [H, W] of a sweep: those its lidar_camera_projection [H, W, 6]
    (camera name, u, v, twice) projects into ``camera``."""
    return ((projection[..., 0] == camera) | (projection[..., 3] == camera))[kept]


def _spacing(calibration: LidarCalibration, height: int, what: str) -> np.ndarray:
    """[H] the angular spacing of a range image's rows (``footprints.row_spacings``)."""
    return row_spacings(beam_inclinations(calibration, height, what))


def _users(passes: list[CameraPass]) -> dict[int, list[tuple[int, int]]]:
    """Lidar timestamp -> the (pass index, camera frame) pairs that read its sweep."""
    users: dict[int, list[tuple[int, int]]] = {}
    for i, item in enumerate(passes):
        for t in item.needed:
            users.setdefault(int(item.unit.frames.timestamps[t]), []).append((i, t))
    return users


def _in_vehicle(sweep: TopSweep) -> Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """world_from_vehicle [4, 4] -> (vehicle_from_world [4, 4], the sweep's points [M, 3] in that
    vehicle frame), each pose's computed once (the cameras of a frame share the vehicle's pose)."""
    placed: dict[bytes, tuple[np.ndarray, np.ndarray]] = {}

    def at(pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        key = pose.tobytes()
        if key not in placed:
            vehicle_from_world = invert_se3(pose)
            placed[key] = vehicle_from_world, transform_points(vehicle_from_world, sweep.points)
        return placed[key]

    return at


def _per_object(item: CameraPass) -> dict[str, dict[int, np.ndarray]]:
    """An empty per-object, per-frame table for the objects of ``item``."""
    return {run.object_id: {} for run in item.runs}


def _camera_frame(
    item: CameraPass,
    evidence: LidarEvidence,
    t: int,
    in_camera: np.ndarray,
    sweep: TopSweep,
    in_vehicle: tuple[np.ndarray, np.ndarray],
    shrink: float,
    occlusion_margin: float,
    parallax_cleanup: bool,
    depth: bool,
) -> tuple[np.ndarray, dict[str, tuple[np.ndarray, np.ndarray]]]:
    """Camera frame t's share of a sweep: its objects' points and, with ``depth``, its depth samples,
    into ``evidence``. Returns the kept points the lidar projects into this camera [K] and per object
    its body points [K'] (kept-point indices) with its box_from_vehicle [4, 4].

    in_camera: [M] bool, the kept points the lidar projects into this camera (``seen_by_camera``);
    in_vehicle: vehicle_from_world [4, 4] at the frame and the sweep's points [M, 3] in that frame."""
    world = sweep.points
    if depth:
        evidence.depth_uv[t], evidence.depth_z[t] = depth_samples(
            world[in_camera], item.camera, t, occlusion_margin, parallax_cleanup
        )
    vehicle_from_world, vehicle = in_vehicle
    pixels = sweep.pixels
    bodies = {}
    for run in item.runs:
        if run.start <= t < run.stop:
            inside, points, box_from_vehicle = box_points(vehicle, run.lidar_boxes[t - run.start], shrink)
            box_from_world = box_from_vehicle[:3, :3] @ vehicle_from_world[:3, :3]
            normals = sweep.normals(inside) @ box_from_world.T
            evidence.bodies[run.object_id][t] = BodyPoints(points, normals, pixels[inside])
            bodies[run.object_id] = inside, box_from_vehicle
    return np.flatnonzero(in_camera), bodies


def _refined_bodies(
    refined: RefinedEvidence,
    t: int,
    sweep: TopSweep,
    spacing: np.ndarray,
    in_camera: np.ndarray,
    bodies: dict[str, tuple[np.ndarray, np.ndarray]],
    in_vehicle: tuple[np.ndarray, np.ndarray],
) -> None:
    """What the refined visibility reads of its own objects in camera frame t's sweep, into
    ``refined``: their body views and surfaces.

    spacing: [H] the rows' angular spacing; in_camera: [K] the kept points the lidar projects into
    this camera; bodies: object -> its body points (kept-point indices) and box_from_vehicle [4, 4];
    in_vehicle: vehicle_from_world [4, 4] at the frame and the sweep's points [M, 3] in that frame."""
    vehicle_from_world, vehicle = in_vehicle
    labels = refined.motions.labels_at(t, vehicle[in_camera])
    active = [run for run in refined.item.runs if run.start <= t < run.stop]
    on_tracked = np.flatnonzero(np.isin(labels, [refined.labels[run.object_id] for run in active]))
    footprints = sweep_footprints(sweep, in_camera[on_tracked], spacing)
    for run in active:
        body, box_from_vehicle = bodies[run.object_id]
        box_from_world = box_from_vehicle @ vehicle_from_world
        refined.body_views[run.object_id][t] = -sweep.beams(body) @ box_from_world[:3, :3].T
        on_object = np.flatnonzero(labels[on_tracked] == refined.labels[run.object_id])
        refined.surfaces[run.object_id][t] = _surface(sweep, footprints, on_object, box_from_world, spacing)


def _sweep_footprints(
    refined: RefinedEvidence,
    t: int,
    sweep: TopSweep,
    spacing: np.ndarray,
    in_camera: np.ndarray,
    in_vehicle: tuple[np.ndarray, np.ndarray],
) -> None:
    """The footprints of camera frame t's sweep in the camera frames t - 1, t and t + 1 it serves,
    into ``refined.footprints``: of the returns on the objects tracked at t or near an object region
    of a frame served. Arguments as ``_refined_bodies``'s."""
    item, motions = refined.item, refined.motions
    vehicle_from_world, vehicle = in_vehicle
    labels = motions.labels_at(t, vehicle[in_camera])
    needed = set(item.needed)
    targets = [  # (frame, its moves, its regions)
        (target, motions.moves(t, target), refined.frame_regions(target))
        for target in (t - 1, t, t + 1)
        if target in needed
    ]
    edge_rows = field_edge_rows(sweep.pixels[in_camera] // sweep.kept.shape[1], sweep.kept.shape[0])
    reach = likely_reach(sweep, in_camera, spacing)
    reach[(edge_rows != 0) & (labels >= 0)] = np.inf  # up to its box (``BoxMotions.box_limits``)
    serving = serving_returns(item.camera, sweep.points[in_camera], labels, reach, targets)
    tracked = [refined.labels[run.object_id] for run in item.runs if run.start <= t < run.stop]
    # Footprints for the returns on the objects tracked now or serving some frame.
    wanted = np.flatnonzero(np.isin(labels, tracked) | serving.any(axis=0))
    footprints = sweep_footprints(sweep, in_camera[wanted], spacing)
    wanted_labels = labels[wanted]
    limits, along_inclination = motions.box_limits(
        t, footprints, wanted_labels, vehicle_from_world, edge_rows[wanted]
    )
    vectors = (footprints.normals, footprints.along_azimuth, along_inclination)
    for (target, moves, regions), serves in zip(targets, serving, strict=True):
        at = np.flatnonzero(serves[wanted])  # the target's returns among those with footprints
        world = moved(at, wanted_labels, moves, footprints.points, *vectors)
        source = t - target
        seen = frame_footprints(item.camera, target, source, world, limits[at], wanted_labels[at], regions)
        refined.footprints.setdefault(target, {})[source] = seen


def _surface(
    sweep: TopSweep,
    footprints: SweepFootprints,
    on_object: np.ndarray,
    box_from_world: np.ndarray,
    spacing: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """An object's surface in one sweep (``object_surface``): the returns ``on_object`` (rows of
    ``footprints``, the camera's returns) in the box frame [K, 3] (box_from_world [4, 4]) and their
    triangles [M, 3]. spacing: [H] the rows' angular spacing."""
    points = transform_points(box_from_world, footprints.points[on_object])
    if len(on_object) < 3:
        return points, np.zeros((0, 3), np.int64)
    pixels = sweep.pixels[footprints.index[on_object]]
    triangles = surface_triangles(pixels, sweep.ranges, spacing)
    normals = footprints.normals[on_object] @ box_from_world[:3, :3].T
    return points, consistent_triangles(points, normals, triangles)


def gather_lidar(
    unit: UnitInput,
    runs: list[ObjectRun],
    camera: UnitCamera,
    world_from_frame: np.ndarray,
    shrink: float,
    occlusion_margin: float,
    *,
    parallax_cleanup: bool = True,
    refined: bool = False,
    depth: bool = True,
) -> LidarEvidence:
    """``gather_lidar_cameras`` for one camera. world_from_frame: [T, 4, 4] (``camera_model.frame_poses``)."""
    (evidence,) = gather_lidar_cameras(
        [CameraPass(unit, runs, camera, world_from_frame)],
        shrink,
        occlusion_margin,
        parallax_cleanup=parallax_cleanup,
        refined=refined,
        depth=depth,
    )
    return evidence
