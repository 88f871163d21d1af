"""Which of an object's lidar points a DriveTrack clip tracks (in the box frame, so a point is
carried to every frame by its camera-synced box)."""

from __future__ import annotations

import dataclasses

import numpy as np

from pipeline.drivetrack.camera_model import UnitCamera
from pipeline.drivetrack.draws import lowest_keys
from pipeline.drivetrack.evidence import LidarEvidence
from pipeline.drivetrack.objects import ObjectRun
from pipeline.drivetrack.queries import match_given_queries


@dataclasses.dataclass(frozen=True)
class PointPool:
    """An object's lidar points from the sweeps of its clip frames, in frame order: points [P, 3]
    and unit normals [P, 3] in the box frame, and what names each point: the timestamp [P] of its
    sweep and its range-image pixel [P]."""

    points: np.ndarray
    normals: np.ndarray
    timestamps: np.ndarray
    pixels: np.ndarray


def point_pool(evidence: LidarEvidence, run: ObjectRun, timestamps: np.ndarray) -> PointPool | None:
    """The object's pool from ``evidence`` (camera frame timestamps [T] name the sweeps); None when
    no sweep has a point in its box."""
    points = evidence.body_points[run.object_id]
    frames = [t for t in range(run.start, run.stop) if len(points.get(t, ()))]
    if not frames:
        return None
    return PointPool(
        np.concatenate([points[t] for t in frames]),
        np.concatenate([evidence.body_normals[run.object_id][t] for t in frames]),
        np.concatenate([np.full(len(points[t]), timestamps[t], np.int64) for t in frames]),
        np.concatenate([evidence.body_pixels[run.object_id][t] for t in frames]),
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
    (``draws.py``), sorted."""
    if given is not None:
        return match_given_queries(pool, given, run, camera, clip)
    return lowest_keys(keys, count)
