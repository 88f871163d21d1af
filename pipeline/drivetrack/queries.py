"""A DriveTrack clip's queries: the given ones (``--queries-from``) matched to the object's lidar
points, or the projection of each track at a frame drawn among its visible frames."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from pipeline.core.errors import InputError
from pipeline.core.geometry import project, transform_points
from pipeline.core.sampling import queries_from_tracks, sample_query_frames
from pipeline.export.given_queries import given_query_frames


def match_given_queries(
    pool: np.ndarray, queries: np.ndarray, cam_from_box: np.ndarray, fx_fy_cx_cy: np.ndarray, clip: str
) -> np.ndarray:
    """Index into the object's lidar points [P, 3] (box frame) of each given query [N, 3]: the
    point whose projection at the query's frame (camera poses [T, 4, 4]) is nearest (x, y);
    it must lie within half a pixel, as the release's queries are such projections."""
    frames = given_query_frames(queries, len(cam_from_box), clip)
    chosen = np.empty(len(queries), np.int64)
    for t in np.unique(frames):
        rows = np.nonzero(frames == t)[0]
        points = transform_points(cam_from_box[t], pool)
        front = np.nonzero(points[:, 2] > 0)[0]
        if not len(front):
            raise InputError(f"{clip}: no lidar point of the object is in front of the camera at frame {t}")
        distance, nearest = cKDTree(project(points[front], fx_fy_cx_cy)).query(queries[rows, :2])
        if distance.max() > 0.5:
            k = int(np.argmax(distance))
            x, y = queries[rows[k], :2]
            raise InputError(
                f"{clip}: given query {int(rows[k])} at ({x:.1f}, {y:.1f}, t={t}) is {distance[k]:.2f} px "
                "from the nearest lidar point of the object"
            )
        chosen[rows] = front[nearest]
    return chosen


def clip_queries(
    tracks: np.ndarray,
    visibility: np.ndarray,
    given: np.ndarray | None,
    rng: np.random.Generator,
    fx_fy_cx_cy: np.ndarray,
) -> np.ndarray:
    """Queries [N, 3] (x, y, t) of tracks [T, N, 3]: the projection at the given queries' [N, 3]
    frames, or else at a frame drawn uniformly among each track's visible frames [T, N] (NaN for a
    track never visible)."""
    query_frames = sample_query_frames(visibility, rng) if given is None else given[:, 2].astype(np.int64)
    queries = queries_from_tracks(tracks, np.maximum(query_frames, 0), fx_fy_cx_cy)
    queries[query_frames < 0] = np.nan
    return queries
