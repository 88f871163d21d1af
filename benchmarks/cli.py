"""``python -m benchmarks {all,<source>} [--quick | --full] [--micro]``: speed and memory.

Per-unit benchmark (default; ``benchmarks/units.py``), for each source (``all``: every registered
source, in the registry's order):

1. one unit's real work on one worker (read inputs + annotate + filter + encode and write the
   clips: ``pipeline.runner.stages.run_group``, the Beam graph's own stages), per unit and per input frame;
2. the peak memory (max RSS) of the process that ran it;
3. the speed-up of the same set of units (``--units``) from 1 to ``--workers`` (default 2)
   worker processes, each single-threaded and bound to a CPU of its own;
4. the read+decode floor: the bare cost of reading and decoding the unit's inputs, in one more
   such process right after each 1-worker run (the entry's ``floor``), and the unit's time
   over it (time on one core: the CPU time of these single-threaded pinned processes, their wall
   time on an idle machine);
5. the CPU-hours of the whole benchmark (units of the release x CPU per unit).

It ends with one table (ms/frame, peak RSS, speed-up, with ``--beam`` the speed-up through Beam,
CPU-hours, unit/floor, each against its target, and a last row ``all`` with the total CPU-hours),
also written as JSON (``--json``, default ``<workdir>/bench.json``, ``bench-full.json`` with
``--full``); the JSON also holds each source's peak memory per rule set
(``peak_rss_gib_by_rules``: the unit under its own and under each variant's, ``release`` and
``refined`` for each built-in source, DriveTrack's ``refined without undistorted frames`` too).

Sizes. Default (``make bench``, a few minutes): inputs as large per frame as the release's but
shorter, the release unit extrapolated from the measured per-frame cost (marked ``*``).
``--full`` (``make bench-full``): full-size inputs, 4 units in the scaling set. ``--beam`` (at any
size; ``make bench-full`` sets it): each source's groups also through ``python -m pipeline.run`` on
Beam's DirectRunner, as a user runs them, with 1 and ``--workers`` worker processes: 4 distinct
groups per worker, made of the unit's input by links (the entry's ``beam_input``); the whole
command's speed-up, judged like the units', and its serial start (the command's start until its
first unit starts, + its last unit's end until the command ends; from the units' checkpoints), in
the table and its JSON (``beam_speedup``, ``beam_wall_s``, ``beam_serial_s``;
``benchmarks/beam.py``). ``--quick``: small sizes to exercise the code paths fast (figures
meaningless). Inputs are generated once under ``--workdir`` (default out/bench) and reused.

Micro-benchmarks (``--micro``, with ``--frames``): each source's entry's ``micro``.

Per source, its benchmark entry (``pipeline/<source>/bench.py`` for a built-in source):
"""

from __future__ import annotations

import argparse
import os
import sys
import textwrap
import time

from pipeline.commandline import StrictParser

# The pipeline, hence NumPy, is imported inside the functions, after ``one_thread_here``.


def main(argv: list[str] | None = None) -> int:
    one_thread_here()
    args = parse(argv)
    from benchmarks.units import bench_source, prepare_side_by_side
    from pipeline import sources

    names = sources.names() if args.source == "all" else (args.source,)
    if args.micro:
        return micro(names, args.frames)
    started, load = time.perf_counter(), os.getloadavg()
    prepared = prepare_side_by_side(names, args)
    figures = [f for f in (bench_source(source, args, prepared.get(source)) for source in names) if f]
    if not figures:
        print("nothing was benchmarked")
        return 1
    command = ["python", "-m", "benchmarks", *(sys.argv[1:] if argv is None else argv)]
    summarize(figures, args, command, started, load)
    return 0


def one_thread_here() -> None:
    """Writing the inputs is NumPy work in this process: one BLAS / OpenMP thread, as in the workers
    (on a busy machine BLAS's spinning threads made it several times slower); only before NumPy is
    imported (a test calling ``main`` keeps its own)."""
    if "numpy" not in sys.modules:
        from benchmarks.processes import THREAD_ENV

        os.environ.update(THREAD_ENV)


def _described(names: tuple[str, ...]) -> str:
    """This module's docstring, then the first paragraph of each source's entry's docstring."""
    from benchmarks.entry import entry

    lines = [__doc__]
    for name in names:
        summary = entry(name).__doc__.split("\n\n")[0]
        lines.append(f"{name}:\n{textwrap.indent(summary, '  ')}")
    return "\n".join(lines)


def parse(argv: list[str] | None) -> argparse.Namespace:
    """The command line, checked; ``size`` ("quick", "default", "full"), ``units`` and ``json``
    filled in."""
    from pipeline import sources

    parser = _parser(sources.names())
    args = parser.parse_args(argv)
    args.units = args.units if args.units is not None else 4 if args.full else 2
    if args.units < 1 or args.workers < 1:
        parser.error("--units and --workers must be at least 1")
    args.size = "quick" if args.quick else "full" if args.full else "default"
    args.json = args.json or os.path.join(
        args.workdir, "bench.json" if args.size == "default" else f"bench-{args.size}.json"
    )
    return args


def _parser(names: tuple[str, ...]) -> StrictParser:
    from benchmarks.beam import GROUPS_PER_WORKER

    parser = StrictParser(
        prog="python -m benchmarks",
        description=_described(names),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("source", choices=["all", *names])
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
        help=f"also run {GROUPS_PER_WORKER} groups per worker of each source through python -m pipeline.run "
        "on Beam's DirectRunner, with 1 and --workers workers: the command's speed-up and serial start",
    )
    parser.add_argument(
        "--json", default=None, help="where to write the table (default <workdir>/bench[-full|-quick].json)"
    )
    parser.add_argument("--micro", action="store_true", help="run the per-source micro-benchmarks instead")
    parser.add_argument("--frames", type=int, default=3, help="--micro: frames to time (default %(default)s)")
    return parser


def micro(names: tuple[str, ...], frames: int) -> int:
    """Each source's micro-benchmarks, over ``frames`` frames."""
    from benchmarks.entry import entry

    for source in names:
        print(f"\n=== {source} (micro) ===")
        entry(source).micro(frames)
    return 0


def summarize(
    figures: list[dict], args: argparse.Namespace, command: list[str], started: float, load: tuple
) -> None:
    """Print the table of ``figures`` and the sources' notes, and write it as JSON (``args.json``)
    with the command, the machine (its load average at ``started`` and now) and the time since."""
    from benchmarks.table import format_table, summary_table, write_json

    table = summary_table(figures, args.size)
    print(f"\n=== summary: {args.size} size, {args.units} unit(s), 1 -> {args.workers} workers ===")
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
    write_json(table, args.json, {"command": command, "machine": machine, "elapsed_s": elapsed})
    print(f"table written to {os.path.abspath(args.json)} ({elapsed:.0f} s in all)")


if __name__ == "__main__":
    sys.exit(main())
