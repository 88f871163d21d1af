"""ADT's benchmark entry. Unit: the real excerpt (``pipeline.adt.sample.excerpt.excerpt_path()``:
$ADT_EXCERPT, else ../shared/data/adt_sample), read through projectaria-tools: its one 2-frame
chunk run 15 times; the 300-frame unit is extrapolated (the opening of the sequence, measured
apart, + 300 x per-frame cost), at every size. Micro: per-frame cost of reading and re-rendering
RGB, depth and ids.

Inputs (``prepare``): the excerpt's ground-truth window holds 2 frames, so its unit is that 2-frame
chunk, run ``REPEAT`` times through ``pipeline.runner.stages.run_group`` (each run opens and closes the
sequence, as a group does); a release unit (300 frames) is extrapolated: its share of its group's
opening and closing (the sequence opened, its re-rendering tables built and the sequence closed once
for ``CHUNKS_PER_GROUP`` chunks, measured apart by ``measure_fixed_cost`` with the source's own
``open_sequence`` and ``close_sequence``), the filter, encode and write stage of a 300-frame clip
(measured apart, once per unit), plus 300 x the measured per-frame cost of reading, re-rendering
and annotating.

Floor (``floor``): opening the sequence with projectaria-tools (``AriaDigitalTwinDataProvider``,
once, cold) and its frame timestamps, then the chunk's RGB, depth and segmentation frames read from
the VRS files ``repeat`` times, as the unit's runs read them, then closing it; the report
extrapolates it to a 300-frame unit like the unit itself (its share of a group's opening and
closing + 300 x per-frame read).

Micro (``micro``): per-frame cost of reading RGB, depth and ids (projectaria-tools' VRS decode), of
re-rendering them to the stored frames both ways -- projectaria-tools' ``distort_*_by_calibration``
(the reference) and ours (``Remap`` gathers, the same pixels) -- of the poses and the JPEG encoding,
with the largest difference between the two renderings; then the cost of building the tables and
the annotation cost of one clip, per frame and extrapolated to a 300-frame chunk.

Rules: the unit runs under the release's rules (``rules=release``: what regenerating the release
costs), and each 1-worker unit once more under the refined rules (``rules=refined``, a plain
run's), printed beside it, the peak memory of each in the table's JSON; with the excerpt's settings
the two do the same work (the one ADT setting they govern, ``adt.max_gt_offset_ms``, is one of
those settings).

Beam (``--beam``, ``beam_input``): as many sequences as groups asked, each a symbolic link to the
excerpt under a name of its own, its one chunk a group: a 2-frame group, so the command's start
and finish weigh on the speed-up more than with a release's 300-frame chunks.

The pipeline's modules are imported inside the functions, so that a floor process imports only
what its floor reads.
"""

from __future__ import annotations

import os
import time
from typing import TYPE_CHECKING

import numpy as np

from pipeline.core.benchmark import UnitSetup, wall_and_cpu

if TYPE_CHECKING:
    from pipeline.settings.run_config import RunConfig

# Per input frame on one core.
TARGETS = {"ms_per_frame": 60.0}
RELEASE_SHAPE = (4096, (300, 300))  # the release's candidates per clip, (fewest, most) frames per clip
# Each repeated run opens and closes the sequence again (warm: the tables cached); the worker times
# these inside the runs and the report takes them out of the per-frame cost.
FIXED_IN_WORK = (("pipeline.adt.annotate", "open_sequence"), ("pipeline.adt.annotate", "close_sequence"))
CHUNK_FRAMES = 300
RELEASE_UNITS = 1956  # one clip per (sequence, 300-frame chunk) unit, 215 sequences
REPEAT, QUICK_REPEAT = 15, 2


def prepare(workdir: str, size: str) -> UnitSetup | None:
    """The excerpt's unit (read in place: nothing is written under ``workdir``), or None (skipped)
    without an excerpt."""
    from pipeline.adt.sample.excerpt import EXCERPT_SETTINGS, SHARED_EXCERPT, excerpt_path

    path = excerpt_path()
    if path is None:
        where = os.environ.get("ADT_EXCERPT") or SHARED_EXCERPT
        print(f"adt: no ADT excerpt at {where}; set ADT_EXCERPT to a sequence folder. Skipped.")
        return None
    chunk = int(EXCERPT_SETTINGS[0].split("=")[1])
    repeat = QUICK_REPEAT if size == "quick" else REPEAT
    return UnitSetup(
        source="adt",
        input_root=path,
        units=[[[path, 0]]],
        overrides=[*EXCERPT_SETTINGS, "rules=release"],
        frames=chunk * repeat,
        description=[
            f"the real ADT excerpt: its one chunk of {chunk} frames ({', '.join(EXCERPT_SETTINGS)}), "
            "1408x1408 fisheye RGB, depth and ids re-rendered to 512x512",
            f"unit = that chunk through pipeline.runner.stages.run_group {repeat} times "
            f"({chunk * repeat} frames), "
            "so that process start does not dominate; the opening of the sequence is measured apart "
            "(cold, a third of it per unit) and the runs' own openings are timed and taken out of the "
            "per-frame cost; the scaling set repeats the unit (same input, separate outputs)",
        ],
        full_units=RELEASE_UNITS,
        full_clips=RELEASE_UNITS,
        full_units_note=(
            f"1956 clips = 1956 (sequence, {CHUNK_FRAMES}-frame chunk) units; per-unit CPU extrapolated"
        ),
        extrapolate_frames=CHUNK_FRAMES,
        notes=[
            "the excerpt is small: opening a full sequence (its poses and object tables) costs more time "
            "and memory than here; a 300-frame unit also holds 300 JPEGs and [300, 4096] tracks "
            "(~70 MB more); the repeated frames are read from the page cache; the chunk's 4,096 "
            f"candidate queries fall on its {chunk} frames (2,048 a frame, a 300-frame chunk's 14): the "
            "per-query work of the query frames (drawing, attaching) leans high"
        ],
        extra={"repeat": repeat},
        variants={"the refined rules": ["rules=refined"]},
        rule_sets={"refined": "the refined rules"},
    )


def _settings(config: RunConfig):
    """The run's ADT section (what ADT's functions take)."""
    from pipeline.adt.settings import AdtConfig

    return config.section(AdtConfig)


def _open_and_close_once(sequence: str, config: RunConfig) -> tuple[float, float]:
    """Wall and CPU seconds of what a group of ADT units does once, around its chunks: open the
    sequence, read its frame timestamps and build the re-rendering tables (``open_sequence``; the
    tables are cached per calibration in the process, so the first opening builds them), then
    close it (``close_sequence``)."""
    from pipeline.adt.frames import close_sequence, open_sequence

    wall, cpu = time.perf_counter(), time.process_time()
    close_sequence(open_sequence(sequence, _settings(config)))
    return time.perf_counter() - wall, time.process_time() - cpu


def _first_calls(sequence: str, config: RunConfig) -> tuple[float, float]:
    """Wall and CPU seconds of numba's first dispatch of the re-rendering loops (loading them from
    its cache: once per worker process, like the imports, so not a unit's cost)."""
    from pipeline.adt.frames import open_sequence

    frames = open_sequence(sequence, _settings(config)).frames
    wall, cpu = time.perf_counter(), time.process_time()
    frames.rectifier.rgb(np.zeros((*frames.reader.image_shape, 3), np.uint8))
    frames.rectifier.depth_mm(np.zeros(frames.reader.image_shape, np.uint16))
    return time.perf_counter() - wall, time.process_time() - cpu


def release_size_clip(spec: dict, config: RunConfig):
    """The unit's own clip with its frames repeated to a release unit's 300 (JPEGs, tracks,
    visibility, extrinsics): the harness times its filter, encode and write stage apart
    (``write_unit_s``), as a release unit pays it once."""
    import dataclasses

    from pipeline import sources

    source = sources.get("adt")
    ((sequence, chunk),) = spec["unit"]
    (made,) = source.annotate_group(spec["input_root"], [unit_of([sequence, chunk])], config, [None])
    if isinstance(made, Exception):
        raise made
    (clip,) = made.clips
    assert clip.extrinsics_w2c is not None, "ADT clips hold their extrinsics"
    take = np.arange(CHUNK_FRAMES) % clip.num_frames
    return dataclasses.replace(
        clip,
        images_jpeg=[clip.images_jpeg[i] for i in take],
        extrinsics_w2c=clip.extrinsics_w2c[take],
        tracks_xyz=clip.tracks_xyz[take],
        visibility=clip.visibility[take],
        frame_ids=np.arange(CHUNK_FRAMES),
    )


def measure_fixed_cost(spec: dict, config: RunConfig) -> dict:
    """The unit's costs that do not scale with its frames, measured apart (called by
    ``benchmarks.worker`` before the runs).

    fixed_s / fixed_cpu_s: the unit's share of its group's opening and closing (``CHUNKS_PER_GROUP``
    chunks of a sequence share one, cold: its re-rendering tables built);
    open_s / open_cpu_s: that whole opening and closing; first_calls_s / first_calls_cpu_s: numba's
    first dispatch of the re-rendering loops (once per worker process, reported, not counted);
    (fixed_in_work_s / fixed_in_work_cpu_s, the openings and closings the ``repeat`` runs pay inside
    their work, are timed in the runs themselves: ``FIXED_IN_WORK``). The write stage of a
    300-frame clip (``release_size_clip``) is timed by the harness."""
    from pipeline.adt.units import CHUNKS_PER_GROUP

    ((sequence, _),) = spec["unit"]
    open_wall, open_cpu = _open_and_close_once(sequence, config)
    first_wall, first_cpu = _first_calls(sequence, config)
    return {
        "fixed_s": open_wall / CHUNKS_PER_GROUP,
        "fixed_cpu_s": open_cpu / CHUNKS_PER_GROUP,
        "open_s": open_wall,
        "open_cpu_s": open_cpu,
        "first_calls_s": first_wall,
        "first_calls_cpu_s": first_cpu,
    }


def floor(spec: dict) -> dict:
    """The read+decode floor of the unit's chunk (the module's docstring): floor_s / floor_cpu_s
    and floor_frames, with floor_open_s / floor_open_cpu_s (the opening and closing, inside
    floor_s) and floor_open_share (a unit's share of it: a group of chunks opens and closes the
    sequence once)."""
    from pipeline.adt.frames import open_reader
    from pipeline.adt.units import CHUNKS_PER_GROUP
    from pipeline.settings.fields import with_overrides
    from pipeline.settings.run_config import RunConfig

    config = with_overrides(RunConfig(), spec["overrides"])
    ((sequence, chunk),) = spec["unit"]
    opened: list = []

    def open_sequence() -> None:
        reader = open_reader(sequence, _settings(config))
        opened[:] = reader, reader.frame_timestamps()

    open_wall, open_cpu = wall_and_cpu(open_sequence)
    reader, all_stamps = opened
    size = _settings(config).chunk_frames
    stamps = all_stamps[chunk * size : (chunk + 1) * size]
    repeat = spec.get("repeat", 1)

    def read() -> None:
        for _ in range(repeat):
            for timestamp in stamps:
                reader.rgb(timestamp)
                reader.depth_mm(timestamp)
                reader.ids(timestamp)

    wall, cpu = wall_and_cpu(read)
    close_wall, close_cpu = wall_and_cpu(reader.close)
    return {
        "floor_s": open_wall + wall + close_wall,
        "floor_cpu_s": open_cpu + cpu + close_cpu,
        "floor_frames": len(stamps) * repeat,
        "floor_open_s": open_wall + close_wall,
        "floor_open_cpu_s": open_cpu + close_cpu,
        "floor_open_share": 1.0 / CHUNKS_PER_GROUP,  # a group of chunks opens and closes the sequence once
    }


def unit_of(fields: list):
    """The SequenceChunk of a spec's JSON fields."""
    from pipeline.adt.units import SequenceChunk

    return SequenceChunk(*fields)


def micro(frames: int) -> None:
    """Print per-frame reading/re-rendering costs over ``frames`` frame reads, then the clip cost."""
    from pipeline.adt.frames import SequenceFrames, open_reader
    from pipeline.adt.rectify import _stored_remap
    from pipeline.adt.sample.excerpt import EXCERPT_SETTINGS, SHARED_EXCERPT, excerpt_path
    from pipeline.settings.fields import with_overrides
    from pipeline.settings.run_config import RunConfig

    path = excerpt_path()
    if path is None:
        where = os.environ.get("ADT_EXCERPT") or SHARED_EXCERPT
        print(f"adt bench: no ADT excerpt at {where}; set ADT_EXCERPT to a sequence folder")
        return
    config = with_overrides(RunConfig(), list(EXCERPT_SETTINGS))
    settings = _settings(config)
    open_time, reader = _timed(open_reader, path, settings)
    stamps = reader.frame_timestamps()
    _stored_remap.cache_clear()
    build_time, sequence = _timed(SequenceFrames, reader, settings)
    cached_time = _timed(SequenceFrames, reader, settings)[0]
    jit_time, steps, largest = _per_frame_steps(reader, sequence, settings, stamps, max(1, frames))
    size = settings.image_size
    print(f"ADT excerpt {path}")
    print(f"opening the sequence (projectaria-tools provider): {1000 * open_time:.0f} ms")
    print(
        f"re-rendering tables (projectaria-tools' project for {size * size} pixels, once per calibration "
        f"per process): {1000 * build_time:.0f} ms; cached: {1000 * cached_time:.2f} ms; first RGB and depth "
        f"calls (numba compiles or loads its cached loops, once per process): {1000 * jit_time:.0f} ms"
    )
    _print_steps(steps, largest, max(1, frames), size)
    _clip_cost(path, sequence, stamps, config)


def _timed(function, *args):
    start = time.perf_counter()
    result = function(*args)
    return time.perf_counter() - start, result


def _library_renderers(reader, settings):
    """The reference: projectaria-tools' re-rendering then the clockwise turn, per image kind."""
    from projectaria_tools.core import calibration

    from pipeline.adt.rectify import target_calibration

    source = reader.calibration
    target = target_calibration(source, settings.image_size, settings.focal)
    return {
        "RGB": lambda image: np.rot90(calibration.distort_by_calibration(image, target, source), -1),
        "depth": lambda depth: np.rot90(
            calibration.distort_depth_by_calibration(depth.astype(np.float32), target, source), -1
        ),
        "ids": lambda ids: np.rot90(calibration.distort_label_by_calibration(ids, target, source), -1),
    }


def _per_frame_steps(reader, sequence, settings, stamps, frames: int) -> tuple[float, dict, dict]:
    """Over ``frames`` frame reads: (seconds of the first RGB and depth calls of ours, seconds of
    each step summed, the largest difference between the two renderings per image kind)."""
    from pipeline.adt.frames import encode_jpeg

    rect, library = sequence.rectifier, _library_renderers(reader, settings)
    ours = {"RGB": rect.rgb, "depth": rect.depth_mm, "ids": rect.ids}
    read = {"RGB": reader.rgb, "depth": reader.depth_mm, "ids": reader.ids}
    first = int(stamps[0])
    jit_time = sum(_timed(ours[kind], read[kind](first))[0] for kind in ("RGB", "depth"))
    steps: dict[str, float] = {}
    largest = {"RGB": 0.0, "depth": 0.0, "ids": 0}  # grey levels, mm, mismatched pixels
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
    return jit_time, steps, largest


def _print_steps(steps: dict, largest: dict, frames: int, size: int) -> None:
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


def _clip_cost(path: str, sequence, stamps, config) -> None:
    """Print the annotation cost of the excerpt's first chunk, per frame and for a 300-frame chunk."""
    from pipeline.adt.records import Chunk
    from pipeline.adt.tracks import candidate_clip
    from pipeline.adt.units import SequenceChunk, clip_name
    from pipeline.sources import RunChoices

    chunk = Chunk(clip_name(path, 0), SequenceChunk(path, 0).name, stamps[: _settings(config).chunk_frames])
    reads = (sequence.frame, sequence.jpeg, sequence.instances)
    seconds, clip = _timed(candidate_clip, chunk, *reads, _settings(config), RunChoices.of(config, "adt"))
    per_frame = seconds / clip.num_frames
    print(
        f"annotation of one clip ({clip.num_frames} frames, {clip.num_tracks} candidate tracks; RGB, depth, "
        f"ids and poses read once per frame): {seconds:.2f} s = {1000 * per_frame:.0f} ms/frame; a "
        f"300-frame chunk at that rate: {300 * per_frame:.0f} s"
    )


def beam_input(setup: UnitSetup, folder: str, groups: int) -> list[str]:
    """``groups`` sequence folders in ``folder``, each a symbolic link to the excerpt under a name of
    its own (``<excerpt>_<k>``, read in place; the excerpt's one chunk is a group). Returns the
    ``pipeline.run`` arguments."""
    name = os.path.basename(setup.input_root)
    for k in range(groups):
        os.symlink(setup.input_root, os.path.join(folder, f"{name}_{k}"))
    return ["--input", folder]
