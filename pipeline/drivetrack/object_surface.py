"""The tracked object's own surface (refined visibility), for self-occlusion.

In each sweep, the object's returns (``objects.on_surface_box``: its box grown a little, the ground
below it left out) are joined into triangles between range-image neighbours that lie on one surface:
range steps no larger than a surface seen MAX_STEP_SPACINGS beam spacings deep makes, and a triangle
normal within MIN_NORMAL_COSINE of its corners' normals (no skirt across a depth step, no chord
across a concave corner). The triangles are kept in the box frame, where the object is rigid, so the
surface seen in every sweep of the clip serves every frame.

A track point is hidden by its own object when the camera's ray to it crosses the surface in front of
it, by more than the clearance, in the sweeps of both halves of the clip (even and odd sweeps): a
triangle that one sweep got wrong is not confirmed by the other half.
"""

from __future__ import annotations

import numba
import numpy as np

# A triangle's range step may be at most this many beam spacings (at its nearest corner's range):
# a plane seen at up to 80 degrees from its normal.
MAX_STEP_SPACINGS = 7.5
# Each corner's range-image normal within this cosine of the triangle's own.
MIN_NORMAL_COSINE = 0.95


def surface_triangles(pixels: np.ndarray, ranges: np.ndarray, spacing: np.ndarray) -> np.ndarray:
    """Triangles [M, 3] (indices into the K returns) of returns at range-image pixels [K] (flat
    indices into ranges [H, W], ascending), rows' angular spacing [H] (``footprints.row_spacings``):
    each square of four neighbouring returns gives two triangles, three of them one, when their range
    steps are those of one surface (``consistent_triangles`` checks their normals). In order: every
    square's first triangle (here, right, down), then every square's second (right, diagonal, down),
    then the three-return squares' (here, diagonal, down) and (here, right, diagonal)."""
    pixels, ranges = np.asarray(pixels, np.int64), np.ascontiguousarray(ranges, np.float64)
    triangles = np.empty((2 * len(pixels), 3), np.int64)
    return triangles[: _surface_triangles(pixels, ranges, spacing, MAX_STEP_SPACINGS, triangles)]


@numba.njit(cache=True, nogil=True)
def _surface_triangles(pixels, ranges, spacing, max_step, triangles):
    """Fills triangles [<= 2K, 3] (``surface_triangles``) and returns their count. A triangle's range
    step (largest less smallest corner range) is at most max_step x its nearest range x its beam
    spacing (the larger of the azimuth's and its corner rows')."""
    height, width = ranges.shape
    corners = np.empty((4, len(pixels), 3), np.int64)  # per kind, the squares' candidates
    counts = np.zeros(4, np.int64)
    for k in range(len(pixels)):
        row, col = pixels[k] // width, pixels[k] % width
        if row + 1 >= height or col + 1 >= width:
            continue
        right = _position(pixels, pixels[k] + 1)
        down = _position(pixels, pixels[k] + width)
        diagonal = _position(pixels, pixels[k] + width + 1)
        if right >= 0 and down >= 0:
            counts[0] = _put(corners[0], counts[0], k, right, down)
            if diagonal >= 0:
                counts[1] = _put(corners[1], counts[1], right, diagonal, down)
        elif diagonal >= 0 and down >= 0:
            counts[2] = _put(corners[2], counts[2], k, diagonal, down)
        elif diagonal >= 0 and right >= 0:
            counts[3] = _put(corners[3], counts[3], k, right, diagonal)
    flat = ranges.ravel()
    azimuth = 2.0 * np.pi / width
    count = 0
    for kind in range(4):
        for m in range(counts[kind]):
            low = high = flat[pixels[corners[kind, m, 0]]]
            beam = azimuth
            for c in range(3):
                corner = pixels[corners[kind, m, c]]
                low = min(low, flat[corner])
                high = max(high, flat[corner])
                beam = max(beam, spacing[corner // width])
            if high - low <= max_step * low * beam:
                count = _put(triangles, count, corners[kind, m, 0], corners[kind, m, 1], corners[kind, m, 2])
    return count


@numba.njit(cache=True, nogil=True)
def _put(rows, count, a, b, c):
    """Writes (a, b, c) into row ``count`` of rows [R, 3]; the count after it."""
    rows[count, 0], rows[count, 1], rows[count, 2] = a, b, c
    return count + 1


@numba.njit(cache=True, nogil=True)
def _position(sorted_pixels, wanted):
    """Index of the wanted pixel in the sorted pixels [K], -1 where it is not one of them (a binary
    search written out: np.searchsorted costs more than a second of compiling per process)."""
    low, high = 0, len(sorted_pixels)
    while low < high:  # the first position holding wanted or more
        middle = (low + high) // 2
        if sorted_pixels[middle] < wanted:
            low = middle + 1
        else:
            high = middle
    return low if low < len(sorted_pixels) and sorted_pixels[low] == wanted else -1


def consistent_triangles(points: np.ndarray, normals: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """The triangles [M, 3] over points [K, 3] whose own normal lies within MIN_NORMAL_COSINE of each
    corner's normal [K, 3] (either sign)."""
    keep = np.empty(len(triangles), np.bool_)
    _consistent(
        np.ascontiguousarray(points, np.float64),
        np.ascontiguousarray(normals, np.float64),
        triangles,
        MIN_NORMAL_COSINE,
        keep,
    )
    return triangles[keep]


@numba.njit(cache=True, nogil=True)
def _consistent(points, normals, triangles, min_cosine, keep):
    """keep [M] (``consistent_triangles``): sums in NumPy's order (np.linalg.norm's (x + y) + z,
    einsum's (x + z) + y), the bits of the array expressions."""
    for m in range(len(triangles)):
        a, b, c = triangles[m, 0], triangles[m, 1], triangles[m, 2]
        ux, uy, uz = points[b, 0] - points[a, 0], points[b, 1] - points[a, 1], points[b, 2] - points[a, 2]
        vx, vy, vz = points[c, 0] - points[a, 0], points[c, 1] - points[a, 1], points[c, 2] - points[a, 2]
        nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
        length = np.sqrt((nx * nx + ny * ny) + nz * nz)
        keep[m] = length > 0
        if not keep[m]:
            continue
        nx, ny, nz = nx / length, ny / length, nz / length
        for corner in (a, b, c):
            cosine = (nx * normals[corner, 0] + nz * normals[corner, 2]) + ny * normals[corner, 1]
            keep[m] = keep[m] and abs(cosine) >= min_cosine


class OwnSurface:
    """An object's surface in its box frame, from its sweeps' triangles, in two halves (even and
    odd sweeps in clip order) cast against with open3d's ray casting (Embree).

    sweeps: per sweep of the clip, in order, (points [K, 3] box frame, triangles [M, 3]).

    open3d is imported here, not with the module: it takes about a second, which the release's
    rules never need."""

    def __init__(self, sweeps: list[tuple[np.ndarray, np.ndarray]]):
        import open3d as o3d

        self._tensor = o3d.core.Tensor.from_numpy
        self.halves: list[o3d.t.geometry.RaycastingScene | None] = []
        for half in (sweeps[0::2], sweeps[1::2]):
            scene = o3d.t.geometry.RaycastingScene(nthreads=1)
            offset, vertices, faces = 0, [], []
            for points, triangles in half:
                vertices.append(points)
                faces.append(triangles + offset)
                offset += len(points)
            if not sum(len(f) for f in faces):
                self.halves.append(None)  # nothing to confirm a crossing with
                continue
            scene.add_triangles(
                o3d.core.Tensor.from_numpy(np.concatenate(vertices).astype(np.float32)),
                o3d.core.Tensor.from_numpy(np.concatenate(faces).astype(np.uint32)),
            )
            self.halves.append(scene)

    def hides(self, points: np.ndarray, rays: np.ndarray, clearance: np.ndarray) -> np.ndarray:
        """[N] bool: the rays [N, 3] that end at points [N, 3] (both box frame) cross the surface of
        both halves more than ``clearance`` [N] (metres) before their end. Each half casts only the
        rays that every half before it found crossing."""
        scenes = [scene for scene in self.halves if scene is not None]
        hidden = np.zeros(len(points), bool)
        if not len(points) or len(scenes) < len(self.halves):
            return hidden
        length = np.linalg.norm(rays, axis=1)
        short = rays * np.clip(1.0 - clearance / length, 0.0, 1.0)[:, None]
        cast = np.concatenate([points - rays, short], axis=1).astype(np.float32)
        crossing = np.arange(len(points))
        for scene in scenes:
            hits = scene.test_occlusions(self._tensor(cast[crossing]), tnear=0.0, tfar=1.0, nthreads=1)
            crossing = crossing[hits.numpy().astype(bool)]
        hidden[crossing] = True
        return hidden
