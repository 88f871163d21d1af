"""ADT speed figures on the real excerpt: per-frame cost of reading RGB, depth and ids
(projectaria-tools' VRS decode), of re-rendering them to the stored frames both ways --
projectaria-tools' ``distort_*_by_calibration`` (the reference) and ours (``Remap`` gathers,
the same pixels) -- of the poses and the JPEG encoding, with the largest difference between the
two renderings; then the cost of building the tables and the annotation cost of one clip, per
frame and extrapolated to a 300-frame chunk.

The excerpt is ``pipeline.adt.source.excerpt_path()``: ``$ADT_EXCERPT``, else
``../shared/data/adt_sample/aria_digital_twin_test_data`` beside the repository.
"""

from __future__ import annotations

import os
import time

import numpy as np

from pipeline.adt.source import EXCERPT_SETTINGS, SHARED_EXCERPT, excerpt_path
from pipeline.core.config import with_overrides
from pipeline.settings import RunConfig


def _timed(function, *args):
    start = time.perf_counter()
    result = function(*args)
    return time.perf_counter() - start, result


def _library_renderers(reader, config):
    """The reference: projectaria-tools' re-rendering then the clockwise turn, per image kind."""
    from projectaria_tools.core import calibration

    from pipeline.adt.rectify import target_calibration

    source = reader.calibration
    target = target_calibration(source, config.adt.image_size, config.adt.focal)
    return {
        "RGB": lambda image: np.rot90(calibration.distort_by_calibration(image, target, source), -1),
        "depth": lambda depth: np.rot90(
            calibration.distort_depth_by_calibration(depth.astype(np.float32), target, source), -1
        ),
        "ids": lambda ids: np.rot90(calibration.distort_label_by_calibration(ids, target, source), -1),
    }


def run(frames: int) -> None:
    """Print per-frame reading/re-rendering costs over ``frames`` frame reads, then the clip cost."""
    from pipeline.adt.frames import SequenceFrames, encode_jpeg, open_reader
    from pipeline.adt.records import Chunk
    from pipeline.adt.rectify import _stored_remap
    from pipeline.adt.tracks import annotate_chunk
    from pipeline.adt.units import clip_name, unit_name

    path = excerpt_path()
    if path is None:
        where = os.environ.get("ADT_EXCERPT") or SHARED_EXCERPT
        print(f"adt bench: no ADT excerpt at {where}; set ADT_EXCERPT to a sequence folder")
        return
    config = with_overrides(RunConfig(), EXCERPT_SETTINGS)
    open_time, reader = _timed(open_reader, path, config)
    stamps = reader.frame_timestamps()
    _stored_remap.cache_clear()
    build_time, sequence = _timed(SequenceFrames, reader, config)
    cached_time = _timed(SequenceFrames, reader, config)[0]
    rect, library = sequence.rectifier, _library_renderers(reader, config)
    ours = {"RGB": rect.rgb, "depth": rect.depth_mm, "ids": rect.ids}
    read = {"RGB": reader.rgb, "depth": reader.depth_mm, "ids": reader.ids}
    first = int(stamps[0])
    jit_time = sum(_timed(ours[kind], read[kind](first))[0] for kind in ("RGB", "depth"))
    steps: dict[str, float] = {}
    largest = {"RGB": 0.0, "depth": 0.0, "ids": 0}  # grey levels, mm, mismatched pixels
    frames = max(1, frames)
    for index in range(frames):
        timestamp = int(stamps[index % len(stamps)])
        for kind in ("RGB", "depth", "ids"):
            seconds, image = _timed(read[kind], timestamp)
            steps[f"{kind} read"] = steps.get(f"{kind} read", 0.0) + seconds
            seconds, reference = _timed(library[kind], image)
            steps[f"{kind} library"] = steps.get(f"{kind} library", 0.0) + seconds
            seconds, mine = _timed(ours[kind], image)
            steps[f"{kind} remap"] = steps.get(f"{kind} remap", 0.0) + seconds
            if kind == "ids":
                largest[kind] = max(largest[kind], int((mine != reference).sum()))
            else:
                largest[kind] = max(largest[kind], float(np.abs(mine.astype(float) - reference).max()))
            if kind == "RGB":
                steps["RGB JPEG"] = steps.get("RGB JPEG", 0.0) + _timed(encode_jpeg, mine)[0]
        start = time.perf_counter()
        reader.world_from_camera(timestamp)
        reader.object_poses(timestamp)
        steps["poses"] = steps.get("poses", 0.0) + time.perf_counter() - start
    size = config.adt.image_size
    print(f"ADT excerpt {path}")
    print(f"opening the sequence (projectaria-tools provider): {1000 * open_time:.0f} ms")
    print(
        f"re-rendering tables (projectaria-tools' project for {size * size} pixels, once per calibration "
        f"per process): {1000 * build_time:.0f} ms; cached: {1000 * cached_time:.2f} ms; first RGB and depth "
        f"calls (numba compiles or loads its cached loops, once per process): {1000 * jit_time:.0f} ms"
    )
    print(f"per frame, mean over {frames} read(s), 1408x1408 fisheye -> {size}x{size} pinhole, rotated:")
    for name, seconds in steps.items():
        print(f"  {name:<16} {1000 * seconds / frames:8.2f} ms")
    reading = sum(seconds for name, seconds in steps.items() if "library" not in name and "remap" not in name)
    for way in ("library", "remap"):
        total = reading + sum(seconds for name, seconds in steps.items() if way in name)
        print(f"  {'total, ' + way:<16} {1000 * total / frames:8.2f} ms")
    print(
        f"remap against the library: RGB max {largest['RGB']:.0f} grey level(s), depth max "
        f"{largest['depth']:.3g} mm, ids {largest['ids']} pixel(s) differ"
    )

    chunk = Chunk(clip_name(path, 0), unit_name((path, 0)), stamps[: config.adt.chunk_frames])
    seconds, clip = _timed(annotate_chunk, chunk, sequence.frame, sequence.jpeg, sequence.instances, config)
    per_frame = seconds / clip.num_frames
    print(
        f"annotation of one clip ({clip.num_frames} frames, {clip.num_tracks} candidate tracks; RGB, depth, "
        f"ids and poses read once per frame): {seconds:.2f} s = {1000 * per_frame:.0f} ms/frame; a "
        f"300-frame chunk at that rate: {300 * per_frame:.0f} s"
    )
