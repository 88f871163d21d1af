"""``python -m benchmarks {all,adt,drivetrack,pstudio} [--quick | --full] [--micro]``: speed and memory.

Per-unit benchmark (default; ``benchmarks/units.py``), for each source:

1. one unit's real work on one worker (read inputs + annotate + filter + encode and write the
   clips: ``pipeline.unit.run_group``, the Beam graph's own stages), per unit and per input frame;
2. the peak memory (max RSS) of the process that ran it;
3. the speed-up of the same set of units (``--units``) from 1 to ``--workers`` (default 2)
   worker processes, each single-threaded and bound to a CPU of its own;
4. the read+decode floor: the bare cost of reading and decoding the unit's inputs, in one more
   such process right after each 1-worker run (``benchmarks/floors.py``), and the unit's time
   over it (time on one core: the CPU time of these single-threaded pinned processes, their wall
   time on an idle machine);
5. the CPU-hours of the whole benchmark (units of the release x CPU per unit).

It ends with one table (ms/frame, peak RSS, speed-up, CPU-hours, unit/floor, each against its
target, and a last row ``all`` with the total CPU-hours), also written as JSON (``--json``,
default ``<workdir>/bench.json``, ``bench-full.json`` with ``--full``).

Sizes. Default (``make bench``, a few minutes): inputs as large per frame as the release's but
shorter, the release unit extrapolated from the measured per-frame cost (marked ``*``):
  drivetrack: one synthetic Waymo v2 segment in the real Parquet schema, 30 frames, cameras
    FRONT, FRONT_LEFT, FRONT_RIGHT at 1920x1280, TOP lidar 64x2650 + 4 short-range lidars;
    unit = the segment's 3 cameras, the group the graph annotates together; extrapolated to
    3 x 199 camera frames.
  pstudio: 300,000 Gaussians x 30 frames x 27 cameras at 640x360 in Dynamic 3D Gaussians' file
    layout; unit = 3 cameras of the sequence annotated together; extrapolated to 3 x 150 frames.
  adt: the real excerpt (``pipeline.adt.source.excerpt_path()``: $ADT_EXCERPT, else
    ../shared/data/adt_sample): its one 2-frame chunk run 15 times; the 300-frame unit is
    extrapolated (the opening of the sequence, measured apart, + 300 x per-frame cost), at
    every size.
``--full`` (``make bench-full``): DriveTrack's segment of 199 frames, Panoptic Studio's 150
frames (writing them takes about 7 minutes the first time), 4 units in the scaling set, and
with ``--beam`` the Panoptic Studio units also through ``python -m pipeline.run`` on Beam's
DirectRunner. ``--quick``: small sizes to exercise the code paths fast (figures meaningless).
Inputs are generated once under ``--workdir`` (default out/bench) and reused.

Micro-benchmarks (``--micro``, with ``--frames``), ``benchmarks/<source>.py``:

drivetrack: the occlusion decision for one 1920x1280 frame, ours (nearest lidar point of the
  four integer pixels around each track point) against the DriveTrack generator's (a dense
  NearestNDInterpolator depth map of the whole image), on the same points, with the agreement.
pstudio: full-frame against selected-pixel depth renders, and one clip's annotation.
adt: per-frame cost of reading and re-rendering RGB, depth and ids on the real excerpt.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import time

from pipeline.commandline import StrictParser

ORDER = ("drivetrack", "pstudio", "adt")


def main(argv: list[str] | None = None) -> int:
    parser = StrictParser(
        prog="python -m benchmarks",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("source", choices=["all", *sorted(ORDER)])
    sizes = parser.add_mutually_exclusive_group()
    sizes.add_argument("--quick", action="store_true", help="small sizes: exercise the code paths fast")
    sizes.add_argument("--full", action="store_true", help="full-size inputs (make bench-full)")
    parser.add_argument(
        "--units", type=int, default=None, help="units in the scaling set (default 2; 4 with --full)"
    )
    parser.add_argument(
        "--workers", type=int, default=2, help="workers to compare with 1 (default %(default)s)"
    )
    parser.add_argument(
        "--workdir", default="out/bench", help="generated inputs and scratch (default %(default)s)"
    )
    parser.add_argument(
        "--no-pin",
        dest="pin",
        action="store_false",
        help="do not bind each worker process to a CPU of its own (threads may then use more cores)",
    )
    parser.add_argument(
        "--beam",
        action="store_true",
        help="also run the scaling units through python -m pipeline.run on Beam's DirectRunner (pstudio)",
    )
    parser.add_argument(
        "--json", default=None, help="where to write the table (default <workdir>/bench[-full|-quick].json)"
    )
    parser.add_argument("--micro", action="store_true", help="run the per-source micro-benchmarks instead")
    parser.add_argument("--frames", type=int, default=3, help="--micro: frames to time (default %(default)s)")
    args = parser.parse_args(argv)
    if "numpy" not in sys.modules:
        # Writing the inputs is NumPy work in this process: one BLAS / OpenMP thread, as in the
        # workers (on a busy machine BLAS's spinning threads made it several times slower).
        from benchmarks.processes import THREAD_ENV

        os.environ.update(THREAD_ENV)
    sources = ORDER if args.source == "all" else (args.source,)
    if args.micro:
        for source in sources:
            print(f"\n=== {source} (micro) ===")
            importlib.import_module(f"benchmarks.{source}").run(args.frames)
        return 0
    if args.units is None:
        args.units = 4 if args.full else 2
    if args.units < 1 or args.workers < 1:
        parser.error("--units and --workers must be at least 1")
    from benchmarks.report import format_table, summary_table, write_json
    from benchmarks.units import bench_source, prepare_side_by_side

    size = "quick" if args.quick else "full" if args.full else "default"
    name = "bench.json" if size == "default" else f"bench-{size}.json"
    path = args.json or os.path.join(args.workdir, name)
    started, load = time.perf_counter(), os.getloadavg()
    prepared = prepare_side_by_side(sources, args)
    figures = [f for f in (bench_source(source, args, prepared.get(source)) for source in sources) if f]
    if not figures:
        print("nothing was benchmarked")
        return 1
    table = summary_table(figures, size)
    print(f"\n=== summary: {size} size, {args.units} unit(s), 1 -> {args.workers} workers ===")
    for line in format_table(table):
        print(line)
    for f in figures:
        for note in f["notes"]:
            print(f"note ({f['source']}): {note}")
    elapsed = time.perf_counter() - started
    machine = {"cpus": os.cpu_count(), "load_average_at_start": load, "load_average_at_end": os.getloadavg()}
    print(
        f"load average {load[0]:.1f} at the start, {machine['load_average_at_end'][0]:.1f} at the end on "
        f"{os.cpu_count()} CPU(s): on a busy machine read the ratios, not the absolute times"
    )
    command = ["python", "-m", "benchmarks", *(sys.argv[1:] if argv is None else argv)]
    write_json(table, path, {"command": command, "machine": machine, "elapsed_s": elapsed})
    print(f"table written to {os.path.abspath(path)} ({elapsed:.0f} s in all)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
