"""Pinhole camera and SE(3) maths on NumPy arrays (float64 throughout).

Conventions: a transform ``T_a_from_b`` is a [4, 4] matrix mapping points in frame b
to frame a; camera frames follow OpenCV (x right, y down, z forward).
"""

from __future__ import annotations

import numpy as np

# OpenCV camera axes from a camera frame with x forward, y left, z up (Waymo, vehicles):
# X = -y, Y = -z, Z = x.
CV_FROM_FLU = np.array(
    [[0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
)


def invert_se3(transform: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms [..., 4, 4] (uses R^T, exact for rotations)."""
    rot = transform[..., :3, :3]
    trans = transform[..., :3, 3]
    out = np.zeros_like(transform)
    rot_t = np.swapaxes(rot, -1, -2)
    out[..., :3, :3] = rot_t
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", rot_t, trans)
    out[..., 3, 3] = 1.0
    return out


def transform_points(transform: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a [4, 4] transform to points [..., 3]; returns [..., 3]."""
    return np.einsum("ij,...j->...i", transform[:3, :3], points) + transform[:3, 3]


def transform_points_batch(transforms: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply transforms [..., 4, 4] to points [..., N, 3], one transform per point set; e.g.
    poses per frame [T, 4, 4] with points [N, 3] or [T, N, 3]. Returns [..., N, 3]."""
    return transform_directions_batch(transforms, points) + transforms[..., None, :3, 3]


def transform_directions_batch(transforms: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Rotate directions [..., N, 3] (normals) by the rotation of transforms [..., 4, 4], as
    ``transform_points_batch`` without the translation. Returns [..., N, 3]."""
    return np.einsum("...ij,...nj->...ni", transforms[..., :3, :3], directions)


def project(points_cam: np.ndarray, fx_fy_cx_cy: np.ndarray) -> np.ndarray:
    """Pinhole projection of camera-frame points [..., 3] to pixels [..., 2].

    Points with z <= 0 give non-finite or meaningless pixels: mask them with z > 0.
    """
    fx, fy, cx, cy = fx_fy_cx_cy
    z = points_cam[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = fx * points_cam[..., 0] / z + cx
        v = fy * points_cam[..., 1] / z + cy
    return np.stack([u, v], axis=-1)


def unproject(pixels: np.ndarray, depth: np.ndarray, fx_fy_cx_cy: np.ndarray) -> np.ndarray:
    """Paper eq. 1: pixels [..., 2] with z-depth [...] to camera-frame points [..., 3]."""
    fx, fy, cx, cy = fx_fy_cx_cy
    x = (pixels[..., 0] - cx) / fx * depth
    y = (pixels[..., 1] - cy) / fy * depth
    return np.stack([x, y, depth], axis=-1)


def in_image(pixels: np.ndarray, width: int, height: int) -> np.ndarray:
    """True where pixels [..., 2] fall inside [0, width) x [0, height)."""
    u, v = pixels[..., 0], pixels[..., 1]
    return (u >= 0) & (u < width) & (v >= 0) & (v < height)


def rotation_z(yaw: np.ndarray | float) -> np.ndarray:
    """Rotations about z by yaw [...] radians; returns [..., 3, 3]."""
    yaw = np.asarray(yaw, dtype=np.float64)
    c, s = np.cos(yaw), np.sin(yaw)
    zero, one = np.zeros_like(yaw), np.ones_like(yaw)
    return np.stack(
        [np.stack([c, -s, zero], -1), np.stack([s, c, zero], -1), np.stack([zero, zero, one], -1)],
        axis=-2,
    )


def rotation_from_roll_pitch_yaw(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll) for angle arrays [...]; returns [..., 3, 3]."""
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    rows = [
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


def se3_from_rotation_translation(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """Build transforms [..., 4, 4] from rotations [..., 3, 3] and translations [..., 3]."""
    shape = rotation.shape[:-2]
    out = np.zeros(shape + (4, 4))
    out[..., :3, :3] = rotation
    out[..., :3, 3] = translation
    out[..., 3, 3] = 1.0
    return out


def rigid_transform_problem(transform: np.ndarray, tolerance: float = 1e-3) -> str | None:
    """Why [4, 4] ``transform`` is not a usable rigid transform, or None when it is."""
    transform = np.asarray(transform, dtype=np.float64)
    if transform.shape != (4, 4):
        return f"shape {transform.shape}, expected (4, 4)"
    if not np.all(np.isfinite(transform)):
        return "contains NaN or infinity"
    rot = transform[:3, :3]
    if np.abs(rot.T @ rot - np.eye(3)).max() > tolerance or np.linalg.det(rot) < 0:
        return "rotation part is not orthonormal with det +1"
    if np.abs(transform[3] - [0.0, 0.0, 0.0, 1.0]).max() > tolerance:
        return "last row is not [0, 0, 0, 1]"
    return None
