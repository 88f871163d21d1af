"""Re-render ADT frames to the release's upright pinhole camera: 512x512, focal 280, then a
90-degree clockwise rotation (docs/formats.md, section 4).

Pixel convention of the stored frames: pixel [row r, column c] covers [c, c+1) x [r, r+1), so
its centre is (c + 0.5, r + 0.5) and the intrinsics (280, 280, 256, 256) put the optical axis at
the image centre. projectaria-tools samples pixel index i at coordinate i (centre at the
integer), so the camera it renders is built with principal point 255.5: the same camera. With
the axis at the centre, the rotation maps the image onto itself and the intrinsics stay
(280, 280, 256, 256) exactly.

The rotation is pure NumPy (``rotate_cw``, ``rotate_pixels_cw``, ``CAM_ROT_FROM_CAM``);
``Rectifier`` wraps projectaria-tools' ``distort_by_calibration`` family.
"""

from __future__ import annotations

import numpy as np

# Clockwise rotation of the image by 90 degrees as a camera rotation: X' = -Y, Y' = X, Z' = Z.
# Applied to points in the unrotated pinhole camera [3] it gives points in the stored camera.
CAM_ROT_FROM_CAM = np.array(
    [[0.0, -1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
)


def rotate_cw(image: np.ndarray) -> np.ndarray:
    """Rotate an image [S, S, ...] by 90 degrees clockwise (a contiguous copy).

    Pixel mapping (indices): ``out[r, c] = image[S - 1 - c, r]``; equivalently the source pixel
    at (row v, column u) lands at (row u, column S - 1 - v). In continuous coordinates with
    pixel centres at +0.5: (x, y) -> (S - y, x), which is ``rotate_pixels_cw``.
    """
    if image.shape[0] != image.shape[1]:
        raise ValueError(f"rotate_cw expects a square image, got {image.shape}")
    return np.ascontiguousarray(np.rot90(image, k=-1))


def rotate_pixels_cw(xy: np.ndarray, size: int) -> np.ndarray:
    """Continuous pixel coordinates [..., 2] before the rotation -> after it: (x, y) -> (S - y, x)."""
    xy = np.asarray(xy, dtype=np.float64)
    return np.stack([size - xy[..., 1], xy[..., 0]], axis=-1)


def unrotate_pixels_cw(xy: np.ndarray, size: int) -> np.ndarray:
    """Inverse of ``rotate_pixels_cw``: (x', y') -> (y', S - x')."""
    xy = np.asarray(xy, dtype=np.float64)
    return np.stack([xy[..., 1], size - xy[..., 0]], axis=-1)


def stored_cam_from_world(world_from_camera: np.ndarray) -> np.ndarray:
    """World-to-stored-camera [..., 4, 4] from the RGB camera's pose(s) in the world [..., 4, 4]."""
    from pipeline.core.geometry import invert_se3

    return CAM_ROT_FROM_CAM @ invert_se3(world_from_camera)


class Rectifier:
    """Fisheye RGB / depth / id images -> the stored upright pinhole frames.

    Args:
      source_calibration: the RGB camera's projectaria-tools ``CameraCalibration`` (Fisheye624).
      size, focal: the square pinhole camera.
    """

    def __init__(self, source_calibration, size: int, focal: float):
        from projectaria_tools.core import calibration

        self._calibration = calibration
        self.source = source_calibration
        self.size = int(size)
        centre = self.size / 2.0 - 0.5  # projectaria-tools: pixel centres at integers
        self.target = calibration.CameraCalibration(
            source_calibration.get_label(),
            calibration.CameraModelType.LINEAR,
            np.array([focal, focal, centre, centre], dtype=np.float64),
            source_calibration.get_transform_device_camera(),
            self.size,
            self.size,
            None,
            np.pi,
            "pinhole",
        )

    def rgb(self, image: np.ndarray) -> np.ndarray:
        """Fisheye RGB [H, W, 3] uint8 -> stored frame [S, S, 3] uint8 (bilinear)."""
        return rotate_cw(self._calibration.distort_by_calibration(image, self.target, self.source))

    def depth_m(self, depth_mm: np.ndarray) -> np.ndarray:
        """Fisheye z-depth [H, W] uint16 mm -> stored depth [S, S] float32 metres (0 = none).

        ``distort_depth_by_calibration`` interpolates bilinearly and keeps the values: ADT depth is
        the z of the RGB camera, which the pinhole camera shares (same frame, only the projection
        changes), so no per-pixel conversion is needed.
        """
        depth = self._calibration.distort_depth_by_calibration(depth_mm, self.target, self.source)
        return rotate_cw(depth.astype(np.float32) / np.float32(1000.0))

    def ids(self, ids: np.ndarray) -> np.ndarray:
        """Fisheye instance ids [H, W] uint64 -> stored ids [S, S] uint64 (nearest neighbour)."""
        return rotate_cw(self._calibration.distort_label_by_calibration(ids, self.target, self.source))
