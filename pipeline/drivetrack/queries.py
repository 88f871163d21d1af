"""Which of an object's lidar points a DriveTrack clip tracks (in the box frame, so a point is carried
to every frame by its camera-synced box), and their queries.

Each lidar point of a clip has its own pseudo-random key from (run seed, clip name, frame
timestamp, range-image pixel), so whether a point is drawn, and its query frame, never depend on
which other points exist nor on their order: one point more or less in an object's box changes the
draw by at most that point. The queries are the given ones (``--queries-from``) matched to the
object's lidar points, or where each track appears in the stored frame at a frame drawn among its
visible frames."""

from __future__ import annotations

import dataclasses
import hashlib

import numpy as np
from scipy.spatial import cKDTree

from pipeline.core.errors import InputError
from pipeline.core.geometry import transform_points
from pipeline.drivetrack.camera_model import UnitCamera
from pipeline.drivetrack.lidar import LidarEvidence
from pipeline.drivetrack.objects import ObjectRun
from pipeline.io.given_queries import given_query_frames


@dataclasses.dataclass(frozen=True)
class PointPool:
    """An object's lidar points from the sweeps of its clip frames, in frame order: points [P, 3]
    and unit normals [P, 3] in the box frame, and what names each point: the timestamp [P] of its
    sweep and its range-image pixel [P]; with the refined visibility's evidence, views [P, 3]: the
    unit direction (box frame) from each point to the lidar of its sweep."""

    points: np.ndarray
    normals: np.ndarray
    timestamps: np.ndarray
    pixels: np.ndarray
    views: np.ndarray | None = None


def point_pool(evidence: LidarEvidence, run: ObjectRun, timestamps: np.ndarray) -> PointPool | None:
    """The object's pool from ``evidence`` (camera frame timestamps [T] name the sweeps); None when
    no sweep has a point in its box."""
    bodies = evidence.bodies[run.object_id]
    frames = [t for t in range(run.start, run.stop) if t in bodies and len(bodies[t].points)]
    if not frames:
        return None
    refined = evidence.refined
    return PointPool(
        np.concatenate([bodies[t].points for t in frames]),
        np.concatenate([bodies[t].normals for t in frames]),
        np.concatenate([np.full(len(bodies[t].points), timestamps[t], np.int64) for t in frames]),
        np.concatenate([bodies[t].pixels for t in frames]),
        None if refined is None else np.concatenate([refined.body_views[run.object_id][t] for t in frames]),
    )


def choose_points(
    pool: np.ndarray,
    keys: np.ndarray,
    given: np.ndarray | None,
    run: ObjectRun,
    camera: UnitCamera,
    clip: str,
    count: int,
) -> np.ndarray:
    """Indices into the pool [P, 3] of the points to track: the points the given queries [N, 3]
    fall on (``match_given_queries``), or else the ``count`` (at most P) points of lowest key [P]
    (``point_keys``), sorted."""
    if given is not None:
        return match_given_queries(pool, given, run, camera, clip)
    return lowest_keys(keys, count)


_QUERY_SALT = np.uint64(0x5157_4552_5946_524D)
_FRAME_SALT = np.uint64(0x4652_414D_454B_4559)


def _mix(values: np.ndarray) -> np.ndarray:
    """splitmix64's finaliser on uint64 [...], wrapping arithmetic: a bijection that spreads bits."""
    values = (values ^ (values >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    values = (values ^ (values >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return values ^ (values >> np.uint64(31))


def point_keys(seed: int, clip: str, timestamps: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """uint64 keys [P] of points named by their frame timestamps [P] and range-image pixels [P]."""
    digest = hashlib.sha256(f"{seed}:{clip}".encode()).digest()
    base = np.full(len(pixels), int.from_bytes(digest[:8], "little"), np.uint64)
    stamps = np.asarray(timestamps, np.int64).view(np.uint64)
    return _mix(_mix(base ^ _mix(stamps)) ^ np.asarray(pixels, np.int64).view(np.uint64))


def lowest_keys(keys: np.ndarray, count: int) -> np.ndarray:
    """Sorted indices of the ``count`` (at most all) smallest keys [P]."""
    return np.sort(np.argsort(keys, kind="stable")[:count])


def query_draws(keys: np.ndarray) -> np.ndarray:
    """A uniform draw in [0, 1) [N] per point key [N], independent of the key's rank."""
    return (_mix(keys ^ _QUERY_SALT) >> np.uint64(11)).astype(np.float64) * 2.0**-53


def match_given_queries(
    pool: np.ndarray, queries: np.ndarray, run: ObjectRun, camera: UnitCamera, clip: str
) -> np.ndarray:
    """Index into the object's lidar points [P, 3] (box frame) of each given query [N, 3]: the point
    that appears nearest (x, y) at the query's frame; every query must lie within half a pixel of
    its point, as the release's queries are such points. Where a point appears is its pinhole pixel
    (ours, the schema's) or, when that leaves a query farther, its sensor pixel (where Waymo's frames
    show it): which of the two the release's queries are is not known, so a clip's queries are
    matched by whichever puts every one within half a pixel."""
    frames = given_query_frames(queries, run.stop - run.start, clip)
    pinhole, sensor = (np.empty(len(queries), np.int64) for _ in range(2))
    misses = {"pinhole": np.empty(len(queries)), "sensor": np.empty(len(queries))}
    for t in np.unique(frames):
        rows = np.nonzero(frames == t)[0]
        seen = camera.project(run.start + t, transform_points(run.world_from_box[t], pool))
        shown = np.nonzero(seen.in_view)[0]
        if not len(shown):
            raise InputError(f"{clip}: no lidar point of the object is in view at frame {t}")
        for chosen, kind, pixels in ((pinhole, "pinhole", seen.pixels), (sensor, "sensor", seen.sensor)):
            distance, nearest = cKDTree(pixels[shown]).query(queries[rows, :2])
            chosen[rows], misses[kind][rows] = shown[nearest], distance
    for chosen, kind in ((pinhole, "pinhole"), (sensor, "sensor")):
        if misses[kind].max() <= 0.5:
            return chosen
    k = int(np.argmax(misses["pinhole"]))
    x, y, t = queries[k]
    raise InputError(
        f"{clip}: given query {k} at ({x:.1f}, {y:.1f}, t={int(t)}) is {misses['pinhole'][k]:.2f} px "
        "from the nearest lidar point of the object"
    )


def query_frames(visibility: np.ndarray, draws: np.ndarray) -> np.ndarray:
    """Query frame [N] int64 per track: the visible frame [T, N] of rank floor(draw x count) among
    the track's visible frames, for uniform draws [N] in [0, 1); -1 for a track never visible."""
    counts = visibility.sum(axis=0)
    rank = np.minimum((draws * counts).astype(np.int64), np.maximum(counts - 1, 0))
    frames = np.argmax(np.cumsum(visibility, axis=0) > rank[None, :], axis=0).astype(np.int64)
    frames[counts == 0] = -1
    return frames


def lowest_key_frames(visibility: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """Query frame [N] int64 per track: of the track's visible frames [T, N], the one whose key (the
    track's key [N] mixed with the frame's index) is lowest; -1 for a track never visible. Uniform
    among the visible frames, as ``query_frames`` is, but a visibility change at another frame
    leaves the choice where it was (a rank among the visible frames moves with any change before it)."""
    stamps = _mix(np.arange(visibility.shape[0], dtype=np.uint64) ^ _FRAME_SALT)
    frame_keys = _mix(keys[None, :] ^ stamps[:, None])
    frames = np.argmin(np.where(visibility, frame_keys, np.iinfo(np.uint64).max), axis=0).astype(np.int64)
    frames[~visibility.any(axis=0)] = -1
    return frames


def clip_queries(
    uv: np.ndarray, visibility: np.ndarray, given: np.ndarray | None, keys: np.ndarray, stable: bool
) -> np.ndarray:
    """Queries [N, 3] (x, y, t): where each track appears in the stored frame (uv [T, N, 2]) at the
    given queries' [N, 3] frames, or else at a frame drawn among its visible frames [T, N] by the
    track's key [N]: ``lowest_key_frames`` when ``stable``, else by its uniform draw
    (``query_draws``, ``query_frames``); NaN for a track never visible."""
    if given is not None:
        frames = given[:, 2].astype(np.int64)
    elif stable:
        frames = lowest_key_frames(visibility, keys)
    else:
        frames = query_frames(visibility, query_draws(keys))
    xy = uv[np.maximum(frames, 0), np.arange(uv.shape[1])]
    queries = np.concatenate([xy, frames[:, None].astype(np.float64)], axis=1)
    queries[frames < 0] = np.nan
    return queries
