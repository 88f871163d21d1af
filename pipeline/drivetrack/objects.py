"""Which vehicles become clips of a unit, and on which frames: the objects the camera sees best
whose box projects into it on enough contiguous frames (cut into windows of ``drivetrack.clip_frames``),
near enough; and the geometry of their upright 7-DoF boxes (cx, cy, cz, length, width, height,
heading)."""

from __future__ import annotations

import dataclasses
from collections import Counter

import numpy as np

from pipeline.core.errors import InputError
from pipeline.core.geometry import rotation_z, se3_from_rotation_translation, transform_points
from pipeline.core.outcomes import NotMade
from pipeline.core.windows import cut
from pipeline.drivetrack.camera_model import Projection, UnitCamera
from pipeline.drivetrack.records import UnitInput
from pipeline.drivetrack.settings import DriveTrackConfig
from pipeline.drivetrack.units import clip_name


@dataclasses.dataclass(frozen=True)
class ObjectRun:
    """A vehicle's clip ``name``: frames [start, stop) of the camera, its boxes on those frames.

    world_from_box: [T, 4, 4] camera-synced box poses in the world.
    lidar_boxes: [T, 7] lidar boxes (vehicle frame at frame time).
    """

    name: str
    object_id: str
    start: int
    stop: int
    world_from_box: np.ndarray
    lidar_boxes: np.ndarray


def assigned_camera(most_visible: np.ndarray) -> int:
    """The camera an object belongs to: its most frequent ``most_visible_camera_name`` over its
    labels [R] (the lowest camera on ties)."""
    votes = Counter(most_visible.tolist())
    return min(votes, key=lambda cam: (-votes[cam], cam))


def boxes_per_frame(unit: UnitInput, object_id: str, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """An object's (camera-synced, lidar) boxes per camera frame, each [T, 7] (NaN on frames without
    a label), from its label rows [R] (checked finite)."""
    boxes = unit.boxes
    for component, values in (
        ("lidar_box", boxes.lidar_boxes),
        ("lidar_camera_synced_box", boxes.synced_boxes),
    ):
        bad = ~np.isfinite(values[rows]).all(axis=1)
        if bad.any():
            raise InputError(
                f"{component}/{unit.segment} object {object_id} frame {boxes.timestamps[rows][bad][0]}: "
                "NaN or infinity in the box"
            )
    frame_index = {ts: i for i, ts in enumerate(unit.frames.timestamps.tolist())}
    num_frames = len(unit.frames.timestamps)
    synced = np.full((num_frames, 7), np.nan)
    lidar = np.full((num_frames, 7), np.nan)
    for row in rows:
        index = frame_index.get(int(boxes.timestamps[row]))
        if index is not None:
            synced[index] = boxes.synced_boxes[row]
            lidar[index] = boxes.lidar_boxes[row]
    return synced, lidar


def box_in_view(corners: Projection, width: int, height: int) -> bool:
    """True when the rectangle around a box's corners [8] in front of the camera, as they appear in
    the stored frame, overlaps the ``width`` x ``height`` image."""
    front = corners.points[:, 2] > 0
    if not front.any():
        return False
    uv = corners.pixels[front]
    return bool(
        uv[:, 0].max() >= 0 and uv[:, 0].min() < width and uv[:, 1].max() >= 0 and uv[:, 1].min() < height
    )


OBJECT_TYPES = {1: "vehicle", 2: "pedestrian", 3: "sign", 4: "cyclist"}


def select_objects(
    unit: UnitInput,
    camera: UnitCamera,
    world_from_frame: np.ndarray,
    rules: DriveTrackConfig,
    wanted: frozenset[str] | None = None,
) -> tuple[list[ObjectRun], dict[str, str]]:
    """Vehicles assigned to this camera whose box projects on enough contiguous frames, each on its
    longest such run (cut into windows of ``drivetrack.clip_frames``, each a run of its own), with a
    box corner within reach on one of its frames; in object-id order, then window order.

    world_from_frame: [T, 4, 4] vehicle pose per camera frame (``camera_model.frame_poses``).
    wanted: object ids to consider (a release run's); None: every object of the segment.
    Returns the runs and, by clip name, why each object or window considered makes none (and each
    wanted id the segment does not have).
    """
    known = set(unit.boxes.object_ids.tolist())
    absent = sorted((wanted or set()) - known)
    skipped = {
        clip_name(unit.segment, unit.camera, i): f"object id {i} is not among the segment's boxes"
        for i in absent
    }
    runs = []
    for object_id in sorted(known if wanted is None else known & wanted):
        for name, made in object_runs(unit, camera, world_from_frame, object_id, rules).items():
            if isinstance(made, NotMade):
                skipped[name] = made.reason
            else:
                runs.append(made)
    return runs, skipped


def object_runs(
    unit: UnitInput, camera: UnitCamera, world_from_frame: np.ndarray, object_id: str, rules: DriveTrackConfig
) -> dict[str, ObjectRun | NotMade]:
    """The clip runs of one object of the segment by name (its longest run, or that run's windows),
    or why one makes none on this unit's camera."""
    name = clip_name(unit.segment, unit.camera, object_id)
    rows = np.nonzero(unit.boxes.object_ids == object_id)[0]
    refused = not_tracked(unit, object_id, rows, rules)
    if refused is not None:
        return {name: refused}
    synced, lidar = boxes_per_frame(unit, object_id, rows)
    labelled = np.isfinite(synced[:, 0])
    world_from_box = np.full((len(synced), 4, 4), np.nan)
    world_from_box[labelled] = world_from_frame[labelled] @ box_poses(synced[labelled])
    in_view_flags = np.zeros(len(synced), bool)
    nearest = np.full(len(synced), np.inf)
    for t in np.flatnonzero(labelled).tolist():
        corners = camera.project(t, transform_points(world_from_box[t], box_corners_local(synced[t])))
        in_view_flags[t] = box_in_view(corners, unit.calibration.width, unit.calibration.height)
        nearest[t] = np.linalg.norm(corners.points, axis=1).min()
    start, stop = longest_run(in_view_flags)
    if stop - start < rules.min_contiguous_frames:
        why = (
            f"object {object_id}'s box is in view on at most {stop - start} contiguous frame(s), fewer "
            f"than drivetrack.min_contiguous_frames={rules.min_contiguous_frames}"
        )
        return {name: NotMade(why)}
    runs: dict[str, ObjectRun | NotMade] = {}
    for window in cut(name, stop - start, rules.clip_frames, rules.min_contiguous_frames):
        first, last = start + window.start, start + window.stop
        closest = nearest[first:last].min()
        runs[window.name] = (
            ObjectRun(window.name, object_id, first, last, world_from_box[first:last], lidar[first:last])
            if closest <= rules.max_corner_distance_m
            else NotMade(
                f"object {object_id}'s box comes no nearer than {closest:.1f} m, beyond "
                f"drivetrack.max_corner_distance_m={rules.max_corner_distance_m:g}"
            )
        )
    return runs


def not_tracked(unit: UnitInput, object_id: str, rows: np.ndarray, rules: DriveTrackConfig) -> NotMade | None:
    """Why the object of label rows [R] makes no clip on this unit's camera whatever its boxes: its
    type is not tracked, or another camera sees it most; None when neither."""
    kind = int(unit.boxes.types[rows[0]])
    if kind not in rules.object_types:
        types = ",".join(str(t) for t in rules.object_types)
        return NotMade(
            f"object {object_id} is of type {kind} ({OBJECT_TYPES.get(kind, 'unknown')}), not in "
            f"drivetrack.object_types={types}"
        )
    assigned = assigned_camera(unit.boxes.most_visible_camera[rows])
    if assigned != unit.camera:
        return NotMade(
            f"object {object_id} belongs to camera {assigned} (the one that sees it most), not {unit.camera}"
        )
    return None


_CORNER_SIGNS = np.array(
    [[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=np.float64
)


def box_poses(boxes: np.ndarray) -> np.ndarray:
    """parent_from_box transforms [..., 4, 4] = translate(center) Rz(heading) for boxes [..., 7]."""
    return se3_from_rotation_translation(rotation_z(boxes[..., 6]), boxes[..., :3])


def box_corners_local(box: np.ndarray) -> np.ndarray:
    """The 8 corners [8, 3] of a box [7] in its own frame."""
    return _CORNER_SIGNS * (box[3:6] / 2.0)


# An object's surface (refined visibility) reaches this far beyond its box on every side but the
# bottom, which is raised by as much so that the ground it stands on stays out.
SURFACE_GROW_M = 0.05


def on_surface_box(points_local: np.ndarray, size: np.ndarray) -> np.ndarray:
    """True for points [M, 3] in box coordinates on the object of a box of ``size`` [3]: inside the
    box grown by ``SURFACE_GROW_M`` on every side but the bottom, which is raised by as much."""
    half = np.asarray(size) / 2.0
    lateral = np.all(np.abs(points_local[:, :2]) <= half[:2] + SURFACE_GROW_M, axis=1)
    height = points_local[:, 2]
    return lateral & (height <= half[2] + SURFACE_GROW_M) & (height >= SURFACE_GROW_M - half[2])


def inside_box(points_local: np.ndarray, size: np.ndarray, shrink: float) -> np.ndarray:
    """True for points [M, 3] in box coordinates inside the box of ``size`` [3] shrunk by
    ``shrink`` metres in each dimension."""
    half = (np.asarray(size) - shrink) / 2.0
    return np.all(np.abs(points_local) <= half, axis=-1)


def longest_run(flags: np.ndarray) -> tuple[int, int]:
    """[start, stop) of the longest run of True in ``flags`` [T] (earliest on ties; (0, 0) if none)."""
    best, start = (0, 0), None
    for index, flag in enumerate(list(flags) + [False]):
        if flag and start is None:
            start = index
        elif not flag and start is not None:
            if index - start > best[1] - best[0]:
                best = (start, index)
            start = None
    return best
