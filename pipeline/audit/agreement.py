"""How close a regenerated clip is to the published one, track by track (the same queries, so track i
of one is track i of the other): the agreement ``audit compare`` adds to tapnet's metrics and writes
into a release run's verdicts."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from pipeline.clips import Clip

# A clip agrees fully when its query frames and visibility are the published ones and its tracks lie
# within this of them (p95, millimetres): ``audit compare --agree-mm`` changes it.
AGREE_MM = 1.0


@dataclasses.dataclass(frozen=True)
class Agreement:
    """query_frames_equal: share of tracks [N] whose query frame is the published one (NaN when the
    regenerated clip holds no queries); visibility: share of (frame, track) pairs [T, N] with the
    published visibility; median_mm, p95_mm: distance between the two clips' points over every
    (frame, track) pair where both are finite, in millimetres (NaN when there is none)."""

    query_frames_equal: float
    visibility: float
    median_mm: float
    p95_mm: float

    def agrees(self, tolerance_mm: float = AGREE_MM) -> bool:
        """Every query frame and visibility the published one, the tracks within ``tolerance_mm``."""
        return self.query_frames_equal == 1.0 and self.visibility == 1.0 and self.p95_mm <= tolerance_mm


def agreement(ref: Clip, new: Clip) -> Agreement:
    """The agreement of clip ``new`` with the published ``ref``: both tracks [T, N, 3] and visibility
    [T, N] of one shape; the queries [N, 3] of both, where both hold them, for the query frames."""
    ref_tracks, new_tracks = (np.asarray(clip.tracks, np.float64) for clip in (ref, new))
    visible = ref.visibility == new.visibility
    same_frames = math.nan
    if new.queries is not None and ref.queries is not None and new.queries.shape == ref.queries.shape:
        same_frames = float(np.mean(new.queries[:, 2] == ref.queries[:, 2]))
    distance = np.linalg.norm(new_tracks - ref_tracks, axis=-1)
    finite = distance[np.isfinite(distance)] * 1000.0
    median, p95 = (float(np.percentile(finite, q)) if finite.size else math.nan for q in (50, 95))
    return Agreement(same_frames, float(np.mean(visible)), median, p95)
