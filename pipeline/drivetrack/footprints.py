"""Lidar footprints (refined visibility): the patch of surface each TOP return stands for, where the
footprints of the sweeps around a camera frame appear in it, and how deep a track point lies inside
the footprints of the surfaces in front of it.

A return's footprint reaches half the beam spacing either way along the azimuth (2 pi / W) and the
inclination (the local row spacing), laid on the return's tangent plane (its range-image normal):
neighbouring footprints tile the surface the sweep saw, and a footprint on a surface the lidar sees
at a grazing angle is long on that surface yet thin in the image of a camera that grazes it too. In
a camera frame a footprint is the parallelogram spanned by its two half-vectors around the return's
pixel (their images through the pinhole's Jacobian at the return); its depth along a pixel's ray is
that of its tangent plane.

A camera frame's footprints come from the sweep of that frame and the sweeps before and after it:
labelled objects are moved to the frame by their boxes (attached by the sweep's lidar box, placed by
the frame's camera-synced box, as tracks are), the rest of the world stays where it is. Only those
that may cover a tracked object are kept: inside the image rectangle of its box at that frame, and
nearer than its farthest corner.
"""

from __future__ import annotations

import dataclasses

import numba
import numpy as np

from pipeline.core.geometry import invert_se3, transform_points
from pipeline.drivetrack.camera_model import UnitCamera
from pipeline.drivetrack.objects import SURFACE_GROW_M, box_corners_local, box_poses, on_surface_box

# Where a footprint's plane is seen within this cosine of edge-on from its lidar, its half-vectors
# stretch no further: ten times the beam spacing.
MIN_BEAM_COSINE = 0.1
# The sweep of a frame counts twice as much as each of its neighbours in ``occluded_by_others``.
SOURCE_WEIGHTS = {-1: 1.0, 0: 2.0, 1: 1.0}
# A point within this much (in footprint half-widths) of a footprint's border counts partly: inside by
# that much, fully; outside by that much, not at all; linearly between.
SOFT_BORDER = 0.3


def row_spacings(inclinations: np.ndarray) -> np.ndarray:
    """Angular spacing [H] (radians) of the range image's rows around each row, from their
    inclinations [H] (``lidar.beam_inclinations``): central differences, one-sided at the ends."""
    spacing = np.empty_like(inclinations)
    spacing[1:-1] = np.abs(inclinations[:-2] - inclinations[2:]) / 2.0
    spacing[0] = abs(inclinations[0] - inclinations[1])
    spacing[-1] = abs(inclinations[-2] - inclinations[-1])
    return spacing


@dataclasses.dataclass(frozen=True)
class SweepFootprints:
    """Footprints of some returns of a sweep in the world: points [K, 3], unit normals [K, 3] and the
    half-vectors along the azimuth and the inclination [K, 3] each; ``index`` [K], the returns'
    kept-point indices in the sweep (``lidar.TopSweep``)."""

    points: np.ndarray
    normals: np.ndarray
    along_azimuth: np.ndarray
    along_inclination: np.ndarray
    index: np.ndarray


def sweep_footprints(sweep, index: np.ndarray, spacing: np.ndarray) -> SweepFootprints:
    """The footprints of the kept returns ``index`` [K] of a ``lidar.TopSweep``, its rows' angular
    spacing ``spacing`` [H] (``row_spacings``)."""
    height, width = sweep.kept.shape
    pixels = np.flatnonzero(sweep.kept)[index]
    rows, cols = pixels // width, pixels % width
    ranges = sweep.ranges[rows, cols]
    beam = sweep.grid[rows, cols] / ranges[:, None]  # lidar frame, unit
    level = np.hypot(beam[:, 0], beam[:, 1])
    zero = np.zeros_like(level)
    d_azimuth = np.stack([-beam[:, 1], beam[:, 0], zero], 1)  # d beam / d azimuth
    d_inclination = np.stack([-beam[:, 0] * beam[:, 2] / level, -beam[:, 1] * beam[:, 2] / level, level], 1)
    to_world = sweep.pose_rotations[sweep.pose_of_point[index]] @ sweep.lidar_rotation
    beam, d_azimuth, d_inclination = (
        np.einsum("kij,kj->ki", to_world, v) for v in (beam, d_azimuth, d_inclination)
    )
    normals = sweep.normals(index)
    facing = np.einsum("ki,ki->k", normals, beam)
    facing = np.where(np.abs(facing) < MIN_BEAM_COSINE, np.copysign(MIN_BEAM_COSINE, facing), facing)

    def on_plane(direction: np.ndarray, half_angle: np.ndarray) -> np.ndarray:
        """The beam turned by half_angle [K] along ``direction`` [K, 3], met on the tangent plane."""
        slide = direction - beam * (np.einsum("ki,ki->k", normals, direction) / facing)[:, None]
        return slide * (ranges * half_angle)[:, None]

    return SweepFootprints(
        sweep.points[index],
        normals,
        on_plane(d_azimuth, np.full(len(index), np.pi / width)),
        on_plane(d_inclination, spacing[rows] / 2.0),
        index,
    )


@dataclasses.dataclass(frozen=True)
class FrameFootprints:
    """Footprints seen in one camera frame: pixels [M, 2]; camera points [M, 3] and unit normals
    [M, 3] (OpenCV axes); the pixel half-vectors along the azimuth and the inclination [M, 2] each,
    and how far each footprint reaches along them [M, 4] (``BoxMotions.box_limits``: -azimuth,
    +azimuth, -inclination, +inclination, in half-vectors); the label of each return's object [M]
    (``BoxMotions``; -1: the unlabelled world) and the sweep it comes from [M] (-1, 0, 1: the frame's
    neighbour before it, its own, the one after it)."""

    pixels: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    along_azimuth: np.ndarray
    along_inclination: np.ndarray
    limits: np.ndarray
    labels: np.ndarray
    sources: np.ndarray

    @staticmethod
    def joined(parts: list[FrameFootprints]) -> FrameFootprints:
        """The footprints of ``parts`` together, in their order."""
        fields = [f.name for f in dataclasses.fields(FrameFootprints)]
        return FrameFootprints(*(np.concatenate([getattr(p, name) for p in parts]) for name in fields))


class BoxMotions:
    """The labelled objects of a camera's unit, and how each moves between its frames.

    object_ids: every object id of the segment's boxes, sorted: an object's label is its position.
    Per box row on one of the unit's frames: its label, its lidar box [7] (vehicle frame) and the
    world poses of its lidar and camera-synced boxes [4, 4] (world_from_frame [T, 4, 4]:
    ``camera_model.frame_poses``)."""

    def __init__(self, unit, world_from_frame: np.ndarray):
        boxes = unit.boxes
        self.object_ids = np.unique(boxes.object_ids)
        row_of = {int(stamp): t for t, stamp in enumerate(unit.frames.timestamps)}
        frame = np.array([row_of.get(int(stamp), -1) for stamp in boxes.timestamps], np.int64)
        on_frames = np.flatnonzero(frame >= 0)
        self._rows = [on_frames[frame[on_frames] == t] for t in range(len(world_from_frame))]
        self._labels = np.searchsorted(self.object_ids, boxes.object_ids)
        self._lidar = boxes.lidar_boxes
        poses = world_from_frame[np.maximum(frame, 0)]
        self._attached = poses @ box_poses(boxes.lidar_boxes)
        self._placed = poses @ box_poses(boxes.synced_boxes)
        self._box_from_vehicle = invert_se3(box_poses(boxes.lidar_boxes))

    def label(self, object_id: str) -> int:
        """The label of a labelled object."""
        return int(np.searchsorted(self.object_ids, object_id))

    def labels_at(self, t: int, vehicle_points: np.ndarray) -> np.ndarray:
        """Label [K] of the object each point [K, 3] (vehicle frame of frame t) lies on
        (``objects.on_surface_box`` of its lidar box; the first by label where boxes overlap), -1
        where none."""
        labels = np.full(len(vehicle_points), -1, np.int64)
        if not len(vehicle_points):
            return labels
        x, y = np.ascontiguousarray(vehicle_points[:, 0]), np.ascontiguousarray(vehicle_points[:, 1])
        low, high = np.array([x.min(), y.min()]), np.array([x.max(), y.max()])
        for row in self._rows[t][::-1]:  # lowest label last: it wins overlaps
            box = self._lidar[row]
            reach = np.linalg.norm(box[3:6]) / 2.0 + 1.0  # the circumscribed sphere's and a metre
            if np.any(box[:2] + reach < low) or np.any(box[:2] - reach > high):
                continue  # no point near this box
            near = np.flatnonzero((np.abs(x - box[0]) <= reach) & (np.abs(y - box[1]) <= reach))
            local = transform_points(self._box_from_vehicle[row], vehicle_points[near])
            labels[near[on_surface_box(local, box[3:6])]] = self._labels[row]
        return labels

    def box_limits(
        self, t: int, footprints: SweepFootprints, labels: np.ndarray, vehicle_from_world: np.ndarray
    ) -> np.ndarray:
        """[K, 4] how far (in half-vectors, at most 1) the footprints [K] of frame t's sweep reach
        along -azimuth, +azimuth, -inclination and +inclination: a labelled object's footprint stops
        at the border of its box (``objects.on_surface_box``: no surface of the object lies beyond),
        the rest reach a whole half-vector. labels [K]: ``labels_at``'s."""
        limits = np.ones((len(labels), 4))
        for row in self._rows[t]:
            members = np.flatnonzero(labels == self._labels[row])
            if not len(members):
                continue
            box_from_world = self._box_from_vehicle[row] @ vehicle_from_world
            rotation = box_from_world[:3, :3]
            local = transform_points(box_from_world, footprints.points[members])
            half = self._lidar[row, 3:6] / 2.0
            upper = half + SURFACE_GROW_M
            lower = -upper
            lower[2] = SURFACE_GROW_M - half[2]
            for axis, vectors in enumerate((footprints.along_azimuth, footprints.along_inclination)):
                step = vectors[members] @ rotation.T
                for sign in (-1.0, 1.0):
                    limits[members, 2 * axis + (sign > 0)] = _room(local, sign * step, lower, upper)
        return np.clip(limits, MIN_LIMIT, 1.0)

    def moves(self, source: int, target: int) -> dict[int, np.ndarray]:
        """label -> target_world_from_source_world [4, 4] of each object with a lidar box at frame
        ``source`` and a camera-synced box at frame ``target``."""
        placed = {self._labels[row]: self._placed[row] for row in self._rows[target]}
        return {
            self._labels[row]: placed[self._labels[row]] @ invert_se3(self._attached[row])
            for row in self._rows[source]
            if self._labels[row] in placed
        }


# A footprint reaches at least this share of its half-vectors, even from a box's border.
MIN_LIMIT = 0.05


def _room(points: np.ndarray, steps: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """[K] the largest share (up to 1) of steps [K, 3] that points [K, 3] can take and stay within
    lower [3] <= p <= upper [3]."""
    with np.errstate(divide="ignore", invalid="ignore"):
        room = np.where(
            steps > 0, (upper - points) / steps, np.where(steps < 0, (lower - points) / steps, np.inf)
        )
    return np.clip(room.min(axis=1), 0.0, 1.0)


def moved(labels: np.ndarray, moves: dict[int, np.ndarray], points: np.ndarray, *vectors: np.ndarray):
    """World points [K, 3] and directions (each [K, 3]) of returns with labels [K] moved by their
    objects' ``moves`` (``BoxMotions.moves``): the rows kept [K'] (a labelled return whose object has
    no move is dropped), then the moved points and directions [K', 3]."""
    movable = np.array(sorted(moves), np.int64)
    rows = np.flatnonzero((labels < 0) | np.isin(labels, movable))
    points, kept = points[rows], [vector[rows] for vector in vectors]
    movers = np.flatnonzero(labels[rows] >= 0)
    if len(movers):
        transforms = np.stack([moves[label] for label in movable])[
            np.searchsorted(movable, labels[rows[movers]])
        ]
        rotations = transforms[:, :3, :3]
        points[movers] = np.einsum("kij,kj->ki", rotations, points[movers]) + transforms[:, :3, 3]
        for vector in kept:
            vector[movers] = np.einsum("kij,kj->ki", rotations, vector[movers])
    return rows, points, *kept


def likely_reach(sweep, index: np.ndarray, spacing: np.ndarray) -> np.ndarray:
    """[K] how far (metres) a footprint of the kept returns ``index`` reaches from its return unless
    its surface is seen within 60 degrees of edge-on: twice the larger half beam spacing, both ways."""
    width = sweep.kept.shape[1]
    pixels = np.flatnonzero(sweep.kept)[index]
    beam = np.maximum(np.pi / width, spacing[pixels // width] / 2.0)
    return 4.0 * sweep.ranges.ravel()[pixels] * beam


def pixel_vectors(fx: float, fy: float, points: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """Pixel offsets [K, 2] of small camera-frame offsets ``vectors`` [K, 3] at camera points
    [K, 3]: the pinhole's Jacobian."""
    z = points[:, 2]
    return np.stack(
        [
            fx * (vectors[:, 0] - points[:, 0] * vectors[:, 2] / z) / z,
            fy * (vectors[:, 1] - points[:, 1] * vectors[:, 2] / z) / z,
        ],
        1,
    )


def object_regions(camera: UnitCamera, t: int, boxes: list[tuple[np.ndarray, np.ndarray]]):
    """Per box seen in frame t, given as (world_from_box [4, 4], box [7]): the image rectangle [4]
    (u0, v0, u1, v1) around its corners and their largest depth; a box with a corner behind the
    camera spans the whole image at any depth. Returns rectangles [R, 4] and depths [R]."""
    width, height = camera.calibration.width, camera.calibration.height
    if not boxes:
        return np.zeros((0, 4)), np.zeros(0)
    corners = [transform_points(world_from_box, box_corners_local(box)) for world_from_box, box in boxes]
    seen = camera.project(t, np.concatenate(corners))
    rectangles, depths = [], []
    for pixels, points in zip(
        np.split(seen.pixels, len(boxes)), np.split(seen.points, len(boxes)), strict=True
    ):
        if np.any(points[:, 2] <= 0):
            rectangles.append([-np.inf, -np.inf, np.inf, np.inf])
            depths.append(np.inf)
            continue
        low, high = pixels.min(axis=0), pixels.max(axis=0)
        if high[0] < 0 or high[1] < 0 or low[0] >= width or low[1] >= height:
            continue
        rectangles.append([low[0], low[1], high[0], high[1]])
        depths.append(points[:, 2].max())
    return np.array(rectangles, np.float64).reshape(-1, 4), np.array(depths, np.float64)


def serving_returns(
    camera: UnitCamera,
    points: np.ndarray,
    labels: np.ndarray,
    reach: np.ndarray,
    targets: list[tuple[int, dict[int, np.ndarray], tuple[np.ndarray, np.ndarray]]],
) -> list[np.ndarray]:
    """Per target frame, the rows [K'] of a sweep's returns (world points [K, 3], labels [K],
    footprints reaching about ``reach`` [K] metres, ``likely_reach``) whose footprints may serve
    there: moved to it (``targets``: per frame, its moves and its regions, ``object_regions``), near
    one of its regions. A footprint seen nearly edge-on may reach further: such a surface covers
    little of the image beyond its return."""
    still = np.flatnonzero(labels < 0)
    movers = np.flatnonzero(labels >= 0)
    still_points, mover_points = points[still], points[movers]
    serving = []
    for target, moves, regions in targets:
        rows, placed = moved(labels[movers], moves, mover_points)
        near_still = still[near_regions(camera, target, still_points, reach[still], regions)]
        near_movers = movers[rows[near_regions(camera, target, placed, reach[movers[rows]], regions)]]
        serving.append(np.union1d(near_still, near_movers))
    return serving


def frame_footprints(
    camera: UnitCamera,
    t: int,
    source: int,
    world: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    limits: np.ndarray,
    labels: np.ndarray,
    regions: tuple[np.ndarray, np.ndarray],
) -> FrameFootprints:
    """Footprints of one sweep in camera frame t, from ``source`` (-1, 0, 1: the frame's neighbour
    before it, its own sweep, the one after): ``world`` = (points, normals, along_azimuth,
    along_inclination) [K, 3] each, already at frame t (``moved``; those ``serving_returns`` found
    near a region), with their limits [K, 4] (``BoxMotions.box_limits``) and labels [K]; kept where in
    view and inside ``regions`` (``object_regions``)."""
    points, normals, along_azimuth, along_inclination = world
    seen = camera.project(t, points)
    rotation = camera.cam_from_world[t, :3, :3]
    fx, fy = camera.calibration.fx_fy_cx_cy[:2]
    rows = np.flatnonzero(seen.in_view)
    local = seen.points[seen.in_view]
    half_u = pixel_vectors(fx, fy, local, along_azimuth[rows] @ rotation.T)
    half_v = pixel_vectors(fx, fy, local, along_inclination[rows] @ rotation.T)
    pixels = seen.pixels[seen.in_view]
    wanted = np.empty(len(rows), np.bool_)
    _overlapping(pixels, np.abs(half_u) + np.abs(half_v), local[:, 2], *regions, wanted)
    keep = np.flatnonzero(wanted)
    return FrameFootprints(
        pixels[keep],
        local[keep],
        normals[rows[keep]] @ rotation.T,
        half_u[keep],
        half_v[keep],
        limits[rows[keep]],
        labels[rows[keep]],
        np.full(len(keep), source, np.int8),
    )


@numba.njit(cache=True, nogil=True)
def _overlapping(pixels, reach, depth, rectangles, depths, wanted):
    """wanted [K]: the rectangle of pixels [K, 2] +- reach [K, 2] overlaps a rectangle [R, 4] (u0,
    v0, u1, v1) whose depth [R] is beyond the footprint's depth [K]."""
    for k in range(len(pixels)):
        wanted[k] = False
        for i in range(len(depths)):
            if depth[k] < depths[i] and pixels[k, 0] + reach[k, 0] >= rectangles[i, 0]:
                if (
                    pixels[k, 0] - reach[k, 0] <= rectangles[i, 2]
                    and pixels[k, 1] + reach[k, 1] >= rectangles[i, 1]
                ):
                    if pixels[k, 1] - reach[k, 1] <= rectangles[i, 3]:
                        wanted[k] = True
                        break


# The pinhole of the frame's pose misplaces a point, against the camera model, by at most the
# lens's distortion (Waymo's: ~8 px at a 1920x1280 frame's corners) plus the rolling shutter.
LENS_BOUND_PX = 16.0


def near_regions(
    camera: UnitCamera, t: int, points: np.ndarray, extent: np.ndarray, regions: tuple[np.ndarray, np.ndarray]
) -> np.ndarray:
    """Indices of the world points [K, 3] whose footprints (reaching ``extent`` [K] metres from them)
    may lie in ``regions`` of frame t: their pinhole pixels at the frame's pose, padded by what the
    lens and the rolling shutter can move them (the camera's speed and turn over the readout, at the
    point's depth) and by the footprint's size, overlap a region, nearer than its depth."""
    rectangles, depths = regions
    if not len(points) or not len(depths):
        return np.zeros(0, np.int64)
    near = np.empty(len(points), np.bool_)
    _near_regions(
        np.ascontiguousarray(points, np.float64),
        np.ascontiguousarray(extent, np.float64),
        camera.cam_from_world[t],
        camera.calibration.fx_fy_cx_cy,
        *shutter_motion(camera, t),
        LENS_BOUND_PX,
        rectangles,
        depths,
        near,
    )
    return np.flatnonzero(near)


@numba.njit(cache=True, nogil=True)
def _near_regions(points, extent, cam_from_world, lens, travel, turn, lens_bound, rectangles, depths, near):
    """near [K] (``near_regions``) of world points [K, 3] reaching extent [K] metres."""
    fx, fy, cx, cy = lens[0], lens[1], lens[2], lens[3]
    focal = max(fx, fy)
    r = cam_from_world
    for k in range(len(points)):
        x, y, z = points[k, 0], points[k, 1], points[k, 2]
        depth = r[2, 0] * x + r[2, 1] * y + r[2, 2] * z + r[2, 3]
        near[k] = False
        if depth <= 0:
            continue
        u = fx * (r[0, 0] * x + r[0, 1] * y + r[0, 2] * z + r[0, 3]) / depth + cx
        v = fy * (r[1, 0] * x + r[1, 1] * y + r[1, 2] * z + r[1, 3]) / depth + cy
        pad = focal * ((travel + extent[k]) / depth + turn) + lens_bound
        for i in range(len(depths)):
            if depth - travel >= depths[i]:
                continue
            if u + pad >= rectangles[i, 0] and u - pad <= rectangles[i, 2]:
                if v + pad >= rectangles[i, 1] and v - pad <= rectangles[i, 3]:
                    near[k] = True
                    break


def shutter_motion(camera: UnitCamera, t: int) -> tuple[float, float]:
    """How far (metres) and how much (radians) the camera moves between frame t's pose and the
    instant its rolling shutter reads its farthest pixel (0, 0 for a frame seen at once)."""
    readout = camera.readouts[t]
    if readout is None:
        return 0.0, 0.0
    longest = max(abs(readout.start), abs(readout.start + readout.rate * readout.extent))
    return float(np.linalg.norm(readout.velocity)) * longest, float(np.linalg.norm(readout.omega)) * longest


class FrameOccluders:
    """A camera frame's footprints, from each source sweep (source -> ``FrameFootprints``), joined
    and binned for ``occluder_reach``: built once per frame, read by every clip of the camera."""

    def __init__(self, parts: dict[int, FrameFootprints]):
        self.sources = tuple(sorted(parts))
        self.footprints = FrameFootprints.joined([parts[source] for source in self.sources])
        extent = SCALE * (np.abs(self.footprints.along_azimuth) + np.abs(self.footprints.along_inclination))
        pixels = self.footprints.pixels
        self.cells = BoxCells(pixels - extent, pixels + extent) if len(pixels) else None


# A footprint is searched up to this many half-widths from its return.
SCALE = 1.0 + SOFT_BORDER


def occluder_reach(
    occluders: FrameOccluders, pixels: np.ndarray, points: np.ndarray, limits: np.ndarray, own: int
) -> np.ndarray:
    """[N, 3] per track point and per source sweep (-1, 0, 1): how far inside the nearest footprint
    that occludes it the point lies, in footprint half-widths (the larger of its two coordinates: 1 on
    the border, below 1 inside; inf where none reaches ``SCALE``). A footprint occludes a point when
    its plane meets the point's ray nearer than the point's limit.

    pixels [N, 2], points [N, 3] (camera, as seen), limits [N]: the depth an occluder must be nearer
    than; own: the label of the tracked object, whose footprints are left out."""
    reach = np.full((len(pixels), 3), np.inf)
    if occluders.cells is None or not len(pixels):
        return reach
    footprints = occluders.footprints
    _occluder_reach(
        np.ascontiguousarray(pixels, np.float64),
        np.ascontiguousarray(points, np.float64),
        np.ascontiguousarray(limits, np.float64),
        footprints.pixels,
        footprints.points,
        footprints.normals,
        footprints.along_azimuth,
        footprints.along_inclination,
        footprints.limits,
        footprints.labels,
        footprints.sources,
        own,
        SCALE,
        *occluders.cells.arrays,
        reach,
    )
    return reach


def occluded_by_others(reach: np.ndarray, sources: tuple[int, ...]) -> np.ndarray:
    """[N] bool: the sweeps ``sources`` (those read around the frame) say, weighed by
    ``SOURCE_WEIGHTS``, that other surfaces cover the points: each sweep scores a point 1 well inside
    an occluding footprint, 0 outside one, linearly across ``SOFT_BORDER`` around its border
    (``occluder_reach`` [N, 3]); occluded when the weighted mean is above one half."""
    score = np.zeros(len(reach))
    total = 0.0
    for source in sources:
        inside = np.clip((1.0 + SOFT_BORDER - reach[:, source + 1]) / (2.0 * SOFT_BORDER), 0.0, 1.0)
        score += SOURCE_WEIGHTS[source] * inside
        total += SOURCE_WEIGHTS[source]
    return score > 0.5 * total


class BoxCells:
    """Rectangles [M] (low [M, 2], high [M, 2] pixel corners) binned in square cells: each is listed
    in every cell it overlaps, so the cell of a pixel lists every rectangle that may hold it.

    arrays: origin [2], side, columns, rows, starts [cells + 1] and members (rectangle indices, cell
    after cell: cell c holds members[starts[c]:starts[c + 1]])."""

    def __init__(self, low: np.ndarray, high: np.ndarray):
        side = max(float(np.median(high - low)) * 2.0, 0.5)
        origin = low.min(axis=0)
        first = np.floor((low - origin) / side).astype(np.int64)
        last = np.floor((high - origin) / side).astype(np.int64)
        columns, rows = int(last[:, 0].max()) + 1, int(last[:, 1].max()) + 1
        span = last - first + 1
        count = span[:, 0] * span[:, 1]
        member = np.repeat(np.arange(len(low)), count)
        offset = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
        width = np.repeat(span[:, 0], count)
        keys = (np.repeat(first[:, 1], count) + offset // width) * columns + np.repeat(first[:, 0], count)
        keys += offset % width
        order = np.argsort(keys, kind="stable")
        starts = np.zeros(rows * columns + 1, np.int64)
        np.cumsum(np.bincount(keys, minlength=rows * columns), out=starts[1:])
        self.arrays = (origin, side, columns, rows, starts, member[order])


@numba.njit(cache=True, nogil=True)
def _occluder_reach(
    pixels,
    points,
    limits,
    f_pixels,
    f_points,
    f_normals,
    f_u,
    f_v,
    f_limits,
    f_labels,
    f_sources,
    own,
    scale,
    origin,
    side,
    columns,
    rows,
    starts,
    members,
    reach,
):
    """Fills reach [N, 3] (``occluder_reach``) from the footprints (f_*) binned by ``BoxCells``."""
    for q in range(len(pixels)):
        column = int(np.floor((pixels[q, 0] - origin[0]) / side))
        row = int(np.floor((pixels[q, 1] - origin[1]) / side))
        if column < 0 or row < 0 or column >= columns or row >= rows:
            continue
        ray_x, ray_y = points[q, 0] / points[q, 2], points[q, 1] / points[q, 2]
        cell = row * columns + column
        for k in range(starts[cell], starts[cell + 1]):
            j = members[k]
            if f_labels[j] == own and own >= 0:
                continue
            determinant = f_u[j, 0] * f_v[j, 1] - f_v[j, 0] * f_u[j, 1]
            if determinant == 0.0:
                continue
            du, dv = pixels[q, 0] - f_pixels[j, 0], pixels[q, 1] - f_pixels[j, 1]
            along_u = (f_v[j, 1] * du - f_v[j, 0] * dv) / determinant
            along_v = (f_u[j, 0] * dv - f_u[j, 1] * du) / determinant
            along_u = along_u / f_limits[j, 1] if along_u >= 0 else -along_u / f_limits[j, 0]
            along_v = along_v / f_limits[j, 3] if along_v >= 0 else -along_v / f_limits[j, 2]
            inside = max(along_u, along_v)
            source = f_sources[j] + 1
            if inside > scale or inside >= reach[q, source]:
                continue
            n = f_normals[j]
            facing = n[0] * ray_x + n[1] * ray_y + n[2]
            depth = f_points[j, 2]
            if abs(facing) > 1e-12:  # the tangent plane along the point's ray, within reason
                plane = (n[0] * f_points[j, 0] + n[1] * f_points[j, 1] + n[2] * f_points[j, 2]) / facing
                depth = min(max(plane, 0.5 * depth), 1.5 * depth)
            if depth < limits[q]:
                reach[q, source] = inside
