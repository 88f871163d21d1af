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
from pipeline.drivetrack.objects import SURFACE_GROW_M, box_corners_local, box_poses

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


def field_edge_rows(rows: np.ndarray, height: int) -> np.ndarray:
    """[K] +1 for returns in range-image rows [K] on row 0 (the highest beam,
    ``lidar.beam_inclinations``), -1 on the last row (the lowest), 0 elsewhere."""
    return np.where(rows == 0, 1, 0) - np.where(rows == height - 1, 1, 0)


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
    normals = sweep.normals(index)
    along = np.empty((2, len(index), 3))
    _half_vectors(
        sweep.grid,
        sweep.ranges,
        sweep.pixels[index],
        sweep.world_from_lidar,
        sweep.pose_of_point[index],
        spacing,
        normals,
        MIN_BEAM_COSINE,
        along,
    )
    return SweepFootprints(sweep.points[index], normals, along[0], along[1], index)


@numba.njit(cache=True, nogil=True)
def _half_vectors(grid, ranges, pixels, world_from_lidar, pose, spacing, normals, min_cosine, along):
    """along [2, K, 3]: the half-vectors along the azimuth and the inclination (world frame) of the
    footprints of returns at range-image pixels [K] (flat), with their poses [K] (rows of
    world_from_lidar [P, 3, 3]) and unit world normals [K, 3]: the beam turned by half the beam
    spacing (pi / W; the row's ``spacing`` [H] / 2) either way, met on the tangent plane, whose
    cosine to the beam counts as at least ``min_cosine``. Rotations summed as ``lidar.turned``,
    dot products as einsum (x + z) + y: the bits of the array expressions."""
    width = ranges.shape[1]
    beam, direction = np.empty(3), np.empty(3)
    for k in range(len(pixels)):
        row, col = pixels[k] // width, pixels[k] % width
        distance = ranges[row, col]
        bx, by, bz = grid[row, col, 0] / distance, grid[row, col, 1] / distance, grid[row, col, 2] / distance
        level = np.hypot(bx, by)
        directions = (
            (-by, bx, 0.0),  # d beam / d azimuth
            (-bx * bz / level, -by * bz / level, level),  # d beam / d inclination
        )
        r = world_from_lidar[pose[k]]
        for i in range(3):
            beam[i] = (r[i, 0] * bx + r[i, 2] * bz) + r[i, 1] * by
        n0, n1, n2 = normals[k, 0], normals[k, 1], normals[k, 2]
        facing = (n0 * beam[0] + n2 * beam[2]) + n1 * beam[1]
        if abs(facing) < min_cosine:
            facing = np.copysign(min_cosine, facing)
        for a in range(2):
            dx, dy, dz = directions[a]
            for i in range(3):
                direction[i] = (r[i, 0] * dx + r[i, 2] * dz) + r[i, 1] * dy
            share = ((n0 * direction[0] + n2 * direction[2]) + n1 * direction[1]) / facing
            scale = distance * (np.pi / width if a == 0 else spacing[row] / 2.0)
            for i in range(3):
                along[a, k, i] = (direction[i] - beam[i] * share) * scale


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
    Per box row on one of the unit's frames: its label, its lidar box [7] (vehicle frame) with its
    box_from_vehicle [4, 4] and reach (metres), box_from_world of its lidar box and world_from_box of
    its camera-synced box [4, 4] (world_from_frame [T, 4, 4]: ``camera_model.frame_poses``)."""

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
        self._detached = invert_se3(poses @ box_poses(boxes.lidar_boxes))
        self._placed = poses @ box_poses(boxes.synced_boxes)
        self._box_from_vehicle = invert_se3(box_poses(boxes.lidar_boxes))
        # Per row, the circumscribed sphere's radius and a metre.
        self._reach = np.array([np.linalg.norm(box[3:6]) / 2.0 + 1.0 for box in boxes.lidar_boxes])

    def label(self, object_id: str) -> int:
        """The label of a labelled object."""
        return int(np.searchsorted(self.object_ids, object_id))

    def labels_at(self, t: int, vehicle_points: np.ndarray) -> np.ndarray:
        """Label [K] of the object each point [K, 3] (vehicle frame of frame t) lies on
        (``objects.on_surface_box`` of its lidar box; the first by label where boxes overlap), -1
        where none."""
        labels = np.full(len(vehicle_points), -1, np.int64)
        rows = self._rows[t][::-1]  # lowest label last: it wins overlaps
        _labels(
            np.ascontiguousarray(vehicle_points, np.float64),
            self._lidar[rows],
            self._box_from_vehicle[rows],
            self._reach[rows],
            self._labels[rows],
            SURFACE_GROW_M,
            labels,
        )
        return labels

    def box_limits(
        self,
        t: int,
        footprints: SweepFootprints,
        labels: np.ndarray,
        vehicle_from_world: np.ndarray,
        edge_rows: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """How far the footprints [K] of frame t's sweep reach: limits [K, 4] (in half-vectors, at
        most 1) along -azimuth, +azimuth, -inclination and +inclination, and their half-vectors
        along the inclination [K, 3]. A labelled object's footprint stops at the border of its box
        (``objects.on_surface_box``: no surface of the object lies beyond), the rest reach a whole
        half-vector. labels [K]: ``labels_at``'s.

        Beyond the lidar's field of view: a labelled return in its highest row (``edge_rows`` [K]
        +1) or its lowest (-1) reaches up, or down, as far as its box: the lidar cannot see past
        its highest and lowest beams (a truck's top 15 m away, the lower half of a car 5 m away),
        the camera can, and the object's surface goes on there up to its box."""
        limits = np.ones((len(labels), 4))
        present = np.bincount(labels + 1, minlength=len(self.object_ids) + 1)[1:] > 0
        for row in self._rows[t]:
            if not present[self._labels[row]]:
                continue
            members = np.flatnonzero(labels == self._labels[row])
            box_from_world = self._box_from_vehicle[row] @ vehicle_from_world
            rotation = box_from_world[:3, :3]
            _box_room(
                footprints.points,
                members,
                box_from_world,
                footprints.along_azimuth[members] @ rotation.T,
                footprints.along_inclination[members] @ rotation.T,
                self._lidar[row, 3:6] / 2.0,
                SURFACE_GROW_M,
                limits,
            )
        along_inclination = footprints.along_inclination.copy()
        beyond = np.flatnonzero((edge_rows != 0) & (labels >= 0))
        side = np.where(edge_rows[beyond] > 0, 3, 2)  # the side past the edge
        room = limits[beyond, side]
        stretch = np.where(np.isfinite(room), np.maximum(room, 1.0), 1.0)  # inf: a null half-vector
        along_inclination[beyond] *= stretch[:, None]
        limits = np.clip(limits, MIN_LIMIT, 1.0)
        limits[beyond, side] = 1.0
        limits[beyond, 5 - side] /= stretch
        return limits, along_inclination

    def moves(self, source: int, target: int) -> Moves:
        """How each object with a lidar box at frame ``source`` and a camera-synced box at frame
        ``target`` moves between them (target_world_from_source_world)."""
        placed = {self._labels[row]: row for row in self._rows[target]}
        attached = {self._labels[row]: row for row in self._rows[source] if self._labels[row] in placed}
        labels = sorted(attached)
        to_rows, from_rows = [placed[label] for label in labels], [attached[label] for label in labels]
        transforms = self._placed[to_rows] @ self._detached[from_rows]
        row_of_label = np.full(len(self.object_ids), -1, np.int64)
        row_of_label[labels] = np.arange(len(labels))
        rotations, translations = transforms[:, :3, :3], transforms[:, :3, 3]
        return Moves(row_of_label, np.ascontiguousarray(rotations), np.ascontiguousarray(translations))


@dataclasses.dataclass(frozen=True)
class Moves:
    """How the labelled objects move from a sweep's frame to another frame: per label [L] the row of
    its move, -1 for an object without one, and per row its rotation [R, 3, 3] and translation
    [R, 3] (target_world_from_source_world, ``BoxMotions.moves``)."""

    row_of_label: np.ndarray
    rotations: np.ndarray
    translations: np.ndarray


@numba.njit(cache=True, nogil=True)
def _labels(points, boxes, box_from_vehicle, reach, box_labels, grow, labels):
    """labels [K] (``BoxMotions.labels_at``) of points [K, 3] from lidar boxes [B, 7] laid in order
    (a later one wins overlaps), each with its box_from_vehicle [B, 4, 4], reach [B] (only points
    that near its centre in x and y are carried into the box frame) and label [B]. Points carried as
    ``transform_points`` carries them (einsum's (x + z) + y): the same bits."""
    if not len(points):
        return
    low_x, low_y = points[:, 0].min(), points[:, 1].min()
    high_x, high_y = points[:, 0].max(), points[:, 1].max()
    for b in range(len(boxes)):
        x0, y0, near = boxes[b, 0], boxes[b, 1], reach[b]
        if x0 + near < low_x or y0 + near < low_y or x0 - near > high_x or y0 - near > high_y:
            continue  # no point near this box
        r = box_from_vehicle[b]
        half_x, half_y, half_z = boxes[b, 3] / 2.0, boxes[b, 4] / 2.0, boxes[b, 5] / 2.0
        for k in range(len(points)):
            x, y, z = points[k, 0], points[k, 1], points[k, 2]
            if abs(x - x0) > near or abs(y - y0) > near:
                continue
            local_x = ((r[0, 0] * x + r[0, 2] * z) + r[0, 1] * y) + r[0, 3]
            local_y = ((r[1, 0] * x + r[1, 2] * z) + r[1, 1] * y) + r[1, 3]
            local_z = ((r[2, 0] * x + r[2, 2] * z) + r[2, 1] * y) + r[2, 3]
            if abs(local_x) <= half_x + grow and abs(local_y) <= half_y + grow:
                if local_z <= half_z + grow and local_z >= grow - half_z:
                    labels[k] = box_labels[b]


@numba.njit(cache=True, nogil=True)
def _box_room(points, members, box_from_world, along_azimuth, along_inclination, half, grow, limits):
    """limits [K, 4] of the footprints ``members`` [M] (rows of points [K, 3]), their half-vectors
    in the box frame [M, 3] each (``BoxMotions.box_limits``): the largest multiple (at least 0) of
    each signed half-vector the point can take and stay within the box of half size ``half`` [3]
    grown by ``grow`` (its bottom raised by as much). Points carried as ``transform_points`` carries
    them."""
    r = box_from_world
    upper = np.empty(3)
    lower = np.empty(3)
    for c in range(3):
        upper[c] = half[c] + grow
        lower[c] = -upper[c]
    lower[2] = grow - half[2]
    local = np.empty(3)
    for m in range(len(members)):
        x, y, z = points[members[m], 0], points[members[m], 1], points[members[m], 2]
        for c in range(3):
            local[c] = ((r[c, 0] * x + r[c, 2] * z) + r[c, 1] * y) + r[c, 3]
        for axis in range(2):
            steps = along_azimuth if axis == 0 else along_inclination
            for side in range(2):
                sign = 1.0 if side else -1.0
                room = np.inf
                for c in range(3):
                    step = sign * steps[m, c]
                    if step > 0:
                        room = min(room, (upper[c] - local[c]) / step)
                    elif step < 0:
                        room = min(room, (lower[c] - local[c]) / step)
                limits[members[m], 2 * axis + side] = max(room, 0.0)


# A footprint reaches at least this share of its half-vectors, even from a box's border.
MIN_LIMIT = 0.05


def moved(
    index: np.ndarray, labels: np.ndarray, moves: Moves, points: np.ndarray, *vectors: np.ndarray
) -> tuple[np.ndarray, ...]:
    """World points [K, 3] and directions (each [K, 3]) of the returns ``index`` [N], labels [K],
    moved by their objects' ``moves`` (every labelled one has a move): the moved points and
    directions [N, 3]. Carried as einsum("kij,kj->ki") over the gathered moves carries them."""
    out = np.empty((1 + len(vectors), len(index), 3))
    directions = tuple(np.ascontiguousarray(vector, np.float64) for vector in vectors)
    rotations, translations = moves.rotations, moves.translations
    _moved(index, labels, moves.row_of_label, rotations, translations, points, directions, out)
    return tuple(out)


@numba.njit(cache=True, nogil=True)
def _moved(index, labels, row_of_label, rotations, translations, points, vectors, out):
    """out [1 + V, N, 3] (``moved``) of points [K, 3] and V vectors [K, 3] at rows index [N]."""
    for v in range(len(out)):
        source = points if v == 0 else vectors[v - 1]
        for n in range(len(index)):
            k = index[n]
            x, y, z = source[k, 0], source[k, 1], source[k, 2]
            row = row_of_label[labels[k]] if labels[k] >= 0 else -1
            if row < 0:
                out[v, n, 0], out[v, n, 1], out[v, n, 2] = x, y, z
                continue
            r = rotations[row]
            for i in range(3):
                rotated = (r[i, 0] * x + r[i, 2] * z) + r[i, 1] * y
                out[v, n, i] = rotated + translations[row, i] if v == 0 else rotated


def likely_reach(sweep, index: np.ndarray, spacing: np.ndarray) -> np.ndarray:
    """[K] how far (metres) a footprint of the kept returns ``index`` reaches from its return unless
    its surface is seen within 60 degrees of edge-on: twice the larger half beam spacing, both ways."""
    width = sweep.kept.shape[1]
    pixels = sweep.pixels[index]
    beam = np.maximum(np.pi / width, spacing[pixels // width] / 2.0)
    return 4.0 * sweep.ranges.ravel()[pixels] * beam


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


# The pinhole of the frame's pose misplaces a point, against the camera model, by at most the
# lens's distortion (Waymo's: ~8 px at a 1920x1280 frame's corners) plus the rolling shutter.
LENS_BOUND_PX = 16.0


def serving_returns(
    camera: UnitCamera,
    points: np.ndarray,
    labels: np.ndarray,
    reach: np.ndarray,
    targets: list[tuple[int, Moves, tuple[np.ndarray, np.ndarray]]],
) -> np.ndarray:
    """[F, K] bool: per target frame [F], the returns of a sweep (world points [K, 3], labels [K],
    footprints reaching about ``reach`` [K] metres, ``likely_reach``) whose footprints may serve
    there: moved to it (``targets``: per frame, its moves and its regions, ``object_regions``; a
    labelled return whose object has no move is dropped), near one of its regions
    (``_near_regions``). A footprint seen nearly edge-on may reach further: such a surface covers
    little of the image beyond its return."""
    serving = np.zeros((len(targets), len(points)), np.bool_)
    points = np.ascontiguousarray(points, np.float64)
    for near, (target, moves, (rectangles, depths)) in zip(serving, targets, strict=True):
        _near_regions(
            points,
            labels,
            moves.row_of_label,
            moves.rotations,
            moves.translations,
            np.ascontiguousarray(reach, np.float64),
            camera.cam_from_world[target],
            camera.calibration.fx_fy_cx_cy,
            *shutter_motion(camera, target),
            LENS_BOUND_PX,
            rectangles,
            depths,
            near,
        )
    return serving


def frame_footprints(
    camera: UnitCamera,
    t: int,
    source: int,
    world: tuple[np.ndarray, ...],
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
    pixels, local, half = (
        np.empty((len(points), 2)),
        np.empty((len(points), 3)),
        np.empty((2, len(points), 2)),
    )
    chosen = np.empty(len(points), np.int64)
    count = _overlapping(
        seen.in_view,
        seen.pixels,
        seen.points,
        along_azimuth @ rotation.T,
        along_inclination @ rotation.T,
        camera.calibration.fx_fy_cx_cy,
        *regions,
        (pixels, local, half, chosen),
    )
    chosen = chosen[:count]
    return FrameFootprints(  # copies of the kept rows: a view would keep the K-row buffers alive
        pixels[:count].copy(),
        local[:count].copy(),
        normals[chosen] @ rotation.T,
        half[0, :count].copy(),
        half[1, :count].copy(),
        limits[chosen],
        labels[chosen],
        np.full(count, source, np.int8),
    )


@numba.njit(cache=True, nogil=True)
def _overlapping(in_view, seen_pixels, seen_points, along_u, along_v, lens, rectangles, depths, kept):
    """The count C of the footprints kept, and for them ``kept`` = (pixels [C, 2], camera points
    [C, 3], pixel half-vectors [2, C, 2], rows [C]) of footprints in view where ``in_view`` [K] at
    ``seen_pixels`` [K, 2] and ``seen_points`` [K, 3], their half-vectors [K, 3] each (camera frame):
    the pixel half-vectors are their images through the pinhole's Jacobian (lens: fx, fy, ...); kept
    where the footprint's pixel rectangle (the pixel +- the sum of their sizes) overlaps a rectangle
    [R, 4] (u0, v0, u1, v1) whose depth [R] is beyond the footprint's depth."""
    pixels, points, half, rows = kept
    fx, fy = lens[0], lens[1]
    count = 0
    for k in range(len(in_view)):
        if not in_view[k]:
            continue
        x, y, z = seen_points[k, 0], seen_points[k, 1], seen_points[k, 2]
        u_x = fx * (along_u[k, 0] - x * along_u[k, 2] / z) / z
        u_y = fy * (along_u[k, 1] - y * along_u[k, 2] / z) / z
        v_x = fx * (along_v[k, 0] - x * along_v[k, 2] / z) / z
        v_y = fy * (along_v[k, 1] - y * along_v[k, 2] / z) / z
        reach_u, reach_v = abs(u_x) + abs(v_x), abs(u_y) + abs(v_y)
        u, v = seen_pixels[k, 0], seen_pixels[k, 1]
        for i in range(len(depths)):
            if z < depths[i] and u + reach_u >= rectangles[i, 0] and u - reach_u <= rectangles[i, 2]:
                if v + reach_v >= rectangles[i, 1] and v - reach_v <= rectangles[i, 3]:
                    pixels[count, 0], pixels[count, 1] = u, v
                    points[count, 0], points[count, 1], points[count, 2] = x, y, z
                    half[0, count, 0], half[0, count, 1] = u_x, u_y
                    half[1, count, 0], half[1, count, 1] = v_x, v_y
                    rows[count] = k
                    count += 1
                    break
    return count


@numba.njit(cache=True, nogil=True)
def _near_regions(
    points,
    labels,
    row_of_label,
    rotations,
    translations,
    extent,
    cam_from_world,
    lens,
    travel,
    turn,
    lens_bound,
    rectangles,
    depths,
    near,
):
    """near [K] (``serving_returns``) of world points [K, 3] of labels [K] reaching extent [K]
    metres, moved as ``moved`` moves them (a labelled one without a move is not near): their
    pinhole pixels at the frame's pose (cam_from_world [4, 4], lens: fx, fy, cx, cy), padded by
    what the lens and the rolling shutter can move them (the camera's ``travel`` and ``turn`` over
    the readout, at the point's depth) and by the footprint's size, overlap a region (rectangles
    [R, 4], depths [R]), nearer than its depth."""
    fx, fy, cx, cy = lens[0], lens[1], lens[2], lens[3]
    focal = max(fx, fy)
    r = cam_from_world
    for k in range(len(points)):
        near[k] = False
        x, y, z = points[k, 0], points[k, 1], points[k, 2]
        if labels[k] >= 0:
            row = row_of_label[labels[k]]
            if row < 0:
                continue
            m = rotations[row]
            x, y, z = (
                ((m[0, 0] * x + m[0, 2] * z) + m[0, 1] * y) + translations[row, 0],
                ((m[1, 0] * x + m[1, 2] * z) + m[1, 1] * y) + translations[row, 1],
                ((m[2, 0] * x + m[2, 2] * z) + m[2, 1] * y) + translations[row, 2],
            )
        depth = r[2, 0] * x + r[2, 1] * y + r[2, 2] * z + r[2, 3]
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
        starts = np.zeros(rows * columns + 1, np.int64)
        members = np.empty(int((span[:, 0] * span[:, 1]).sum()), np.int64)
        _bin(first, last, columns, starts, members)
        self.arrays = (origin, side, columns, rows, starts, members)


@numba.njit(cache=True, nogil=True)
def _bin(first, last, columns, starts, members):
    """starts [cells + 1] and members (``BoxCells``) of rectangles spanning the cells first [M, 2] to
    last [M, 2] (column, row): each cell's rectangles in ascending order."""
    for j in range(len(first)):
        for row in range(first[j, 1], last[j, 1] + 1):
            for column in range(first[j, 0], last[j, 0] + 1):
                starts[row * columns + column + 1] += 1
    for cell in range(len(starts) - 1):
        starts[cell + 1] += starts[cell]
    filled = starts[:-1].copy()
    for j in range(len(first)):
        for row in range(first[j, 1], last[j, 1] + 1):
            for column in range(first[j, 0], last[j, 0] + 1):
                cell = row * columns + column
                members[filled[cell]] = j
                filled[cell] += 1


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
