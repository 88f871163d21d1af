"""The real ADT excerpt (``pipeline.adt.sample.excerpt.excerpt_path``: ``$ADT_EXCERPT``, else ../shared/data
beside the repository), read in place, and the settings its two frames need (the same as the ADT
bench's); tests that use it skip when it is absent."""

import pathlib

import pytest

from pipeline.adt.sample.excerpt import EXCERPT_SETTINGS, SHARED_EXCERPT, excerpt_path

SAMPLE = pathlib.Path(excerpt_path() or SHARED_EXCERPT)
SETTINGS = [part for setting in EXCERPT_SETTINGS for part in ("--set", setting)]
# One chunk per frame of the excerpt's ground-truth window: two clips.
ONE_FRAME_CHUNKS = (
    "--set",
    "adt.chunk_frames=1",
    "--set",
    "adt.min_frames=1",
    "--set",
    "adt.max_gt_offset_ms=40",
)
needs_excerpt = pytest.mark.skipif(
    excerpt_path() is None,
    reason=f"the real ADT excerpt is not at {SAMPLE} (../shared/data beside the repo, or $ADT_EXCERPT)",
)
