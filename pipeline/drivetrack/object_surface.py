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
    steps are those of one surface (``consistent_triangles`` checks their normals)."""
    height, width = ranges.shape
    rows, cols = pixels // width, pixels % width
    here = np.flatnonzero((rows + 1 < height) & (cols + 1 < width))
    right, down, diagonal = (_position(pixels, pixels[here] + step) for step in (1, width, width + 1))
    has_right, has_down, has_diagonal = right >= 0, down >= 0, diagonal >= 0
    four = has_right & has_down & has_diagonal
    candidates = [
        (np.stack([here, right, down], 1), four | (has_right & has_down & ~has_diagonal)),
        (np.stack([right, diagonal, down], 1), four),
        (np.stack([here, diagonal, down], 1), ~has_right & has_down & has_diagonal),
        (np.stack([here, right, diagonal], 1), has_right & ~has_down & has_diagonal),
    ]
    triangles = np.concatenate([corners[keep] for corners, keep in candidates]).astype(np.int64)
    corner_ranges = ranges.ravel()[pixels[triangles]]
    beam = np.maximum(2.0 * np.pi / width, spacing[rows[triangles]].max(axis=1))
    one_surface = np.ptp(corner_ranges, axis=1) <= MAX_STEP_SPACINGS * corner_ranges.min(axis=1) * beam
    return triangles[one_surface]


def _position(sorted_pixels: np.ndarray, wanted: np.ndarray) -> np.ndarray:
    """Index [Q] of each wanted pixel [Q] in the sorted pixels [K], -1 where it is not one of them."""
    at = np.minimum(np.searchsorted(sorted_pixels, wanted), len(sorted_pixels) - 1)
    return np.where(sorted_pixels[at] == wanted, at, -1)


def consistent_triangles(points: np.ndarray, normals: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """The triangles [M, 3] over points [K, 3] whose own normal lies within MIN_NORMAL_COSINE of each
    corner's normal [K, 3] (either sign)."""
    corners = points[triangles]
    own = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    length = np.linalg.norm(own, axis=1)
    own = own / np.where(length > 0, length, 1.0)[:, None]
    agreement = np.abs(np.einsum("mi,mci->mc", own, normals[triangles])).min(axis=1)
    return triangles[(length > 0) & (agreement >= MIN_NORMAL_COSINE)]


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
        both halves more than ``clearance`` [N] (metres) before their end."""
        scenes = [scene for scene in self.halves if scene is not None]
        if not len(points) or len(scenes) < len(self.halves):
            return np.zeros(len(points), bool)
        length = np.linalg.norm(rays, axis=1)
        short = rays * np.clip(1.0 - clearance / length, 0.0, 1.0)[:, None]
        tensor = self._tensor(np.concatenate([points - rays, short], axis=1).astype(np.float32))
        hidden = np.ones(len(points), bool)
        for scene in scenes:
            hidden &= scene.test_occlusions(tensor, tnear=0.0, tfar=1.0, nthreads=1).numpy().astype(bool)
        return hidden
