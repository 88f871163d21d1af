"""Which of an object's lidar points a DriveTrack clip tracks (in the box frame, so a point is
carried to every frame by its camera-synced box)."""

from __future__ import annotations

import numpy as np

from pipeline.drivetrack.evidence import LidarEvidence
from pipeline.drivetrack.objects import ObjectRun
from pipeline.drivetrack.queries import match_given_queries


def point_pool(evidence: LidarEvidence, run: ObjectRun) -> tuple[np.ndarray, np.ndarray] | None:
    """The object's lidar points [P, 3] and their normals [P, 3] (box frame) from the sweeps of all
    its clip frames, in frame order; None when no sweep has a point in its box."""
    points, normals = evidence.body_points[run.object_id], evidence.body_normals[run.object_id]
    frames = [t for t in range(run.start, run.stop) if len(points.get(t, ()))]
    if not frames:
        return None
    return np.concatenate([points[t] for t in frames]), np.concatenate([normals[t] for t in frames])


def choose_points(
    pool: np.ndarray,
    given: np.ndarray | None,
    cam_from_box: np.ndarray,
    fx_fy_cx_cy: np.ndarray,
    clip: str,
    count: int,
    rng: np.random.Generator,
) -> np.ndarray:
    """Indices into the pool [P, 3] of the points to track: the points the given queries [N, 3]
    fall on (``match_given_queries``, camera poses [T, 4, 4]), or else ``count`` (at most P)
    drawn without replacement, sorted."""
    if given is not None:
        return match_given_queries(pool, given, cam_from_box, fx_fy_cx_cy, clip)
    return np.sort(rng.choice(len(pool), size=min(len(pool), count), replace=False))
