"""Track points' surface normals fitted on the object's accumulated lidar points (refined visibility).

A range-image normal comes from one sweep's two neighbours, and beside a crease those lie on two
faces. Here every point of the object's clip, from all its sweeps in the box frame, votes: among the
planes through a track point and two of its NEIGHBOURS nearest points, the one they vote for most
wins (Tukey's biweight of a point's distance to the plane: 1 on it, 0 from PLANE_TOLERANCE_M), and
the normal is refitted (principal axes, weighed by the same votes) on that plane's points. Votes
that fall smoothly keep a millimetre's change of the input from swapping one plane for another. It
faces the lidar of the track point's own sweep, which saw that side of the surface.
"""

from __future__ import annotations

import numba
import numpy as np
from scipy.spatial import cKDTree

NEIGHBOURS = 24
PLANE_TOLERANCE_M = 0.01
# Two neighbours span a candidate plane only when they are this far from collinear with the point
# (the sine of the angle between them, seen from the point).
MIN_SPAN_SINE = 0.3


def fitted_normals(points: np.ndarray, tracked: np.ndarray, towards_lidar: np.ndarray) -> np.ndarray:
    """Unit normals [N, 3] at the tracked points [N] (indices into the object's points [P, 3], box
    frame), each facing ``towards_lidar`` [N, 3] (from the point towards the lidar of its sweep)."""
    count = min(NEIGHBOURS, len(points))
    _, neighbours = cKDTree(points).query(points[tracked], k=count)
    neighbours = np.asarray(neighbours, np.int64).reshape(len(tracked), count)
    normals = np.empty((len(tracked), 3))
    _fit(points, points[tracked], neighbours, towards_lidar, PLANE_TOLERANCE_M, MIN_SPAN_SINE, normals)
    return normals


@numba.njit(cache=True, nogil=True)
def _weight(distance, tolerance):
    """A point's vote for a plane it lies ``distance`` from: Tukey's biweight, 1 on the plane, falling
    smoothly to 0 at ``tolerance``; a millimetre's change of a point changes its vote by little."""
    ratio = distance / tolerance
    return (1.0 - ratio * ratio) ** 2 if abs(ratio) < 1.0 else 0.0


@numba.njit(cache=True, nogil=True)
def _fit(points, query, neighbours, towards, tolerance, min_sine, normals):
    """normals [N, 3] (``fitted_normals``) for query points [N, 3] and their neighbours [N, k]."""
    count = neighbours.shape[1]
    offsets = np.empty((count, 3))
    for q in range(len(query)):
        for k in range(count):
            for c in range(3):
                offsets[k, c] = points[neighbours[q, k], c] - query[q, c]
        length = np.sqrt(towards[q, 0] ** 2 + towards[q, 1] ** 2 + towards[q, 2] ** 2)
        best_x, best_y, best_z = towards[q, 0] / length, towards[q, 1] / length, towards[q, 2] / length
        best_score = -1.0
        for i in range(count):
            ax, ay, az = offsets[i, 0], offsets[i, 1], offsets[i, 2]
            length_a = np.sqrt(ax * ax + ay * ay + az * az)
            for j in range(i + 1, count):
                bx, by, bz = offsets[j, 0], offsets[j, 1], offsets[j, 2]
                length_b = np.sqrt(bx * bx + by * by + bz * bz)
                nx, ny, nz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
                length = np.sqrt(nx * nx + ny * ny + nz * nz)
                if length == 0.0 or length < min_sine * length_a * length_b:
                    continue
                nx, ny, nz = nx / length, ny / length, nz / length
                score = 0.0
                for k in range(count):
                    if score + count - k <= best_score:
                        break  # this plane can no longer score as high as the best
                    score += _weight(nx * offsets[k, 0] + ny * offsets[k, 1] + nz * offsets[k, 2], tolerance)
                if score > best_score:
                    best_score = score
                    best_x, best_y, best_z = nx, ny, nz
        normal = np.empty(3)
        normal[0], normal[1], normal[2] = best_x, best_y, best_z
        # Written out where NumPy's array expressions would do: each costs seconds of compiling in
        # every new process.
        weights = np.empty(count)
        members = 0
        for k in range(count):
            weights[k] = _weight(
                offsets[k, 0] * best_x + offsets[k, 1] * best_y + offsets[k, 2] * best_z, tolerance
            )
            members += weights[k] > 0.0
        if members >= 3:  # refit on the plane's points, weighed, and the query point (offset 0, weight 1)
            mean = np.zeros(3)
            total = 1.0
            for k in range(count):
                for c in range(3):
                    mean[c] += weights[k] * offsets[k, c]
                total += weights[k]
            for c in range(3):
                mean[c] /= total
            scatter = np.zeros((3, 3))
            for a in range(3):
                for b in range(3):
                    scatter[a, b] += mean[a] * mean[b]  # the query point's (0 - mean) products
            for k in range(count):
                for a in range(3):
                    for b in range(3):
                        scatter[a, b] += weights[k] * (offsets[k, a] - mean[a]) * (offsets[k, b] - mean[b])
            normal = np.linalg.eigh(scatter)[1][:, 0].copy()
        flip = normal[0] * towards[q, 0] + normal[1] * towards[q, 1] + normal[2] * towards[q, 2] < 0
        for c in range(3):
            normals[q, c] = -normal[c] if flip else normal[c]
