"""Waymo's camera model: where a world point appears in a stored frame, lens distortion and rolling
shutter included (docs/formats.md, section 3). Read from Waymo's C++ model
(``src/waymo_open_dataset/wdl_limited/camera/camera_model.cc``) and written anew.

- Lens: OpenCV's k1, k2, p1, p2, k3 on the normalised coordinates (X / Z, Y / Z in OpenCV axes,
  which are Waymo's -y / x, -z / x). Where the radial factor leaves [0.8, 1.2] the polynomial folds
  back: such a point is placed far outside the image in its own direction and is never in view
  (Waymo's guard).
- Rolling shutter (``camera_image`` ``rolling_shutter_params``, ``velocity``, ``pose_timestamp``,
  and the calibration's ``rolling_shutter_direction``): the sensor reads its rows (or columns) one
  after another, a pixel at ``trigger + shutter / 2 + readout / H x v`` (v its row coordinate,
  counted from the last row when reading bottom to top; u and W for columns), readout =
  ``readout_done - trigger - shutter``. Meanwhile the camera moves with the vehicle's linear velocity
  (world frame, plus the angular velocity's lever arm to the camera) and turns with its angular
  velocity (vehicle frame, as Waymo's code reads it), from its pose at ``pose_timestamp``. A point
  is seen at the instant its own pixel is read, solved per point (secant method). Waymo's code
  makes that instant linear in the undistorted coordinate instead of the sensor's row: the two
  differ by the distortion's share of the readout (8 px of 1280 rows over 30 ms: 0.2 ms).
- Without those columns, or with a global or unknown shutter direction, a frame is seen at once,
  from its pose.

A point's camera coordinates are those at the instant it is seen (``Projection.points``); the
frame's extrinsics are the camera's pose at the pose timestamp. A clip's pixels (queries, depth
lookups, silhouettes) are the pinhole projections of those coordinates with the calibration's
intrinsics (``Projection.pixels``), so ``fx_fy_cx_cy`` projects a track onto its query whatever the
frames; where the lens put the point on the sensor is ``Projection.sensor``. Pixels follow TAP-Vid's
convention, as Waymo's do (``InImage`` is 0 <= u < W): pixel [r, c] covers [c, c + 1) x [r, r + 1).


A unit's poses per camera frame are checked here too (the vehicle in the world, the camera from the
world: the vehicle frame at frame time holds boxes and lidar points; the camera frame at exposure has
OpenCV axes, via the camera image's own vehicle pose), and frames are undistorted with OpenCV
(``drivetrack.undistort_frames``): each stored pixel then shows what the sensor saw along that
pinhole pixel's ray, so a point appears where its pinhole pixel is; the rolling shutter stays in the
image, as in the tracks. Waymo's frames, kept as they are, show a point at its sensor pixel.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import cv2
import numba
import numpy as np

from pipeline.core.errors import InputError
from pipeline.core.geometry import CV_FROM_FLU, invert_se3, rigid_transform_problem, transform_points
from pipeline.core.images import decode_jpeg_bgrx
from pipeline.drivetrack.records import CameraCalibration, CameraFrames, UnitInput

GLOBAL_SHUTTER = 5
# Readout direction -> (pixel axis read along: 0 columns, 1 rows; counted from the far edge).
READOUT_AXES = {1: (1, False), 2: (0, False), 3: (1, True), 4: (0, True)}
MIN_RADIAL, MAX_RADIAL = 0.8, 1.2
SECANT_STEPS = 12
TOLERANCE_S = 1e-9


@dataclasses.dataclass(frozen=True)
class Readout:
    """When one frame's pixels are read, in seconds after its pose: ``start + rate x coordinate``,
    coordinate the pixel's position along ``axis`` (0: u, 1: v) clipped to [0, extent], counted
    from the far edge when ``reverse``; and how the camera moves: ``velocity`` [3] (its own axes
    at the pose, OpenCV, m/s) and ``omega`` [3] (its own axes, rad/s)."""

    start: float
    rate: float
    axis: int
    reverse: bool
    extent: int
    velocity: np.ndarray
    omega: np.ndarray


@dataclasses.dataclass(frozen=True)
class Projection:
    """Points [N] seen in one frame: ``points`` [N, 3] camera coordinates (OpenCV axes, metres) at
    the instant each is seen; ``pixels`` [N, 2] their pinhole projection with the calibration's
    intrinsics (where they appear in an undistorted frame; (-1, -1) behind the camera); ``sensor``
    [N, 2] where the lens put them on the sensor (in Waymo's own frame); ``in_view`` [N] bool: in
    front, the lens model holding, and both pixels inside the frame."""

    points: np.ndarray
    pixels: np.ndarray
    sensor: np.ndarray
    in_view: np.ndarray


@numba.njit(cache=True, nogil=True)
def _moved(x, y, z, t, vx, vy, vz, spin, a0, a1, a2):
    """Camera point (x, y, z) seen from the camera as it is t seconds after its pose: moved back by
    the velocity (vx, vy, vz), turned back by exp(-t spin [a]x) about the unit axis (a0, a1, a2)."""
    x, y, z = x - vx * t, y - vy * t, z - vz * t
    if spin == 0.0:
        return x, y, z
    angle = -spin * t
    cos, sin = np.cos(angle), np.sin(angle)
    along = x * a0 + y * a1 + z * a2
    return (
        x * cos + (a1 * z - a2 * y) * sin + a0 * along * (1.0 - cos),
        y * cos + (a2 * x - a0 * z) * sin + a1 * along * (1.0 - cos),
        z * cos + (a0 * y - a1 * x) * sin + a2 * along * (1.0 - cos),
    )


@numba.njit(cache=True, nogil=True)
def _sensor_pixel(x, y, z, lens):
    """Where camera point (x, y, z) (OpenCV axes) falls on the sensor: (u, v, valid), valid when it
    is in front and the lens model holds there; (-1, -1, False) behind the camera. lens: [10] fx,
    fy, cx, cy, k1, k2, p1, p2, k3 and the guard's reach (px, the image diagonal)."""
    if not z > 0:
        return -1.0, -1.0, False
    nx, ny = x / z, y / z
    k1, k2, p1, p2, k3 = lens[4], lens[5], lens[6], lens[7], lens[8]
    r2 = nx * nx + ny * ny
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    valid = radial >= MIN_RADIAL and radial <= MAX_RADIAL
    if valid:
        xd = nx * radial + 2.0 * p1 * nx * ny + p2 * (r2 + 2.0 * nx * nx)
        yd = ny * radial + p1 * (r2 + 2.0 * ny * ny) + 2.0 * p2 * nx * ny
    else:  # beyond the lens model: far outside the image, in the point's own direction (Waymo's guard)
        length = max(np.sqrt(nx * nx + ny * ny), 1e-12)
        xd, yd = nx / length * lens[9] / lens[0], ny / length * lens[9] / lens[1]
    return xd * lens[0] + lens[2], yd * lens[1] + lens[3], valid


@numba.njit(cache=True, nogil=True)
def _inside(u, v, width, height):
    """(u, v) in [0, width) x [0, height) (``core.geometry.in_image``)."""
    return u >= 0 and u < width and v >= 0 and v < height


@numba.njit(cache=True, nogil=True)
def _stored_pixels(local, lens, width, height, pixels, sensor, in_view):
    """pixels [N, 2], sensor [N, 2] and in_view [N] of camera points [N, 3] as seen (``Projection``):
    the pinhole pixel of the intrinsics and the sensor pixel; in view when in front, the lens model
    holds and both pixels lie in the image."""
    fx, fy, cx, cy = lens[0], lens[1], lens[2], lens[3]
    for m in range(local.shape[0]):
        x, y, z = local[m, 0], local[m, 1], local[m, 2]
        u, v, valid = _sensor_pixel(x, y, z, lens)
        sensor[m, 0], sensor[m, 1] = u, v
        seen = valid and _inside(u, v, width, height)
        if z > 0:
            u, v = fx * x / z + cx, fy * y / z + cy
            seen = seen and _inside(u, v, width, height)
        pixels[m, 0], pixels[m, 1], in_view[m] = u, v, seen


@numba.njit(cache=True, nogil=True)
def _seen_points(local, frame, start, rate, velocity, spin, axes, lens, axis, reverse, extent, out):
    """out [M, 3]: camera points [M, 3] (at the pose of their frame ``frame`` [M]) at the instant
    each is seen: the root of r(t) = t - read_time(point as seen at t), by one fixed-point step from
    the pose, then the secant method until a step is below ``TOLERANCE_S`` (``SECANT_STEPS`` at
    most). Per frame [F], as in ``Readout``: ``start``, ``rate``, ``velocity`` [F, 3], and the turn
    as ``spin`` [F] (|omega|) about the unit ``axes`` [F, 3]; the sweep's ``axis``, ``reverse`` and
    ``extent`` (the calibration's). Array elements are read into scalars first: slicing a row
    per call cost 20 times the arithmetic."""
    for m in range(local.shape[0]):
        f = frame[m]
        x, y, z = local[m, 0], local[m, 1], local[m, 2]
        motion = (velocity[f, 0], velocity[f, 1], velocity[f, 2], spin[f], axes[f, 0], axes[f, 1], axes[f, 2])
        first, per_pixel = start[f], rate[f]
        before, time, residual_before = 0.0, 0.0, 0.0
        for step_index in range(SECANT_STEPS + 1):
            mx, my, mz = _moved(x, y, z, time, *motion)
            u, v, _ = _sensor_pixel(mx, my, mz, lens)
            coordinate = (u if axis == 0 else v) if mz > 0 else lens[2 + axis]  # the centre, behind
            coordinate = min(max(coordinate, 0.0), extent)
            if reverse:
                coordinate = extent - coordinate
            now = time - (first + per_pixel * coordinate)
            if step_index == 0:  # the fixed-point step from the pose
                residual_before, time = now, 0.0 - now
                continue
            rise, run = now - residual_before, time - before
            slope = rise / run if run != 0 else 1.0
            step = now / (slope if abs(slope) > 1e-3 else 1.0)
            before, residual_before = time, now
            time -= step
            if not abs(step) >= TOLERANCE_S:
                break
        out[m, 0], out[m, 1], out[m, 2] = _moved(x, y, z, time, *motion)


class UnitCamera:
    """One unit's camera over its frames: ``project(t, world points)``, or ``project_frames`` for
    several frames at once.

    calibration, frames: the reader's records; cam_from_world: [T, 4, 4] OpenCV camera from world
    at each frame's pose (``poses.camera_from_world``); what: names the camera in errors.
    """

    def __init__(
        self, calibration: CameraCalibration, frames: CameraFrames, cam_from_world: np.ndarray, what: str
    ):
        self.calibration = calibration
        self.cam_from_world = cam_from_world
        self.readouts = [
            self._readout(frames, t, f"{what} frame {frames.timestamps[t]}")
            for t in range(len(cam_from_world))
        ]

    def _readout(self, frames: CameraFrames, t: int, what: str) -> Readout | None:
        motion, calibration = frames.motion, self.calibration
        if motion is None or calibration.rolling_shutter_direction not in READOUT_AXES:
            return None
        values = [motion.pose_timestamp[t], motion.shutter[t], motion.trigger[t], motion.readout_done[t]]
        velocity, omega = motion.linear_velocity[t], motion.angular_velocity[t]
        if np.isnan(values).any() or np.isnan(velocity).any() or np.isnan(omega).any():
            return None  # this frame has no rolling-shutter record
        pose_time, shutter, trigger, done = values
        readout = done - trigger - shutter
        if readout < 0 or shutter < 0:
            raise InputError(
                f"{what}: rolling shutter readout of {readout:.6g} s (shutter {shutter:.6g} s), "
                "expected both >= 0"
            )
        axis, reverse = READOUT_AXES[calibration.rolling_shutter_direction]
        extent = calibration.height if axis == 1 else calibration.width
        world_from_vehicle = frames.world_from_vehicle_at_exposure[t]
        vehicle_from_camera = calibration.camera_to_vehicle
        arm = world_from_vehicle[:3, :3] @ vehicle_from_camera[:3, 3]
        camera_velocity = velocity + np.cross(world_from_vehicle[:3, :3] @ omega, arm)
        return Readout(
            start=trigger + 0.5 * shutter - pose_time,
            rate=readout / extent,
            axis=axis,
            reverse=reverse,
            extent=extent,
            velocity=self.cam_from_world[t, :3, :3] @ camera_velocity,
            omega=CV_FROM_FLU[:3, :3] @ vehicle_from_camera[:3, :3].T @ omega,
        )

    def project(self, t: int, world: np.ndarray) -> Projection:
        """Where world points [N, 3] appear in frame t of the unit."""
        return self.project_frames([t], [world])[0]

    def project_frames(
        self, frames: Sequence[int], world: Sequence[np.ndarray] | np.ndarray
    ) -> list[Projection]:
        """Where world points appear in several frames of the unit: world[i] [N_i, 3] (a list, or
        [T, N, 3]) in frame frames[i]. One Projection per frame, the same as ``project`` gives it:
        the frames' points are solved together, each with its own frame's arithmetic."""
        if not len(frames):
            return []
        local = np.concatenate(
            [transform_points(self.cam_from_world[t], w) for t, w in zip(frames, world, strict=True)]
        )
        counts = np.array([len(w) for w in world])
        bounds = np.concatenate([[0], np.cumsum(counts)])
        readouts = [self.readouts[t] for t in frames]
        rolling = [i for i, readout in enumerate(readouts) if readout is not None]
        read = [readout for readout in readouts if readout is not None]
        if len(rolling) == len(frames):  # every frame's: no points to pick out and put back
            local = self._seen(read, np.repeat(np.arange(len(frames)), counts), local)
        elif rolling:
            rows = np.concatenate([np.arange(bounds[i], bounds[i + 1]) for i in rolling])
            frame = np.repeat(np.arange(len(rolling)), counts[rolling])
            local[rows] = self._seen(read, frame, local[rows])
        whole = self._stored(local)
        arrays = (whole.points, whole.pixels, whole.sensor, whole.in_view)
        parts = (np.split(array, bounds[1:-1]) for array in arrays)
        return [Projection(*frame) for frame in zip(*parts, strict=True)]

    def _stored(self, local: np.ndarray) -> Projection:
        """Where camera points [N, 3], as seen, appear: pinhole and sensor pixels."""
        c = self.calibration
        pixels, sensor = np.empty((len(local), 2)), np.empty((len(local), 2))
        in_view = np.empty(len(local), np.bool_)
        _stored_pixels(local, self._lens(), c.width, c.height, pixels, sensor, in_view)
        return Projection(local, pixels, sensor, in_view)

    def _lens(self) -> np.ndarray:
        """[10] fx, fy, cx, cy, k1, k2, p1, p2, k3, reach: the kernels' lens (``_sensor_pixel``)."""
        c = self.calibration
        return np.array([*c.fx_fy_cx_cy, *c.distortion, np.hypot(c.width, c.height)], dtype=np.float64)

    def _seen(self, readouts: list[Readout], frame: np.ndarray, local: np.ndarray) -> np.ndarray:
        """Camera points [M, 3] at the instant each is seen, from their coordinates [M, 3] at the pose
        of their frame (``frame`` [M], an index into ``readouts`` [F])."""
        spin = np.array([np.linalg.norm(readout.omega) for readout in readouts])
        turns = zip(readouts, spin, strict=True)
        axes = np.array([readout.omega / w if w != 0.0 else np.zeros(3) for readout, w in turns])
        first = readouts[0]  # the readout axis and direction are the calibration's: every frame's
        seen = np.empty_like(local)
        _seen_points(
            np.ascontiguousarray(local, dtype=np.float64),
            frame,
            np.array([readout.start for readout in readouts]),
            np.array([readout.rate for readout in readouts]),
            np.array([readout.velocity for readout in readouts]),
            spin,
            axes,
            self._lens(),
            first.axis,
            first.reverse,
            float(first.extent),
            seen,
        )
        return seen


def require_rigid(what: str, matrix: np.ndarray) -> None:
    """InputError naming ``what`` unless ``matrix`` [4, 4] is a rigid transform."""
    problem = rigid_transform_problem(matrix)
    if problem:
        raise InputError(f"{what} {problem}")


def frame_poses(unit: UnitInput) -> np.ndarray:
    """world_from_vehicle at each camera frame's frame time [T, 4, 4], checked; the camera must
    have an image at every frame of the segment (every vehicle_pose timestamp)."""
    segment, camera = unit.segment, unit.camera
    poses = []
    for index, timestamp in enumerate(unit.frames.timestamps.tolist()):
        pose = unit.world_from_vehicle.get(timestamp)
        if pose is None:
            raise InputError(
                f"camera_image/{segment} camera {camera} frame {timestamp}: "
                "no vehicle_pose row at this timestamp"
            )
        require_rigid(f"vehicle_pose/{segment} frame {timestamp}: world_from_vehicle", pose)
        require_rigid(
            f"camera_image/{segment} camera {camera} frame {timestamp}: pose.transform",
            unit.frames.world_from_vehicle_at_exposure[index],
        )
        poses.append(pose)
    missing = sorted(set(unit.world_from_vehicle) - set(unit.frames.timestamps.tolist()))
    if missing:
        raise InputError(
            f"camera_image/{segment} camera {camera}: no image for frame {missing[0]} "
            f"({len(missing)} of {len(unit.world_from_vehicle)} frames)"
        )
    require_rigid(
        f"camera_calibration/{segment} camera {camera}: extrinsic", unit.calibration.camera_to_vehicle
    )
    require_rigid(f"lidar_calibration/{segment} TOP: extrinsic", unit.lidar_calibration.lidar_to_vehicle)
    return np.stack(poses)


def camera_from_world(frames: CameraFrames, calibration: CameraCalibration) -> np.ndarray:
    """OpenCV camera-from-world per frame [T, 4, 4] from the exposure-time vehicle poses."""
    world_from_camera = frames.world_from_vehicle_at_exposure @ calibration.camera_to_vehicle
    return CV_FROM_FLU @ invert_se3(world_from_camera)


JPEG_QUALITY = 95


class Undistortion:
    """One camera's frames undistorted to its pinhole intrinsics and JPEG-encoded (``jpeg``).

    maps: OpenCV remap tables [H, W] (float32), the sensor pixel read for each stored pixel. A frame
    is decoded with a fourth, opaque channel and remapped so: OpenCV's bilinear remap has vector code
    for 1- and 4-channel images and a scalar loop for 3 (about half the time at 1920x1280), and
    computes each channel alone, so the first three channels are the 3-channel remap's pixels; the
    JPEG encoder drops the fourth. Same bytes (tests/drivetrack/test_camera_model.py). The two
    4-channel images are kept from frame to frame: a fresh 10 MB array each time costs its page
    faults."""

    def __init__(self, calibration: CameraCalibration):
        fx, fy, cx, cy = calibration.fx_fy_cx_cy
        # OpenCV puts pixel centres at integers, Waymo and TAP-Vid at +0.5: the principal point moved
        # by -0.5 gives the same maps in OpenCV's convention, on both sides of the remap.
        matrix = np.array([[fx, 0.0, cx - 0.5], [0.0, fy, cy - 0.5], [0.0, 0.0, 1.0]])
        size = (calibration.width, calibration.height)
        distortion = calibration.distortion
        self.maps = cv2.initUndistortRectifyMap(matrix, distortion, None, matrix, size, cv2.CV_32FC1)
        self._sensor = np.empty((calibration.height, calibration.width, 4), np.uint8)
        self._stored = np.empty_like(self._sensor)

    def jpeg(self, data: bytes, what: str) -> bytes:
        """The JPEG ``data`` of a frame, checked (InputError naming ``what``: ``images.check_jpeg_header``)
        and undistorted (black where the sensor saw nothing), JPEG-encoded."""
        decode_jpeg_bgrx(data, self._sensor, what)
        stored = self._stored
        cv2.remap(self._sensor, *self.maps, cv2.INTER_LINEAR, dst=stored, borderMode=cv2.BORDER_CONSTANT)
        return cv2.imencode(".jpg", stored, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])[1].tobytes()
