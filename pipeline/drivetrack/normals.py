"""Surface normals of an object's lidar points, for the facing test (``visibility.py``)."""

from __future__ import annotations

import numpy as np
import open3d as o3d


def surface_normals(points: np.ndarray, sensor: np.ndarray, radius: float = 0.3) -> np.ndarray:
    """Unit normals [K, 3] of one sweep's points [K, 3] on an object (open3d's local PCA over
    neighbours within ``radius`` metres), turned to face the lidar at ``sensor`` [3], which
    saw those surfaces from its side."""
    if len(points) < 3:
        normals = sensor - points
        return normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=radius, max_nn=16))
    normals = np.asarray(cloud.normals)
    flip = np.einsum("ki,ki->k", normals, sensor - points) < 0
    normals[flip] *= -1.0
    return normals
