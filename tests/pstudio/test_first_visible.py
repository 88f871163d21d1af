"""Only the candidates a clip can keep are tracked: a track's visibility does not depend on the
tracks computed with it, so tracking the candidates a batch at a time until enough are seen at
their own query frame gives the bits of tracking all of them and keeping the first seen there."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.pstudio import tracks as annotate
from pipeline.pstudio.records import Gaussians, UnitInput, Views
from pipeline.pstudio.settings import PstudioConfig
from pipeline.pstudio.tracks import track_first_visible, track_visibility
from tests.pstudio.test_culling import HEIGHT, INTRINSICS, WIDTH, crowded_scene

FRAMES = 4
DELTA = PstudioConfig().depth_delta_m


@pytest.fixture(scope="module")
def unit() -> UnitInput:
    """The crowded scene's 20,000 Gaussians drifting over 4 frames (float32, as stored), one camera."""
    means, quaternions, constants, w2c = crowded_scene()
    drift = np.random.default_rng(2).normal(0.0, 0.01, means.shape)
    return UnitInput(
        sequence="crowd",
        camera_id=0,
        views=Views(np.array([0]), INTRINSICS[None], w2c[None], WIDTH, HEIGHT),
        gaussians=Gaussians(
            means=np.stack([means + t * drift for t in range(FRAMES)]).astype(np.float32),
            quaternions=np.stack([quaternions] * FRAMES),
            scales=constants.scales,
            opacities=constants.opacity,
            foreground=np.ones(len(means), bool),
        ),
        constants=constants,
        frames_jpeg=[],
        packed_mask=lambda view, t: np.packbits(np.zeros((HEIGHT, WIDTH), bool)),
    )


@pytest.fixture(scope="module")
def seen(unit) -> np.ndarray:
    """The Gaussians [S] visible in some frame (most of the crowd is hidden)."""
    everyone = np.arange(unit.gaussians.means.shape[1])
    return np.nonzero(track_visibility(unit, everyone, DELTA)[1].any(axis=0))[0]


def candidates(seen: np.ndarray, count: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Query frames [count] and distinct Gaussians [count] drawn at random, half of them among
    the ``seen``."""
    rng = np.random.default_rng(seed)
    hidden = np.setdiff1d(np.arange(20_000), seen)
    gaussians = np.concatenate(
        [rng.choice(seen, count // 2, replace=False), rng.choice(hidden, count - count // 2, replace=False)]
    )
    return rng.integers(0, FRAMES, count), rng.permutation(gaussians)


def test_a_tracks_visibility_does_not_depend_on_the_others(unit, seen):
    _, gaussians = candidates(seen, 600, seed=3)
    tracks, visible, _ = track_visibility(unit, gaussians, DELTA)
    assert 0.2 < visible.mean() < 0.8  # occluded and visible tracks alike
    for part in (gaussians[:1], gaussians[:137], gaussians[450:], gaussians[::-7]):
        part_tracks, part_visible, _ = track_visibility(unit, part, DELTA)
        columns = [np.nonzero(gaussians == g)[0][0] for g in part]
        np.testing.assert_array_equal(part_tracks, tracks[:, columns])
        np.testing.assert_array_equal(part_visible, visible[:, columns])


@pytest.mark.parametrize("wanted", [1, 40, 150, 599])
def test_batches_keep_the_first_candidates_seen_at_their_query_frame(unit, seen, wanted, monkeypatch):
    query_frames, gaussians = candidates(seen, 600, seed=4)
    tracks, visible, _ = track_visibility(unit, gaussians, DELTA)
    expected = np.nonzero(visible[query_frames, np.arange(len(gaussians))])[0][:wanted]
    assert len(expected) < 599  # the last case asks for more than there are
    batches = []
    monkeypatch.setattr(
        annotate,
        "track_visibility",
        lambda unit, g, delta, export: batches.append(len(g)) or track_visibility(unit, g, delta, export),
    )
    kept, kept_tracks, kept_visible, _ = track_first_visible(unit, query_frames, gaussians, wanted, DELTA)
    np.testing.assert_array_equal(kept, expected)
    np.testing.assert_array_equal(kept_tracks, tracks[:, expected])
    np.testing.assert_array_equal(kept_visible, visible[:, expected])
    assert sum(batches) <= len(gaussians)
    if wanted == 150:  # about half are seen at their query frame: the first batch falls short
        assert len(batches) > 1
        assert sum(batches) < len(gaussians)


def test_the_depth_maps_come_once_and_with_no_candidates(unit, seen):
    query_frames, gaussians = candidates(seen, 300, seed=5)
    _, _, all_maps = track_visibility(unit, gaussians, DELTA, export_depth=True)
    _, _, _, maps = track_first_visible(unit, query_frames, gaussians, 100, DELTA, export_depth=True)
    assert len(maps) == FRAMES
    for map_all, map_batched in zip(all_maps, maps, strict=True):
        np.testing.assert_array_equal(map_batched, map_all)
    kept, tracks, visible, maps = track_first_visible(
        unit, query_frames[:0], gaussians[:0], 100, DELTA, export_depth=True
    )
    assert kept.shape == (0,)
    assert tracks.shape == (FRAMES, 0, 3)
    assert visible.shape == (FRAMES, 0)
    for map_none, map_all in zip(maps, all_maps, strict=True):
        np.testing.assert_array_equal(map_none, map_all)
