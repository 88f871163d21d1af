"""DriveTrack is invariant under re-anchoring: the sample world moved 15 km from the world's origin
(and turned), its world-frame transforms stored as float32 (``tests/support/reanchor.py``), gives the same
clips and tracks. A float32 pose 15 km out is rounded by up to ~1 mm, so camera-frame tracks agree
within 3 mm, queries within a fraction of a pixel, and visibility but for decisions within rounding
of a threshold.

Default settings: candidates are drawn by per-point keys (``point_keys`` in
``pipeline/drivetrack/queries.py``) and the filter stage keeps the survivors with the lowest keys
(``pipeline/filters/select.py``), so a filter verdict within rounding of its threshold changes that
track only, never the rest of the clip: where a clip has more survivors than it writes, such a track
leaving or joining the survivors swaps it with the one of the next key (two tracks unmatched).
"""

import os

import numpy as np
import pytest

from tests.support.cli import run_in_process
from tests.support.reanchor import anchor, reanchor_split

MOVED = anchor(0.7, (12000.0, -9000.0, 35.0))  # new world from old: 15.04 km away, turned 40 degrees


def read_clips(out: str) -> dict[str, dict[str, np.ndarray]]:
    folder = os.path.join(out, "drivetrack")
    return {f: dict(np.load(os.path.join(folder, f))) for f in sorted(os.listdir(folder))}


@pytest.fixture(scope="module")
def clips(sample_split, reference_run, tmp_path_factory):
    """{'base' | 'moved': {clip file: arrays}}: the session's sample run and one on the moved split."""
    root = tmp_path_factory.mktemp("reanchor")
    moved = str(root / "moved_split")
    reanchor_split(sample_split[0], moved, MOVED)
    out = str(root / "moved")
    result = run_in_process("drivetrack", "--input", moved, "--output", out)
    assert result.returncode == 0, result.stderr[-3000:]
    return {"base": read_clips(reference_run("drivetrack")), "moved": read_clips(out)}


def matched_tracks(a: dict, b: dict) -> tuple[np.ndarray, np.ndarray]:
    """Indices (into a, into b) of the tracks of two clips whose trajectories agree within 3 mm."""
    ta, tb = a["tracks_XYZ"].astype(np.float64), b["tracks_XYZ"].astype(np.float64)
    distance = np.linalg.norm(ta[:, :, None] - tb[:, None], axis=3).max(axis=0)
    nearest = distance.argmin(axis=1)
    close = distance[np.arange(len(nearest)), nearest] < 0.003
    return np.flatnonzero(close), nearest[close]


def test_same_clips_tracks_queries_and_visibility(clips):
    base, moved = clips["base"], clips["moved"]
    assert list(base) == list(moved)
    assert len(base) == 4
    tracks = unmatched = flips = pairs = other_query_frames = 0
    worst = 0.0
    for name in base:
        a, b = base[name], moved[name]
        ia, ib = matched_tracks(a, b)
        error = np.linalg.norm(a["tracks_XYZ"][:, ia].astype(np.float64) - b["tracks_XYZ"][:, ib], axis=2)
        worst = max(worst, float(error.max()))
        tracks += len(a["queries_xyt"])
        unmatched += len(a["queries_xyt"]) + len(b["queries_xyt"]) - 2 * len(ia)
        flipped = (a["visibility"][:, ia] != b["visibility"][:, ib]).any(axis=0)
        flips += int((a["visibility"][:, ia] != b["visibility"][:, ib]).sum())
        pairs += a["visibility"][:, ia].size
        same_frame = a["queries_xyt"][ia, 2] == b["queries_xyt"][ib, 2]
        other_query_frames += int((~same_frame & ~flipped).sum())
        shift = np.abs(a["queries_xyt"][ia, :2] - b["queries_xyt"][ib, :2])[same_frame]
        assert shift.max() < 0.2, f"{name}: a query moved {shift.max():.3f} px"
        assert b["extrinsics_w2c"].dtype == np.float64
        extrinsics = b["extrinsics_w2c"] @ MOVED
        np.testing.assert_allclose(extrinsics, a["extrinsics_w2c"], atol=3e-3)
    print(
        f"re-anchored 15 km: {unmatched} of {tracks} tracks unmatched, worst {worst * 1000:.2f} mm, "
        f"{flips} of {pairs} visibility "
        f"decisions flipped, {other_query_frames} query frames changed without a flip"
    )
    assert unmatched <= 0.02 * tracks
    assert flips <= 1e-3 * pairs
    assert other_query_frames == 0
