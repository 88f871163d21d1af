"""DriveTrack holds under millimetres: the sample world moved 15 km from the world's origin (and
turned), its world-frame transforms stored as float32, and the sample world with every pose moved by
1 mm in its own direction (``tests/support/reanchor.py``), give the same clips and tracks. A float32
pose 15 km out is rounded by up to ~1 mm, so camera-frame tracks agree within 3 mm, queries within a
fraction of a pixel, and visibility but for decisions within a millimetre of a threshold; a query
frame moves only with its own track's visibility (``drivetrack.stable_query_frames``).

Default settings: candidates are drawn by per-point keys (``point_keys`` in
``pipeline/drivetrack/queries.py``) and the filter stage keeps the survivors with the lowest keys
(``pipeline/filters/select.py``), so a filter verdict within rounding of its threshold changes that
track only, never the rest of the clip: where a clip has more survivors than it writes, such a track
leaving or joining the survivors swaps it with the one of the next key (two tracks unmatched).
"""

import dataclasses
import os

import numpy as np
import pytest

from tests.support.cli import run_in_process
from tests.support.reanchor import anchor, nudge_split, reanchor_split

MOVED = anchor(0.7, (12000.0, -9000.0, 35.0))  # new world from old: 15.04 km away, turned 40 degrees


def read_clips(out: str) -> dict[str, dict[str, np.ndarray]]:
    folder = os.path.join(out, "drivetrack")
    return {f: dict(np.load(os.path.join(folder, f), allow_pickle=False)) for f in sorted(os.listdir(folder))}


@pytest.fixture(scope="module")
def clips(sample_split, reference_run, tmp_path_factory):
    """{'base' | 'moved' | 'nudged': {clip file: arrays}}: the session's sample run, one on the
    re-anchored split and one on the split with every pose moved by 1 mm."""
    root = tmp_path_factory.mktemp("reanchor")
    found = {"base": read_clips(reference_run("drivetrack"))}
    for kind, write in (
        ("moved", lambda target: reanchor_split(sample_split[0], target, MOVED)),
        ("nudged", lambda target: nudge_split(sample_split[0], target, 1e-3, seed=0)),
    ):
        split, out = str(root / f"{kind}_split"), str(root / kind)
        write(split)
        result = run_in_process("drivetrack", "--input", split, "--output", out)
        assert result.returncode == 0, result.stderr[-3000:]
        found[kind] = read_clips(out)
    return found


def matched_tracks(a: dict, b: dict) -> tuple[np.ndarray, np.ndarray]:
    """Indices (into a, into b) of the tracks of two clips whose trajectories agree within 3 mm."""
    ta, tb = a["tracks_XYZ"].astype(np.float64), b["tracks_XYZ"].astype(np.float64)
    distance = np.linalg.norm(ta[:, :, None] - tb[:, None], axis=3).max(axis=0)
    nearest = distance.argmin(axis=1)
    close = distance[np.arange(len(nearest)), nearest] < 0.003
    return np.flatnonzero(close), nearest[close]


@dataclasses.dataclass
class Change:
    """How a clip's tracks changed: tracks, those with no match within 3 mm (either side), the worst
    matched distance (m), visibility values flipped of the matched pairs, query frames moved (all, and
    on tracks whose visibility did not change), tracks equal in every respect."""

    tracks: int = 0
    unmatched: int = 0
    worst_m: float = 0.0
    flips: int = 0
    pairs: int = 0
    query_frames_moved: int = 0
    moved_without_a_flip: int = 0
    equal: int = 0


def changes(base: dict, other: dict, moved: np.ndarray, max_shift_px: float) -> dict[str, Change]:
    """Per clip, how ``other``'s clips differ from ``base``'s (``moved``: new world from old); a query
    at the same frame moves by less than ``max_shift_px``."""
    found = {}
    for name in base:
        a, b, change = base[name], other[name], Change()
        ia, ib = matched_tracks(a, b)
        error = np.linalg.norm(a["tracks_XYZ"][:, ia].astype(np.float64) - b["tracks_XYZ"][:, ib], axis=2)
        change.worst_m = float(error.max())
        change.tracks = len(a["queries_xyt"])
        change.unmatched = len(a["queries_xyt"]) + len(b["queries_xyt"]) - 2 * len(ia)
        flipped = (a["visibility"][:, ia] != b["visibility"][:, ib]).any(axis=0)
        change.flips = int((a["visibility"][:, ia] != b["visibility"][:, ib]).sum())
        change.pairs = a["visibility"].size
        same_frame = a["queries_xyt"][ia, 2] == b["queries_xyt"][ib, 2]
        change.query_frames_moved = int((~same_frame).sum())
        change.moved_without_a_flip = int((~same_frame & ~flipped).sum())
        change.equal = int((same_frame & ~flipped).sum())
        shift = np.abs(a["queries_xyt"][ia, :2] - b["queries_xyt"][ib, :2])[same_frame]
        assert shift.max() < max_shift_px, f"{name}: a query moved {shift.max():.3f} px"
        assert b["extrinsics_w2c"].dtype == np.float64
        np.testing.assert_allclose(b["extrinsics_w2c"] @ moved, a["extrinsics_w2c"], atol=3e-3)
        found[name] = change
    return found


def say(what: str, found: dict[str, Change]) -> None:
    for name, c in found.items():
        print(
            f"{what} {name}: {c.unmatched} of {c.tracks} tracks unmatched, worst {c.worst_m * 1000:.2f} mm, "
            f"{c.flips} of {c.pairs} visibility values flipped ({c.flips / c.pairs:.3%}), "
            f"{c.query_frames_moved} query frames moved, {c.equal / c.tracks:.1%} of tracks equal"
        )


# A query at the same frame moves by less than this: a rounding of the poses (re-anchored), or two boxes
# moved by 1 mm each (the one that attaches a point, the one that places it) seen from 5 m.
@pytest.mark.parametrize("kind, max_shift_px", [("moved", 0.2), ("nudged", 0.5)])
def test_same_clips_tracks_queries_and_visibility(clips, kind, max_shift_px):
    base, other = clips["base"], clips[kind]
    assert list(base) == list(other)
    assert len(base) == 4
    found = changes(base, other, MOVED if kind == "moved" else np.eye(4), max_shift_px)
    say(kind, found)
    for name, change in found.items():
        assert change.worst_m < 0.003, name
        # Tracks whose mask agreement lies within a pixel's rounding of the filter's threshold leave or
        # join the survivors (the silhouette is a raster): up to 8 swaps in a clip of 256.
        assert change.unmatched <= 0.07 * change.tracks, name
        assert change.flips <= 1e-3 * change.pairs, name
        assert change.moved_without_a_flip == 0, name
        assert change.equal >= 0.94 * change.tracks, name
    # A query frame moves only where its own track's visibility changed at that frame.
    assert sum(c.query_frames_moved for c in found.values()) <= 1
