"""Masks decoded once per process (pipeline/pstudio/mask_cache.py): within a unit each (camera, frame)
mask is decoded at most once, the next unit of the sequence decodes none, and the cache returns
exactly what decoding returns, within its memory bound. A unit reads them bit-packed: it checks
each by its packed length and unpacks only its own camera's, at its query frames."""

from __future__ import annotations

import collections
import dataclasses

import cv2
import numpy as np
import pytest

from pipeline.core.errors import InputError
from pipeline.pstudio import mask_cache, reader, records
from pipeline.pstudio.settings import PstudioConfig
from pipeline.pstudio.tracks import candidate_clip, read_masks
from pipeline.pstudio.units import list_units
from pipeline.settings.run_config import RunConfig
from pipeline.sources import RunChoices
from tests.support.units import pstudio_input


@pytest.fixture
def decoded(monkeypatch):
    """A fresh cache for the readers, and a Counter of the files (``what``) it decodes."""
    counts = collections.Counter()
    decode = mask_cache.decode_image

    def counting(data, width, height, what, **kwargs):
        counts[what] += 1
        return decode(data, width, height, what, **kwargs)

    monkeypatch.setattr(mask_cache, "decode_image", counting)
    monkeypatch.setattr(reader, "MASKS", mask_cache.MaskCache())
    return counts


def png(mask: np.ndarray) -> bytes:
    return cv2.imencode(".png", mask.astype(np.uint8) * 255)[1].tobytes()


def test_each_mask_is_decoded_once_per_sequence(pstudio_sample, decoded):
    root, _ = pstudio_sample
    config = RunConfig()
    first, second = list_units(root, config).units[:2]
    unit = pstudio_input(root, first.sequence, first.camera, config)
    settings, choices = config.section(PstudioConfig), RunChoices.of(config, "pstudio")
    clip = candidate_clip(unit, settings, choices)
    assert clip.num_tracks > 0
    cameras, frames = len(unit.views.camera_ids), unit.gaussians.num_frames
    assert set(decoded.values()) == {1}
    assert 0 < len(decoded) <= cameras * frames
    decoded.clear()
    candidate_clip(pstudio_input(root, second.sequence, second.camera, config), settings, choices)
    assert not decoded


def test_a_hit_is_the_decoded_mask_and_a_fresh_array(decoded):
    rng = np.random.default_rng(0)
    mask = rng.random((36, 52)) < 0.3
    cache = mask_cache.MaskCache()
    for _ in range(3):
        got = mask_cache.unpack_mask(cache.packed(png(mask), 52, 36, "m.png"), 52, 36)
        np.testing.assert_array_equal(got, mask)
        got[:] = False  # the caller's to change
    assert decoded["m.png"] == 1


def test_the_cache_stays_within_its_bound(decoded):
    rng = np.random.default_rng(1)
    files = [png(rng.random((40, 64)) < 0.5) for _ in range(6)]
    one = len(files[0]) + 40 * 64 // 8
    cache = mask_cache.MaskCache(max_bytes=3 * one)
    for data in files:
        cache.packed(data, 64, 40, "m.png")
    assert cache.bytes <= 3 * one
    cache.packed(files[-1], 64, 40, "m.png")  # recent: kept
    assert decoded["m.png"] == 6
    cache.packed(files[0], 64, 40, "m.png")  # the oldest: evicted
    assert decoded["m.png"] == 7


def test_bad_files_are_refused_every_time(decoded):
    cache = mask_cache.MaskCache()
    good = png(np.ones((20, 30), bool))
    for _ in range(2):
        with pytest.raises(InputError, match="bad.png: corrupt mask"):
            cache.packed(good[:60], 30, 20, "bad.png")
        with pytest.raises(InputError, match="small.png: mask is 30x20, expected 60x40"):
            cache.packed(good, 60, 40, "small.png")


def test_a_unit_unpacks_only_its_cameras_masks_at_its_query_frames(pstudio_sample, monkeypatch):
    """Checked by their packed length and read packed by the mask statistic: the unit unpacks a
    mask only to draw its queries on it, once per query frame."""
    root, _ = pstudio_sample
    config = RunConfig()
    unit = pstudio_input(root, *dataclasses.astuple(list_units(root, config).units[0]), config)
    unpacked = []
    unpack = records.unpack_mask

    def counting(packed, width, height):
        unpacked.append(packed.ctypes.data)
        return unpack(packed, width, height)

    monkeypatch.setattr(records, "unpack_mask", counting)
    clip = candidate_clip(unit, config.section(PstudioConfig), RunChoices.of(config, "pstudio"))
    own = unit.views.index(unit.camera_id)
    assert clip.num_tracks > 0
    assert 0 < len(unpacked) == len(set(unpacked)) <= unit.gaussians.num_frames
    assert set(unpacked) <= {unit.packed_mask(own, t).ctypes.data for t in range(unit.gaussians.num_frames)}


@pytest.mark.parametrize("bad", [np.zeros(5, np.uint8), np.zeros(20 * 30, np.uint8), np.zeros(75, bool)])
def test_a_mask_of_another_packed_size_fails_the_unit_naming_it(pstudio_sample, bad):
    """The statistic's kernel reads a mask's bits by pixel index: a packed mask of another length or
    type is refused before any is read, with the unit, camera and frame named."""
    root, _ = pstudio_sample
    config = RunConfig()
    unit = pstudio_input(root, *dataclasses.astuple(list_units(root, config).units[0]), config)
    good = unit.packed_mask
    unit.packed_mask = lambda view, t: bad if (view, t) == (1, 6) else good(view, t)
    where = f"^dome_{unit.camera_id}: the mask of camera {unit.views.camera_ids[1]} at frame 6 is "
    with pytest.raises(InputError, match=where):
        read_masks(unit)
