"""How a DriveTrack track's query frame is drawn among its visible frames: by the rank of a uniform
draw (``query_frames``, the release's rules) or by the lowest key of (track, frame)
(``lowest_key_frames``, ``drivetrack.stable_query_frames``). Both are uniform over the visible
frames; only the second stays put when the track's visibility changes at another frame."""

import numpy as np

from pipeline.drivetrack.queries import lowest_key_frames, query_draws, query_frames

FRAMES, TRACKS = 20, 20_000


def random_tracks(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Visibility [FRAMES, TRACKS] (each track visible on a random half of its frames, at least one)
    and uint64 track keys [TRACKS]."""
    rng = np.random.default_rng(seed)
    visibility = rng.random((FRAMES, TRACKS)) < 0.5
    visibility[0, ~visibility.any(axis=0)] = True
    keys = rng.integers(0, 2**63, TRACKS, dtype=np.int64).view(np.uint64) * np.uint64(2)
    return visibility, keys


def test_lowest_key_frames_are_visible_and_uniform_over_the_visible_frames():
    visibility, keys = random_tracks(0)
    frames = lowest_key_frames(visibility, keys)
    assert visibility[frames, np.arange(TRACKS)].all()
    # Tracks visible on every frame: each frame is chosen 1/FRAMES of the time (within 5 sigma).
    everywhere = np.ones((FRAMES, TRACKS), bool)
    counts = np.bincount(lowest_key_frames(everywhere, keys), minlength=FRAMES)
    expected = TRACKS / FRAMES
    assert np.abs(counts - expected).max() < 5 * np.sqrt(expected)
    # Among the tracks that see it, the first frame is chosen as often as the last (about 1 in 10).
    first, last = (np.mean(frames[visibility[t]] == t) for t in (0, FRAMES - 1))
    assert 0.08 < first < 0.13
    assert abs(first - last) < 0.015


def test_never_visible_tracks_get_no_query_frame():
    visibility, keys = random_tracks(1)
    visibility[:, :10] = False
    assert (lowest_key_frames(visibility, keys)[:10] == -1).all()
    assert (query_frames(visibility, query_draws(keys))[:10] == -1).all()


def test_a_change_at_another_frame_leaves_the_lowest_key_frame_in_place():
    visibility, keys = random_tracks(2)
    rng = np.random.default_rng(3)
    stable, ranked = lowest_key_frames(visibility, keys), query_frames(visibility, query_draws(keys))
    # Flip one frame per track, never the frame either rule chose.
    flipped = visibility.copy()
    columns = np.arange(TRACKS)
    rows = rng.integers(0, FRAMES, TRACKS)
    clear = (rows != stable) & (rows != ranked)
    flipped[rows[clear], columns[clear]] ^= True
    keep = clear & flipped.any(axis=0)
    # The lowest key among the visible frames changes only where the flip made a frame visible whose
    # key is lower: about a tenth of the tracks here (1 / (visible frames + 1) of the half that gain one).
    moved_stable = np.mean(lowest_key_frames(flipped, keys)[keep] != stable[keep])
    moved_ranked = np.mean(query_frames(flipped, query_draws(keys))[keep] != ranked[keep])
    assert moved_stable < 0.06
    assert moved_ranked > 0.3
    # A frame turned invisible never moves the lowest-key choice.
    lost = keep & ~flipped[rows, columns]
    assert (lowest_key_frames(flipped, keys)[lost] == stable[lost]).all()
