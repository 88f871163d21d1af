"""ADT's stand-in for a sample world: the real ADT excerpt shared beside the repository (read in
place), and how to get ADT. There is no embedded ADT sample (ADT is real Aria recordings with a
digital twin; no synthetic stand-in is shipped)."""

from __future__ import annotations

import os

# The real ADT excerpt shared beside the repository (relative to its root; read in place) and the
# settings its two frames need. Tests, the Makefile's ADT_EXCERPT and the benchmarks use these.
SHARED_EXCERPT = "../shared/data/adt_sample/aria_digital_twin_test_data"
EXCERPT_SETTINGS = ("adt.chunk_frames=2", "adt.min_frames=2", "adt.max_gt_offset_ms=40")
# This file is pipeline/adt/sample/excerpt.py.
_REPOSITORY = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", "..", ".."))


def excerpt_path() -> str | None:
    """The ADT excerpt's folder: ``$ADT_EXCERPT`` when set, else ``SHARED_EXCERPT`` beside the
    repository; None when that folder does not exist."""
    path = os.environ.get("ADT_EXCERPT") or os.path.join(_REPOSITORY, SHARED_EXCERPT)
    path = os.path.normpath(os.path.abspath(path))
    return path if os.path.isdir(path) else None


def demo_args() -> list[str]:
    """A demo run's arguments: the excerpt read in place with the settings its two frames need;
    NoSample when it is not there."""
    from pipeline.sources import NoSample

    path = excerpt_path()
    if path is None:
        where = os.environ.get("ADT_EXCERPT") or SHARED_EXCERPT
        raise NoSample(f"no ADT excerpt at {where} (python -m pipeline.run --source adt says how to get ADT)")
    return ["--input", path, *(word for setting in EXCERPT_SETTINGS for word in ("--set", setting))]


def no_sample_message() -> str:
    settings = " ".join(f"--set {s}" for s in EXCERPT_SETTINGS)
    return (
        "adt: there is no embedded ADT sample (ADT is real Aria recordings with a digital twin; "
        "no synthetic stand-in is shipped). Pass --input with an ADT sequence folder, a folder of "
        "them, or the download-URLs JSON.\n"
        "To get ADT: accept the licence and download the URLs file (ADT_download_urls.json) from "
        "https://www.projectaria.com/datasets/adt/, then either let the run fetch each sequence into "
        "a scratch folder, one at a time, and delete it after:\n"
        "  python -m pipeline.run --source adt --input ADT_download_urls.json "
        "--release ../shared/data/tapvid3d_official_splits.json\n"
        "or download sequences first with projectaria-tools' aria_dataset_downloader "
        "(-c ADT_download_urls.json -o ADT/ -l <sequence names>) and pass --input ADT/.\n"
        "To try the shared 3-frame excerpt (2 frames in its ground-truth window, depth for only "
        "the first of them within 5 ms):\n"
        f"  python -m pipeline.run --source adt --input {SHARED_EXCERPT} {settings}"
    )
