"""Re-render ADT frames as the release's generator does (tapnet ``adt_utils.py``; docs/formats.md,
section 4): projectaria-tools' ``distort_by_calibration`` to a linear camera of 512x512, focal
280, principal point (W/2, H/2) = (256, 256), then a 90-degree clockwise rotation. The frames are
pixel for pixel the generator's before JPEG encoding (``tests/adt/test_frames.py``).

Pixel convention of the stored frames (TAP-Vid's): pixel [row r, column c] covers [c, c+1) x
[r, r+1), its centre is (c + 0.5, r + 0.5). projectaria-tools puts pixel centres at integers, so
its principal point 256 is 256.5 here, in both axes, before the rotation; the rotation
(x, y) -> (S - y, x) moves it to (255.5, 256.5). The stored frames' true intrinsics are
therefore (280, 280, 255.5, 256.5) (``stored_intrinsics``), not the nominal (280, 280, 256, 256)
the release writes.

The rotation is pure NumPy (``rotate_cw``, ``rotate_pixels_cw``, ``CAM_ROT_FROM_CAM``);
``Rectifier`` applies one ``Remap`` per sequence (``remap.py``): the library's own projection
gives each stored pixel its fisheye point once, then every frame is a NumPy gather.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from pipeline.adt.remap import Remap, source_points

# Clockwise rotation of the image by 90 degrees as a camera rotation: X' = -Y, Y' = X, Z' = Z.
# Applied to points in the unrotated pinhole camera [3] it gives points in the stored camera.
CAM_ROT_FROM_CAM = np.array(
    [[0.0, -1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
)


def rotate_cw(image: np.ndarray) -> np.ndarray:
    """Rotate an image [S, S, ...] by 90 degrees clockwise (a contiguous copy).

    Pixel mapping (indices): ``out[r, c] = image[S - 1 - c, r]``; equivalently the source pixel
    at (row v, column u) lands at (row u, column S - 1 - v). In continuous coordinates with
    pixel centres at +0.5: (x, y) -> (S - y, x), which is ``rotate_pixels_cw``. The same pixels
    as the generator's ``PIL.Image.fromarray(image).rotate(-90)`` (a transpose for a square image).
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


def stored_intrinsics(size: int, focal: float) -> np.ndarray:
    """The stored (rotated) frames' true intrinsics [4] (fx, fy, cx, cy), pixel centres at +0.5.

    Before the rotation the optical axis is at (S/2 + 0.5, S/2 + 0.5) (projectaria's S/2 with
    integer centres); (x, y) -> (S - y, x) moves it to (S/2 - 0.5, S/2 + 0.5).
    """
    half = size / 2.0
    return np.array([focal, focal, half - 0.5, half + 0.5], dtype=np.float64)


def stored_cam_from_world(world_from_camera: np.ndarray) -> np.ndarray:
    """World-to-stored-camera [..., 4, 4] from the RGB camera's pose(s) in the world [..., 4, 4]."""
    from pipeline.core.geometry import invert_se3

    return CAM_ROT_FROM_CAM @ invert_se3(world_from_camera)


def target_calibration(source_calibration, size: int, focal: float):
    """The release generator's LINEAR camera [S, S]: focal ``focal``, principal point (S/2, S/2) in
    projectaria-tools' integer-centre pixels, i.e. (S/2 + 0.5, S/2 + 0.5) in ours
    (``stored_intrinsics``). Its pose is unused (distort_by_calibration ignores both poses)."""
    from projectaria_tools.core import calibration

    return calibration.CameraCalibration(
        source_calibration.get_label(),
        calibration.CameraModelType.LINEAR,
        np.array([focal, focal, size / 2.0, size / 2.0], dtype=np.float64),
        source_calibration.get_transform_device_camera(),
        size,
        size,
        None,
        np.pi,
        "pinhole",
    )


@dataclasses.dataclass(frozen=True)
class _Camera:
    """A source calibration with the stored frame's size and focal, equal by value: everything
    ``project`` depends on."""

    model: str
    params: bytes
    image_size: tuple[int, int]
    valid_radius: float
    max_solid_angle: float
    size: int
    focal: float
    calibration: object = dataclasses.field(compare=False)

    @classmethod
    def of(cls, calibration, size: int, focal: float) -> _Camera:
        width, height = calibration.get_image_size()
        return cls(
            str(calibration.get_model_name()),
            np.asarray(calibration.get_projection_params(), np.float64).tobytes(),
            (int(width), int(height)),
            float(calibration.get_valid_radius()),
            float(calibration.get_max_solid_angle()),
            int(size),
            float(focal),
            calibration,
        )


@functools.lru_cache(maxsize=2)  # 16 MiB each at 512x512
def _stored_remap(camera: _Camera) -> Remap:
    target = target_calibration(camera.calibration, camera.size, camera.focal)
    points = rotate_cw(source_points(camera.calibration, target))  # the rotation, once
    width, height = camera.image_size
    return Remap(points, (height, width))


def stored_remap(source_calibration, size: int, focal: float) -> Remap:
    """Fisheye [H, W] -> stored frame [S, S] (re-rendered, then rotated clockwise) as one
    ``Remap``, built once per calibration per process (S^2 calls of projectaria-tools'
    ``project``, about 0.5 s)."""
    return _stored_remap(_Camera.of(source_calibration, size, focal))


class Rectifier:
    """Fisheye RGB / depth / id images [H, W, ...] -> the stored upright pinhole frames [S, S, ...]:
    the release generator's ``distort_*_by_calibration`` then ``rotate_cw``, pixel for pixel
    (``Remap``; ``tests/adt/test_remap.py`` holds them against the library).

    Args:
      source_calibration: the RGB camera's projectaria-tools ``CameraCalibration`` (Fisheye624).
      size, focal: the square pinhole camera.
    """

    def __init__(self, source_calibration, size: int, focal: float):
        self.remap = stored_remap(source_calibration, int(size), float(focal))

    def rgb(self, image: np.ndarray) -> np.ndarray:
        """Fisheye RGB [H, W, 3] uint8 -> stored frame [S, S, 3] uint8 (bilinear)."""
        return self.remap.rgb(image)

    def depth_mm(self, depth_mm: np.ndarray) -> np.ndarray:
        """Fisheye z-depth [H, W] uint16 mm -> stored depth [S, S] float32 mm (0 = none).

        Bilinear in float millimetres (the library on the float32 image; on uint16 it would cut
        the interpolation to whole millimetres). ADT depth is the z of the RGB camera, which the
        pinhole camera shares (same frame, only the projection changes), so no per-pixel
        conversion is needed.
        """
        return self.remap.depth(depth_mm)

    def ids(self, ids: np.ndarray) -> np.ndarray:
        """Fisheye instance ids [H, W] uint64 -> stored ids [S, S] uint64 (nearest neighbour)."""
        return self.remap.labels(ids)
