"""ADT frames, queries and depth against the release's generator on the real excerpt: our
re-rendering (``Remap`` gathers) gives the library's pixels exactly.

Truth is built here with projectaria-tools and PIL, following tapnet's ``adt_utils.py``: the
device calibration's camera-rgb, a LINEAR camera [280, 280, W/2, H/2] with an identity device
pose, ``distort_by_calibration``, then ``Image.fromarray(im).rotate(-90)``. projectaria-tools
puts pixel centres at integers; the conversion to TAP-Vid's +0.5 is written out in each test.
"""

import numpy as np
import pytest
from PIL import Image

from pipeline.adt.reader import SequenceReader
from pipeline.adt.rectify import Rectifier
from pipeline.adt.sample.excerpt import EXCERPT_SETTINGS
from pipeline.adt.settings import AdtConfig
from pipeline.adt.units import SequenceChunk
from pipeline.core.errors import InputError
from pipeline.settings.fields import with_overrides, with_rules
from pipeline.settings.run_config import RunConfig
from tests.support.adt_excerpt import SAMPLE, needs_excerpt
from tests.support.units import adt_clips

W = H = 512
F = 280

pytestmark = needs_excerpt


class Generator:
    """The generator's provider, cameras and frame timestamps (``ADTVideoProcessor``)."""

    def __init__(self):
        from projectaria_tools.core import calibration
        from projectaria_tools.core.stream_id import StreamId
        from projectaria_tools.projects import adt

        paths = adt.AriaDigitalTwinDataPathsProvider(str(SAMPLE)).get_datapaths_by_device_num(0, False)
        self.provider = adt.AriaDigitalTwinDataProvider(paths)
        self.stream = StreamId("214-1")
        raw = self.provider.raw_data_provider_ptr()
        label = raw.get_label_from_stream_id(self.stream)
        self.src = raw.get_device_calibration().get_camera_calib(label)
        identity = calibration.get_linear_camera_calibration(1, 1, 1).get_transform_device_camera()
        self.dst = calibration.CameraCalibration(
            "camera-rgb",
            calibration.CameraModelType.LINEAR,
            np.array([F, F, W / 2, H / 2]),
            identity,
            W,
            H,
            None,
            np.pi,
            "LinearCameraCalibration",
        )
        self.calibration = calibration
        stamps = np.array(self.provider.get_aria_device_capture_timestamps_ns(self.stream))
        stamps = stamps[stamps > self.provider.get_start_time_ns()]
        self.stamps = stamps[stamps < self.provider.get_end_time_ns()]

    def frame(self, stamp):
        """The generator's frame before JPEG [H, W, 3] uint8."""
        image = self.provider.get_aria_image_by_timestamp_ns(int(stamp), self.stream).data().to_numpy_array()
        image = self.calibration.distort_by_calibration(image, self.dst, self.src)
        return np.array(Image.fromarray(image).rotate(-90))


@pytest.fixture(scope="module")
def generator():
    return Generator()


@pytest.fixture(scope="module")
def ours():
    reader = SequenceReader(str(SAMPLE), True, 40_000_000)
    return reader, Rectifier(reader.calibration, W, F)


def test_frames_are_the_generators_before_jpeg(generator, ours):
    reader, rectifier = ours
    stamps = reader.frame_timestamps()
    np.testing.assert_array_equal(stamps, generator.stamps)
    expected = [generator.frame(stamp) for stamp in stamps]
    got = [rectifier.rgb(reader.rgb(stamp)) for stamp in stamps]
    assert len(got) == 2
    assert all(frame.std() > 10 for frame in expected)  # real pictures
    for mine, theirs in zip(got, expected, strict=True):
        np.testing.assert_array_equal(mine, theirs)
    # The generator's check against the release's video_means.
    video_means = np.stack([np.mean(x, axis=(0, 1)) for x in expected])
    np.testing.assert_allclose(np.stack([np.mean(x, axis=(0, 1)) for x in got]), video_means, atol=1e-3)


def test_depth_and_ids_are_the_librarys(generator, ours):
    """The re-rendered depth (float32 mm) and ids are projectaria-tools' own, turned as the
    frames: depth to the bit (the library interpolates in float32 and adds its last term in
    double), ids by the same nearest neighbour (int(p + 0.5))."""
    reader, rectifier = ours
    lib, dst, src = generator.calibration, generator.dst, generator.src
    for stamp in generator.stamps:
        raw_depth, raw_ids = reader.depth_mm(stamp), reader.ids(stamp)
        depth = np.rot90(lib.distort_depth_by_calibration(raw_depth.astype(np.float32), dst, src), -1)
        got = rectifier.depth_mm(raw_depth)
        assert got.dtype == np.float32
        assert (got > 0).mean() > 0.5
        np.testing.assert_array_equal(got, depth)
        ids = np.rot90(lib.distort_label_by_calibration(raw_ids, dst, src), -1)
        assert len(np.unique(ids)) > 10
        np.testing.assert_array_equal(rectifier.ids(raw_ids), ids)


def generator_pixels(points_stored, generator):
    """Stored-camera points [N, 3] -> where they appear in the generator's frames [N, 2], pixel
    centres at +0.5: projectaria-tools' projection (integer centres) before the rotation, then
    the clockwise turn of PIL's rotate(-90), (x, y) -> (W - y, x)."""
    out = []
    for x, y, z in points_stored:
        u, v = generator.dst.project(np.array([y, -x, z]))  # unrotated camera: X = Y', Y = -X'
        out.append((W - (v + 0.5), u + 0.5))
    return np.array(out)


def test_queries_are_where_their_points_appear_in_the_frames(generator):
    config = with_overrides(RunConfig(), [*EXCERPT_SETTINGS, "adt.tracks_per_clip=256"])
    (clip,) = adt_clips(str(SAMPLE), SequenceChunk(str(SAMPLE), 0), config)
    t_q = clip.queries_xyt[:, 2].astype(int)
    at_query = clip.tracks_xyz[t_q, np.arange(clip.num_tracks)]
    assert set(t_q.tolist()) == {0, 1}
    np.testing.assert_allclose(
        generator_pixels(at_query, generator), clip.queries_xyt[:, :2], atol=1e-6, rtol=0
    )
    # The written intrinsics are that camera: (256.5, 256.5) before the turn, (255.5, 256.5) after.
    np.testing.assert_array_equal(clip.fx_fy_cx_cy, [280.0, 280.0, 255.5, 256.5])
    # Each query's depth is the float-millimetre depth the generator's camera sees at its pixel.
    for t in (0, 1):
        stamp = int(generator.stamps[t])
        raw = (
            generator.provider.get_depth_image_by_timestamp_ns(stamp, generator.stream)
            .data()
            .to_numpy_array()
        )
        depth = generator.calibration.distort_depth_by_calibration(
            raw.astype(np.float32), generator.dst, generator.src
        )
        depth = np.rot90(depth, -1).astype(np.float64) / 1000.0
        mine = t_q == t
        rows, cols = (
            np.floor(clip.queries_xyt[mine, 1]).astype(int),
            np.floor(clip.queries_xyt[mine, 0]).astype(int),
        )
        np.testing.assert_allclose(at_query[mine, 2], depth[rows, cols], atol=1e-9, rtol=0)


def test_depth_is_bilinear_in_float_millimetres(generator, ours):
    reader, rectifier = ours
    stamp = int(generator.stamps[0])
    raw = reader.depth_mm(stamp)
    got = rectifier.depth_mm(raw).astype(np.float64)
    surface = got > 0
    fractional = np.abs(got[surface] - np.round(got[surface])) > 1e-3
    assert fractional.mean() > 0.9, fractional.mean()
    # Truth: the generator camera's ray through each stored pixel, projected into the fisheye,
    # bilinear between its four pixels (integer centres) where they are one smooth surface.
    raw = raw.astype(np.float64)
    errors = []
    for row in range(3, H, 23):
        for col in range(5, W, 23):
            r, c = W - 1 - col, row  # the stored pixel [row, col] was the unrotated pixel [r, c]
            uv = generator.src.project(np.array([(c - W / 2) / F, (r - H / 2) / F, 1.0]))
            u0, v0 = int(np.floor(uv[0])), int(np.floor(uv[1]))
            corners = raw[v0 : v0 + 2, u0 : u0 + 2]
            if corners.min() <= 0 or np.ptp(corners) > 10:
                continue
            fu, fv = uv[0] - u0, uv[1] - v0
            weights = np.array([[(1 - fu) * (1 - fv), fu * (1 - fv)], [(1 - fu) * fv, fu * fv]])
            errors.append(abs((weights * corners).sum() - got[row, col]))
    errors = np.array(errors)
    assert len(errors) > 200
    assert errors.max() < 0.01, errors.max()  # millimetres; cut to whole ones it would be 0.5 on average


def test_a_far_ground_truth_sample_fails_by_our_rule_and_passes_by_the_releases():
    """The excerpt's depth stops one frame early: its second frame's nearest depth image is 33.2 ms
    away. ``adt.max_gt_offset_ms`` 5 (refined) refuses it; 0 (release: the closest sample however
    far, as the release's generator) reads it."""
    refined = SequenceReader(str(SAMPLE), True, int(AdtConfig().max_gt_offset_ms * 1e6))
    release_limit = with_rules(AdtConfig(), "release").max_gt_offset_ms
    release = SequenceReader(str(SAMPLE), True, int(release_limit * 1e6))
    try:
        last = int(refined.frame_timestamps()[-1])
        with pytest.raises(InputError, match="33.2 ms away"):
            refined.depth_mm(last)
        assert release.depth_mm(last).shape == refined.depth_mm(int(refined.frame_timestamps()[0])).shape
    finally:
        refined.close()
        release.close()
