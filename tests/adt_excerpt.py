"""The real ADT excerpt beside the repository (../shared/data), read in place, and the settings
its two frames need (the same as the ADT bench's); tests that use it skip when it is absent."""

import pathlib

import pytest

from pipeline.adt.bench import EXCERPT_SETTINGS, excerpt_path

SAMPLE = pathlib.Path(excerpt_path())
SETTINGS = [part for setting in EXCERPT_SETTINGS for part in ("--set", setting)]
needs_excerpt = pytest.mark.skipif(
    not SAMPLE.is_dir(), reason=f"the real ADT excerpt is not at {SAMPLE} (../shared/data beside the repo)"
)
