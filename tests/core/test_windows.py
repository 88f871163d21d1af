"""A clip cut into windows of a set number of frames (``core.windows.cut``): consecutive frame ranges,
each named after the clip and its index, the shorter rest kept only when long enough, and a clip
no longer than the length kept whole under its own name."""

from __future__ import annotations

import pytest

from pipeline.core.windows import Window, cut


@pytest.mark.parametrize(("frames", "length"), [(40, 0), (40, 40), (40, 64), (1, 16)])
def test_a_clip_no_longer_than_the_length_is_one_clip_under_its_name(frames, length):
    assert cut("dome_3", frames, length, 24) == [Window("dome_3", 0, frames)]


def test_a_longer_clip_is_cut_into_consecutive_windows_named_by_their_index():
    assert cut("dome_3", 150, 64, 20) == [
        Window("dome_3_w0", 0, 64),
        Window("dome_3_w1", 64, 128),
        Window("dome_3_w2", 128, 150),
    ]


def test_the_shorter_rest_is_kept_only_with_min_frames_and_full_windows_always():
    assert [w.name for w in cut("car", 150, 64, 23)] == ["car_w0", "car_w1"]
    assert cut("car", 28, 16, 12) == [Window("car_w0", 0, 16), Window("car_w1", 16, 28)]
    assert cut("car", 40, 16, 24) == [Window("car_w0", 0, 16), Window("car_w1", 16, 32)]
