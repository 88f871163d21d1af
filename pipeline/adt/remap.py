"""Sampling tables that reproduce projectaria-tools' ``distort_by_calibration`` family exactly,
applied as gathers (numba loops for the bilinear kinds, NumPy for nearest): the same pixels,
on the excerpt about 6 (RGB) to 15 (depth, ids) times faster than the library's calls
(``micro`` in ``pipeline/adt/bench.py``).

What the library does (core/calibration/utility/Distort.cpp, core/image/utility/Distort.cpp,
core/image/Image.h), with its pixel centres at integers: target pixel (x, y) samples the source
image at p = source.project(target.unproject_no_checks((x, y))) cast to float32; the pixel is 0
where ``project`` fails or p is outside [0, W - 1] x [0, H - 1].

- Bilinear: ix = int(u), dx = u - ix (float32; likewise y), weights dx*dy, dy - dx*dy,
  dx - dx*dy, 1 - dx - dy + dx*dy on the pixels (ix+1, iy+1), (ix, iy+1), (ix+1, iy), (ix, iy),
  summed in that order. Multi-channel pixels (RGB) compute all in float32 and truncate to the
  pixel type; single-channel ones (depth) add the last term in double and convert the sum back
  to the pixel type (float32: rounded). No pixel is treated apart: a 0 depth blends like any.
- Nearest (labels): the pixel int(p + 0.5), p + 0.5 in float32.
"""

from __future__ import annotations

import numba
import numpy as np


def source_points(source, target) -> np.ndarray:
    """Where each target pixel samples the source image: [H_t, W_t, 2] float32 (u, v), pixel
    centres at integers (projectaria-tools'), NaN where the library leaves the pixel 0.

    Args:
      source: the image's ``CameraCalibration``; its ``project`` (every model's checks included)
        is called once per target pixel.
      target: a LINEAR ``CameraCalibration``; its rays are unproject_no_checks' (x - cx) / fx,
        (y - cy) / fy, 1 in double (``tests/adt/test_remap.py`` checks they are the library's).
    """
    from projectaria_tools.core.calibration import CameraModelType

    if target.get_model_name() != CameraModelType.LINEAR:
        raise ValueError(f"source_points needs a LINEAR target camera, got {target.get_model_name()}")
    width, height = (int(n) for n in target.get_image_size())
    rows, cols = np.mgrid[0:height, 0:width]
    pixels = np.stack([cols.ravel(), rows.ravel()], axis=1).astype(np.float64)
    rays = np.ones((len(pixels), 3))
    rays[:, :2] = (pixels - target.get_principal_point()) / target.get_focal_lengths()
    projected = list(map(source.project, rays))
    found = np.array([p is not None for p in projected], bool)
    points = np.full((len(pixels), 2), np.nan, np.float32)
    if found.any():
        points[found] = np.array([p for p in projected if p is not None], np.float32).reshape(-1, 2)
    source_width, source_height = (int(n) for n in source.get_image_size())
    u, v = points[:, 0], points[:, 1]
    with np.errstate(invalid="ignore"):
        inside = (u >= 0) & (v >= 0) & (u <= source_width - 1) & (v <= source_height - 1)
    points[~inside] = np.nan
    return points.reshape(height, width, 2)


@numba.njit(cache=True, nogil=True)
def _bilinear_rgb(flat, taps, weights, out):
    """out [N, 3] uint8 from the flattened [H, W, 3] image: per channel, the float32 sum of the
    four taps [N, 4] x weights [N, 4] in their order, truncated (as the library's cast). A tap's
    three channels are read together, each tap and weight once (a loop over the channels would
    re-read them after every store: LLVM cannot prove the output does not alias them)."""
    for i in range(taps.shape[0]):
        a, b, c, d = 3 * taps[i, 0], 3 * taps[i, 1], 3 * taps[i, 2], 3 * taps[i, 3]
        w0, w1, w2, w3 = weights[i, 0], weights[i, 1], weights[i, 2], weights[i, 3]
        red = np.float32(flat[a]) * w0
        green = np.float32(flat[a + 1]) * w0
        blue = np.float32(flat[a + 2]) * w0
        red += np.float32(flat[b]) * w1
        green += np.float32(flat[b + 1]) * w1
        blue += np.float32(flat[b + 2]) * w1
        red += np.float32(flat[c]) * w2
        green += np.float32(flat[c + 1]) * w2
        blue += np.float32(flat[c + 2]) * w2
        red += np.float32(flat[d]) * w3
        green += np.float32(flat[d + 1]) * w3
        blue += np.float32(flat[d + 2]) * w3
        # toward zero; a float32 -0.00001 is 0 as in the library
        out[i, 0], out[i, 1], out[i, 2] = int(red), int(green), int(blue)


@numba.njit(cache=True, nogil=True)
def _bilinear_depth(flat, taps, weights, last_weight, out):
    """out [N] float32 from the flattened [H, W] image: three taps summed in float32, the last
    one added in double with its double weight [N], rounded to float32 (the library's order)."""
    for i in range(taps.shape[0]):
        total = np.float32(flat[taps[i, 0]]) * weights[i, 0]
        total += np.float32(flat[taps[i, 1]]) * weights[i, 1]
        total += np.float32(flat[taps[i, 2]]) * weights[i, 2]
        out[i] = np.float32(np.float64(total) + np.float64(flat[taps[i, 3]]) * last_weight[i])


@numba.njit(cache=True, nogil=True)
def _gather(flat, index, out):
    """out[i] = flat[index[i]] ([N]; faster than NumPy's fancy indexing on an id frame)."""
    for i in range(index.shape[0]):
        out[i] = flat[index[i]]


class Remap:
    """Gathers from a source image [H, W, ...] at fixed points (``source_points``, any layout).

    Args:
      points: [h, w, 2] float32 (u, v) source coordinates, NaN = no sample (the output is 0).
      source_shape: (H, W) of the images it is applied to.
    """

    def __init__(self, points: np.ndarray, source_shape: tuple[int, int]):
        self.shape = points.shape[:2]
        self.source_shape = (int(source_shape[0]), int(source_shape[1]))
        height, width = self.source_shape
        u, v = points[..., 0].ravel(), points[..., 1].ravel()
        valid = np.isfinite(u) & np.isfinite(v)
        u, v = np.where(valid, u, 0).astype(np.float32), np.where(valid, v, 0).astype(np.float32)
        x0, y0 = u.astype(np.intp), v.astype(np.intp)  # int(u): u >= 0, so the floor
        dx, dy = u - x0.astype(np.float32), v - y0.astype(np.float32)
        dxdy = dx * dy
        # At u = W - 1 the library reads pixel W (past the row) with weight 0: any pixel will do.
        x1, y1 = np.minimum(x0 + 1, width - 1), np.minimum(y0 + 1, height - 1)
        # [N, 4] flat pixel indices and float32 weights, in the library's order of summation;
        # no sample: weights 0, so the sum is 0. The indices as int32: half the bytes to stream.
        if 3 * height * width > np.iinfo(np.int32).max:
            raise ValueError(f"remap: a {width}x{height} source image is too large for int32 taps")
        self.taps = np.stack(
            [y1 * width + x1, y1 * width + x0, y0 * width + x1, y0 * width + x0], axis=1
        ).astype(np.int32)
        self.weights = np.stack([dxdy, dy - dxdy, dx - dxdy, np.float32(1) - dx - dy + dxdy], axis=1)
        self.weights[~valid] = 0
        # Single-channel images: the last weight in double, from the same float32 dx, dy.
        self.last_weight = np.where(valid, (1.0 - dx.astype(np.float64)) - dy + dxdy.astype(np.float64), 0.0)
        half = np.float32(0.5)
        self.nearest = (v + half).astype(np.intp) * width + (u + half).astype(np.intp)
        self.invalid = np.flatnonzero(~valid)

    def _flat(self, image: np.ndarray, channels: tuple[int, ...], dtypes: tuple) -> np.ndarray:
        if image.shape != (*self.source_shape, *channels) or (dtypes and image.dtype not in dtypes):
            raise ValueError(
                f"remap expects an image {(*self.source_shape, *channels)} of {dtypes or 'any type'}, "
                f"got {image.shape} {image.dtype}"
            )
        return np.ascontiguousarray(image).reshape(-1)

    def rgb(self, image: np.ndarray) -> np.ndarray:
        """[H, W, 3] uint8 -> [h, w, 3] uint8, bilinear (the library's ``distort_by_calibration``)."""
        out = np.empty((len(self.taps), 3), np.uint8)
        _bilinear_rgb(self._flat(image, (3,), (np.uint8,)), self.taps, self.weights, out)
        return out.reshape(*self.shape, 3)

    def depth(self, depth: np.ndarray) -> np.ndarray:
        """[H, W] uint16 or float32 -> [h, w] float32, bilinear: the library's
        ``distort_depth_by_calibration`` of the float32 image."""
        out = np.empty(len(self.taps), np.float32)
        flat = self._flat(depth, (), (np.uint16, np.float32))
        _bilinear_depth(flat, self.taps, self.weights, self.last_weight, out)
        return out.reshape(self.shape)

    def labels(self, labels: np.ndarray) -> np.ndarray:
        """[H, W] any dtype -> [h, w], nearest (the library's ``distort_label_by_calibration``)."""
        flat = self._flat(labels, (), ())
        out = np.empty(len(self.nearest), flat.dtype)
        _gather(flat, self.nearest, out)
        out[self.invalid] = 0
        return out.reshape(self.shape)
