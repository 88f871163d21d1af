"""``python -m benchmarks {all,adt,drivetrack,pstudio} [--quick] [--micro]``: speed and memory figures.

Per-unit benchmark (default; ``benchmarks/units.py``), for each source at realistic sizes:

1. one unit's real work on one worker (read inputs + annotate + filter + encode and write the
   clips: ``pipeline.unit.run_unit``, the Beam graph's own stages), per unit and per input frame;
2. the peak memory (max RSS) of the process that ran it (target for DriveTrack: 2.5 GiB);
3. the speed-up of the same set of units (``--units``, default 4) from 1 to ``--workers``
   (default 2) worker processes, each single-threaded and bound to a CPU of its own
   (target 1.6x on 2 cores);
4. the CPU-hours of the whole benchmark (units of the release x CPU per unit).

  drivetrack: one synthetic Waymo v2 segment (199 frames, 1920x1280 cameras, TOP lidar 64x2650,
    short-range lidars) written in the real Parquet schema; unit = (segment, FRONT camera).
  pstudio: 300,000 Gaussians x 150 frames x 27 cameras in Dynamic 3D Gaussians' file layout;
    unit = (sequence, camera).
  adt: the real excerpt (``pipeline.adt.source.excerpt_path()``: $ADT_EXCERPT, else
    ../shared/data/adt_sample): its one 2-frame chunk run 15 times; the 300-frame unit is
    extrapolated (the opening of the sequence, measured apart, + 300 x per-frame cost) and
    labelled so.

Inputs are generated once under ``--workdir`` (default out/bench) and reused. ``--quick`` uses
small sizes to exercise the code paths fast (figures meaningless).

Micro-benchmarks (``--micro``, with ``--frames``), ``benchmarks/micro_<source>.py``:

drivetrack: the occlusion decision for one 1920x1280 frame, ours (nearest lidar point of the
  four integer pixels around each track point) against the DriveTrack generator's (a dense
  NearestNDInterpolator depth map of the whole image), on the same points, with the agreement.
pstudio: full-frame against selected-pixel depth renders, and one clip's annotation.
adt: per-frame cost of reading and re-rendering RGB, depth and ids on the real excerpt.
"""

from __future__ import annotations

import argparse
import importlib
import sys

ORDER = ("drivetrack", "pstudio", "adt")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("source", choices=["all", *sorted(ORDER)])
    parser.add_argument("--quick", action="store_true", help="small sizes: exercise the code paths fast")
    parser.add_argument("--units", type=int, default=4, help="units in the scaling set (default %(default)s)")
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
    parser.add_argument("--micro", action="store_true", help="run the per-source micro-benchmarks instead")
    parser.add_argument("--frames", type=int, default=3, help="--micro: frames to time (default %(default)s)")
    args = parser.parse_args(argv)
    sources = ORDER if args.source == "all" else (args.source,)
    if args.micro:
        for source in sources:
            print(f"\n=== {source} (micro) ===")
            importlib.import_module(f"benchmarks.micro_{source}").run(args.frames)
        return 0
    if args.units < 1 or args.workers < 1:
        parser.error("--units and --workers must be at least 1")
    from benchmarks.report import print_summary
    from benchmarks.units import bench_source

    figures = [f for f in (bench_source(source, args) for source in sources) if f]
    if len(figures) > 1:
        print_summary(figures)
    return 0


if __name__ == "__main__":
    sys.exit(main())
