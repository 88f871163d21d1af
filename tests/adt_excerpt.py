"""The real ADT excerpt beside the repository (../shared/data), read in place, and the settings
its two frames need; tests that use it skip when it is absent."""

import pathlib

import pytest

SAMPLE = (
    pathlib.Path(__file__).resolve().parents[2]
    / "shared"
    / "data"
    / "adt_sample"
    / "aria_digital_twin_test_data"
)
# Two frames make one chunk; the excerpt's second depth frame is 33 ms from its RGB frame.
SETTINGS = ["--set", "adt.chunk_frames=2", "--set", "adt.min_frames=2", "--set", "adt.max_gt_offset_ms=40"]
needs_excerpt = pytest.mark.skipif(
    not SAMPLE.is_dir(), reason=f"the real ADT excerpt is not at {SAMPLE} (../shared/data beside the repo)"
)
