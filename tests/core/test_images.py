"""Checked JPEG decoding: the 4-channel decode the DriveTrack undistortion reads gives OpenCV's
pixels, and refuses what OpenCV's checked decode refuses, with the frame named."""

import cv2
import numpy as np
import pytest

from pipeline.core.errors import InputError
from pipeline.core.images import check_jpeg, check_jpeg_decodes, decode_jpeg_bgrx

HEIGHT, WIDTH = 48, 80


@pytest.fixture(scope="module")
def jpeg():
    rng = np.random.default_rng(3)
    image = cv2.GaussianBlur(rng.integers(0, 256, (HEIGHT, WIDTH, 3), np.uint8), (0, 0), 1.0)
    return cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 90])[1].tobytes()


def test_bgrx_decode_has_opencvs_colour_pixels_and_an_opaque_fourth_channel(jpeg):
    out = np.zeros((HEIGHT, WIDTH, 4), np.uint8)
    decode_jpeg_bgrx(jpeg, out, "frame 7")
    expected = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
    np.testing.assert_array_equal(out[..., :3], expected)
    assert (out[..., 3] == 255).all()


def test_a_grey_jpeg_decodes_as_opencv_decodes_it_in_colour():
    grey = np.tile(np.arange(WIDTH, dtype=np.uint8) * 3, (HEIGHT, 1))
    data = cv2.imencode(".jpg", grey)[1].tobytes()
    out = np.zeros((HEIGHT, WIDTH, 4), np.uint8)
    decode_jpeg_bgrx(data, out, "frame 7")
    np.testing.assert_array_equal(out[..., :3], cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR))


def _broken(jpeg: bytes, case: str) -> bytes:
    if case == "cut in half":
        return jpeg[: len(jpeg) // 2]
    if case == "huffman tables zeroed":
        at = jpeg.index(b"\xff\xc4") + 4
        return jpeg[:at] + bytes(20) + jpeg[at + 20 :]
    if case == "scan header length zeroed":
        at = jpeg.index(b"\xff\xda") + 2
        return jpeg[:at] + b"\x00\x02" + jpeg[at + 2 :]
    return b""


@pytest.mark.parametrize(
    "case, cause",
    [
        ("cut in half", "missing start or end marker"),
        ("huffman tables zeroed", "cannot be decoded"),
        ("scan header length zeroed", "cannot be decoded"),
        ("empty", "missing or empty JPEG"),
    ],
)
def test_a_broken_jpeg_is_refused_as_the_checked_decode_refuses_it(jpeg, case, cause):
    data = _broken(jpeg, case)
    with pytest.raises(InputError, match=f"^frame 7: .*{cause}"):
        check_jpeg(data, WIDTH, HEIGHT, "frame 7", cv2.IMREAD_COLOR)
    with pytest.raises(InputError, match=f"^frame 7: .*{cause}"):
        decode_jpeg_bgrx(data, np.zeros((HEIGHT, WIDTH, 4), np.uint8), "frame 7")
    with pytest.raises(InputError, match=f"^frame 7: .*{cause}"):
        check_jpeg_decodes(data, WIDTH, HEIGHT, "frame 7")


@pytest.mark.parametrize("width, height", [(WIDTH, HEIGHT), (81, 47), (7, 9), (640, 360)])
def test_the_reduced_decode_passes_a_whole_jpeg_of_any_size(width, height):
    """``check_jpeg_decodes`` decodes at an eighth of the size, rounded up as libjpeg rounds it."""
    rng = np.random.default_rng(5)
    data = cv2.imencode(".jpg", rng.integers(0, 256, (height, width, 3), np.uint8))[1].tobytes()
    check_jpeg_decodes(data, width, height, "frame 7")
    with pytest.raises(InputError, match=f"frame 7: JPEG is {width}x{height}, calibration says"):
        check_jpeg_decodes(data, width + 1, height, "frame 7")


def test_a_jpeg_of_another_size_is_refused_before_decoding(jpeg):
    with pytest.raises(InputError, match=f"frame 7: JPEG is {WIDTH}x{HEIGHT}, calibration says"):
        decode_jpeg_bgrx(jpeg, np.zeros((HEIGHT + 1, WIDTH, 4), np.uint8), "frame 7")
