"""ADT speed figures on the real excerpt: per-frame cost of reading and re-rendering RGB, depth
and ids (projectaria-tools' VRS decode, then ``distort_*_by_calibration`` and the rotation), of
the poses and the JPEG encoding; then the annotation cost of one clip, per frame and
extrapolated to a 300-frame chunk.

The excerpt is ``pipeline.adt.source.excerpt_path()``: ``$ADT_EXCERPT``, else
``../shared/data/adt_sample/aria_digital_twin_test_data`` beside the repository.
"""

from __future__ import annotations

import os
import time

from pipeline.adt.source import EXCERPT_SETTINGS, SHARED_EXCERPT, excerpt_path
from pipeline.core.config import RunConfig, with_overrides


def _timed(function, *args):
    start = time.perf_counter()
    result = function(*args)
    return time.perf_counter() - start, result


def run(frames: int) -> None:
    """Print per-frame reading/re-rendering costs over ``frames`` frame reads, then the clip cost."""
    from pipeline.adt.annotate import Chunk, annotate_chunk
    from pipeline.adt.source import SequenceFrames, clip_name, encode_jpeg, open_reader, unit_name

    path = excerpt_path()
    if path is None:
        where = os.environ.get("ADT_EXCERPT") or SHARED_EXCERPT
        print(f"adt bench: no ADT excerpt at {where}; set ADT_EXCERPT to a sequence folder")
        return
    config = with_overrides(RunConfig(), EXCERPT_SETTINGS)
    open_time, reader = _timed(open_reader, path, config)
    stamps = reader.frame_timestamps()
    sequence = SequenceFrames(reader, config)
    rect = sequence.rectifier
    steps = {
        name: 0.0
        for name in (
            "RGB read",
            "RGB re-render",
            "RGB JPEG",
            "depth read",
            "depth re-render",
            "ids read",
            "ids re-render",
            "poses",
        )
    }
    frames = max(1, frames)
    for index in range(frames):
        timestamp = int(stamps[index % len(stamps)])
        seconds, rgb = _timed(reader.rgb, timestamp)
        steps["RGB read"] += seconds
        seconds, rgb = _timed(rect.rgb, rgb)
        steps["RGB re-render"] += seconds
        steps["RGB JPEG"] += _timed(encode_jpeg, rgb)[0]
        seconds, depth = _timed(reader.depth_mm, timestamp)
        steps["depth read"] += seconds
        steps["depth re-render"] += _timed(rect.depth_m, depth)[0]
        seconds, ids = _timed(reader.ids, timestamp)
        steps["ids read"] += seconds
        steps["ids re-render"] += _timed(rect.ids, ids)[0]
        start = time.perf_counter()
        reader.world_from_camera(timestamp)
        reader.object_poses(timestamp)
        steps["poses"] += time.perf_counter() - start
    size = config.adt.image_size
    print(f"ADT excerpt {path}")
    print(f"opening the sequence (projectaria-tools provider): {1000 * open_time:.0f} ms")
    print(f"per frame, mean over {frames} read(s), 1408x1408 fisheye -> {size}x{size} pinhole, rotated:")
    for name, seconds in steps.items():
        print(f"  {name:<16} {1000 * seconds / frames:8.2f} ms")
    total = sum(steps.values()) / frames
    print(f"  {'total':<16} {1000 * total:8.2f} ms")

    chunk = Chunk(clip_name(path, 0), unit_name((path, 0)), stamps[: config.adt.chunk_frames])
    seconds, clip = _timed(annotate_chunk, chunk, sequence.frame, sequence.jpeg, sequence.instances, config)
    per_frame = seconds / clip.num_frames
    print(
        f"annotation of one clip ({clip.num_frames} frames, {clip.num_tracks} candidate tracks; pass 1 reads "
        f"RGB, depth, ids and poses, pass 2 depth, ids and poses again): {seconds:.2f} s = "
        f"{1000 * per_frame:.0f} ms/frame; a 300-frame chunk at that rate: {300 * per_frame:.0f} s"
    )
