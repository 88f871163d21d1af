"""A DriveTrack clip's queries: the given ones (``--queries-from``) matched to the object's lidar
points, or where each track appears in the stored frame at a frame drawn among its visible frames."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from pipeline.core.errors import InputError
from pipeline.core.geometry import transform_points
from pipeline.drivetrack.camera_model import UnitCamera
from pipeline.drivetrack.objects import ObjectRun
from pipeline.io.given_queries import given_query_frames


def match_given_queries(
    pool: np.ndarray, queries: np.ndarray, run: ObjectRun, camera: UnitCamera, clip: str
) -> np.ndarray:
    """Index into the object's lidar points [P, 3] (box frame) of each given query [N, 3]: the
    point that appears nearest (x, y) in the stored frame of the query's frame; it must lie within
    half a pixel, as the release's queries are such points."""
    frames = given_query_frames(queries, run.stop - run.start, clip)
    chosen = np.empty(len(queries), np.int64)
    for t in np.unique(frames):
        rows = np.nonzero(frames == t)[0]
        seen = camera.project(run.start + t, transform_points(run.world_from_box[t], pool))
        shown = np.nonzero(seen.in_view)[0]
        if not len(shown):
            raise InputError(f"{clip}: no lidar point of the object is in view at frame {t}")
        distance, nearest = cKDTree(seen.pixels[shown]).query(queries[rows, :2])
        if distance.max() > 0.5:
            k = int(np.argmax(distance))
            x, y = queries[rows[k], :2]
            raise InputError(
                f"{clip}: given query {int(rows[k])} at ({x:.1f}, {y:.1f}, t={t}) is {distance[k]:.2f} px "
                "from the nearest lidar point of the object"
            )
        chosen[rows] = shown[nearest]
    return chosen


def query_frames(visibility: np.ndarray, draws: np.ndarray) -> np.ndarray:
    """Query frame [N] int64 per track: the visible frame [T, N] of rank floor(draw x count) among
    the track's visible frames, for uniform draws [N] in [0, 1); -1 for a track never visible."""
    counts = visibility.sum(axis=0)
    rank = np.minimum((draws * counts).astype(np.int64), np.maximum(counts - 1, 0))
    frames = np.argmax(np.cumsum(visibility, axis=0) > rank[None, :], axis=0).astype(np.int64)
    frames[counts == 0] = -1
    return frames


def clip_queries(
    uv: np.ndarray, visibility: np.ndarray, given: np.ndarray | None, draws: np.ndarray
) -> np.ndarray:
    """Queries [N, 3] (x, y, t): where each track appears in the stored frame (uv [T, N, 2]) at the
    given queries' [N, 3] frames, or else at a frame drawn among its visible frames [T, N] by its
    own uniform draw [N] (``draws.py``); NaN for a track never visible."""
    frames = query_frames(visibility, draws) if given is None else given[:, 2].astype(np.int64)
    xy = uv[np.maximum(frames, 0), np.arange(uv.shape[1])]
    queries = np.concatenate([xy, frames[:, None].astype(np.float64)], axis=1)
    queries[frames < 0] = np.nan
    return queries
