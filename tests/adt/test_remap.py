"""``Remap`` against projectaria-tools' own ``distort_*_by_calibration`` on synthetic cameras:
the same pixels for RGB, depth (uint16 and float32) and labels, including the pixels the library
leaves 0 (failed projections, points off the source image), samples on the source's last row and
column, and nearest-neighbour ties at half pixels. The real excerpt: ``tests/adt/test_frames.py``.
"""

import numpy as np
import pytest

from pipeline.adt.remap import Remap, source_points


def camera(model: str, params, width: int, height: int, valid_radius=None):
    from projectaria_tools.core import calibration

    identity = calibration.get_linear_camera_calibration(1, 1, 1).get_transform_device_camera()
    model_type = getattr(calibration.CameraModelType, model)
    return calibration.CameraCalibration(
        "camera",
        model_type,
        np.asarray(params, np.float64),
        identity,
        width,
        height,
        valid_radius,
        np.pi,
        "x",
    )


# A Fisheye624 source (non-square, with a valid radius) and a pinhole that sees past its edges.
FISHEYE = (
    "FISHEYE624",
    [60, 41.3, 29.7, 0.4, -0.5, 0.17, 1.1, -1.7, 0.65, 6e-4, 2e-5, -1.5e-5, 2.6e-4, -6.6e-4, 3.8e-5],
)
FISHEYE_SHAPE = (61, 83)
WIDE_PINHOLE = ("LINEAR", [30, 30, 24, 17])
# Linear to linear with the same focal: target pixel x samples x - 0.5 (columns), y - 1 (rows), so
# samples fall on exact half pixels, on row 0 and on the last row H - 1 = 29, and off the image.
SHIFTED_SOURCE, SHIFTED_TARGET = ("LINEAR", [50, 50, 20, 15]), ("LINEAR", [50, 50, 20.5, 16])


def images(shape, rng):
    """Random RGB uint8 [H, W, 3], depth uint16 mm with 30% zeros [H, W], ids uint64 [H, W]."""
    rgb = rng.integers(0, 256, (*shape, 3), dtype=np.uint8)
    depth = rng.integers(1, 5000, shape).astype(np.uint16)
    depth[rng.random(shape) < 0.3] = 0
    ids = rng.integers(0, 2**62, shape, dtype=np.uint64)
    return rgb, depth, ids


@pytest.mark.parametrize(
    "source, source_shape, target, target_shape",
    [
        (FISHEYE, FISHEYE_SHAPE, WIDE_PINHOLE, (37, 50)),
        (SHIFTED_SOURCE, (30, 40), SHIFTED_TARGET, (33, 44)),
    ],
)
def test_remap_is_the_librarys_rendering(source, source_shape, target, target_shape):
    from projectaria_tools.core import calibration

    src = camera(*source, source_shape[1], source_shape[0], 40.0 if source[0] == "FISHEYE624" else None)
    dst = camera(*target, target_shape[1], target_shape[0])
    points = source_points(src, dst)
    assert points.shape == (*target_shape, 2)
    assert points.dtype == np.float32
    missing = np.isnan(points[..., 0])
    assert 0 < missing.sum() < missing.size / 2  # some target pixels see nothing
    remap = Remap(points, source_shape)
    past_last_row = points[..., 1] == source_shape[0] - 1
    rng = np.random.default_rng(0)
    for _ in range(3):
        rgb, depth, ids = images(source_shape, rng)
        np.testing.assert_array_equal(remap.rgb(rgb), calibration.distort_by_calibration(rgb, dst, src))
        expected = calibration.distort_depth_by_calibration(depth.astype(np.float32), dst, src)
        # On the source's last row the library also reads the row past the image (weight 0):
        # memory it does not own, so a NaN or inf there makes its pixel NaN, by chance. Ours
        # leaves that tap out; elsewhere, and wherever the library's pixel is finite, the same.
        garbage = past_last_row & ~np.isfinite(expected)
        assert (np.isfinite(expected) | past_last_row).all()
        expected = np.where(garbage, remap.depth(depth), expected)
        np.testing.assert_array_equal(remap.depth(depth), expected)  # uint16 in, float32 mm out
        np.testing.assert_array_equal(remap.depth(depth.astype(np.float32)), expected)
        np.testing.assert_array_equal(
            remap.labels(ids), calibration.distort_label_by_calibration(ids, dst, src)
        )
        assert (remap.rgb(rgb)[missing] == 0).all()
        assert (remap.labels(ids)[missing] == 0).all()


def test_shifted_camera_samples_edges_and_half_pixels():
    src = camera(*SHIFTED_SOURCE, 40, 30)
    dst = camera(*SHIFTED_TARGET, 44, 33)
    points = source_points(src, dst)
    u, v = points[..., 0], points[..., 1]
    found = np.isfinite(u)
    assert set(np.unique(u[found] % 1).tolist()) == {0.5}
    assert np.nanmax(v) == 29
    assert np.nanmin(v) == 0
    # Nearest-neighbour ties round up (int(p + 0.5)), as the library.
    labels = np.tile(np.arange(40, dtype=np.uint64), (30, 1))
    remapped = Remap(points, (30, 40)).labels(labels)
    np.testing.assert_array_equal(remapped[found], np.floor(u[found] + 0.5).astype(np.uint64))


def test_source_points_are_the_librarys_projection():
    """Each target pixel's point is project(unproject_no_checks(pixel)) cast to float32."""
    src = camera(*FISHEYE, FISHEYE_SHAPE[1], FISHEYE_SHAPE[0], 40.0)
    dst = camera(*WIDE_PINHOLE, 50, 37)
    points = source_points(src, dst)
    for row in range(37):
        for col in range(50):
            projected = src.project(dst.unproject_no_checks(np.array([col, row], np.float64)))
            inside = projected is not None and (0 <= projected).all() and (projected <= [82, 60]).all()
            if inside:
                np.testing.assert_array_equal(points[row, col], np.asarray(projected, np.float32).ravel())
            else:
                assert np.isnan(points[row, col]).all()


def test_remap_refuses_other_images():
    points = np.zeros((4, 4, 2), np.float32)
    remap = Remap(points, (8, 8))
    with pytest.raises(ValueError, match="remap expects"):
        remap.rgb(np.zeros((8, 9, 3), np.uint8))
    with pytest.raises(ValueError, match="remap expects"):
        remap.depth(np.zeros((8, 8), np.float64))
