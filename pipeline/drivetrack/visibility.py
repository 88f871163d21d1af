"""Which (frame, track) pairs of a DriveTrack clip are visible: in view, facing the camera
(``drivetrack.facing_test``), and not occluded in the lidar's depth.

Occluded: the reference depth (the largest of the nearest lidar depths at the four integer
pixels around the track point, ``depth.py``) is < (1 - margin) x the track's depth.
"""

from __future__ import annotations

import numpy as np

from pipeline.core.visibility import passes_relative_depth_test
from pipeline.drivetrack.depth import CellGrid, nearest_depth_max4


def facing_camera(tracks: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """[T, N] bool: the surface at track points [T, N, 3] (camera frame), of normals [T, N, 3]
    (camera frame), faces the camera."""
    cosine = np.einsum("tni,tni->tn", normals, -tracks) / np.linalg.norm(tracks, axis=2)
    return cosine > 0


def track_visibility(
    tracks: np.ndarray,
    uv: np.ndarray,
    in_view: np.ndarray,
    normals: np.ndarray | None,
    depth_uv: list[np.ndarray],
    depth_z: list[np.ndarray],
    depth_trees: list[CellGrid | None],
    image_size: tuple[int, int],
    occlusion_margin: float,
) -> np.ndarray:
    """Visibility [T, N] bool of track points [T, N, 3] (camera frame) appearing at uv [T, N, 2] in
    the stored frames of ``image_size`` (width, height), where ``in_view`` [T, N]
    (``camera_model.Projection``).

    normals: [T, N, 3] surface normals (camera frame), or None to skip the facing test.
    depth_uv, depth_z, depth_trees: per frame, the lidar depth samples' pixels [M, 2], depths [M]
    and the pixels' lookup (``depth.depth_tree``).
    """
    visibility = in_view.copy()
    if normals is not None:
        visibility &= facing_camera(tracks, normals)
    for i, (lidar_uv, lidar_z, tree) in enumerate(zip(depth_uv, depth_z, depth_trees, strict=True)):
        candidates = np.nonzero(visibility[i])[0]
        depth = nearest_depth_max4(lidar_uv, lidar_z, uv[i, candidates], *image_size, tree)
        visibility[i, candidates] = passes_relative_depth_test(
            tracks[i, candidates, 2], depth, occlusion_margin
        )
    return visibility
