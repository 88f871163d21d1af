"""``python -m benchmarks.compare_server [--clips N] [--latency-ms MS] [--jobs 1,8] [--dead]``:
``audit compare`` against the release's files served from 127.0.0.1 with a delay on every answer.

Per ``--jobs`` value: the wall time of comparing N clips, clips per second, and the time a
release-size compare (4,569 clips) would take at that rate. With ``--dead``, also the time a compare
takes to stop against a server that answers every request with 503 (the default ``http`` settings:
six tries a clip, 60 s of waits; ``max_failures_in_a_row`` 20).

The clips are DriveTrack-sized (150 frames x 256 tracks, a frames member of 150 small JPEGs that is
never fetched), written once under ``--workdir``; NEW holds the same clips, so each is scored in full.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import io
import os
import pathlib
import time

import numpy as np

from benchmarks.file_server import serve
from pipeline.commandline import StrictParser

RELEASE_CLIPS = 4569
FRAMES, TRACKS = 150, 256


def write_clips(workdir: str, count: int) -> tuple[str, str, str]:
    """(REF folder, NEW folder, clip list) holding ``count`` clips, written once."""
    import cv2

    from pipeline import sources
    from pipeline.export.npz_writer import encode_npz

    ref, new = os.path.join(workdir, "ref"), os.path.join(workdir, "new")
    listing = os.path.join(workdir, f"clips_{count}.txt")
    jpeg = cv2.imencode(".jpg", np.full((128, 192, 3), 90, np.uint8))[1].tobytes()
    source = sources.names()[0]  # the clips' folder: any registered source's
    for index in range(count):
        name = f"{source}/bench_{index:05d}.npz"
        if os.path.exists(os.path.join(new, name)):
            continue
        rng = np.random.default_rng(index)
        data = encode_npz(
            {
                "images_jpeg_bytes": np.array([jpeg] * FRAMES),
                "queries_xyt": np.column_stack([rng.random((TRACKS, 2)) * 100, np.zeros(TRACKS)]),
                "tracks_XYZ": rng.random((FRAMES, TRACKS, 3)) + [0.0, 0.0, 5.0],
                "visibility": rng.random((FRAMES, TRACKS)) > 0.2,
                "fx_fy_cx_cy": np.array([100.0, 100.0, 96.0, 64.0]),
            }
        )
        for root in (ref, new):
            os.makedirs(os.path.join(root, source), exist_ok=True)
            with open(os.path.join(root, name), "wb") as out:
                out.write(data)
    with open(listing, "w") as out:
        out.writelines(f"{source}/bench_{index:05d}.npz\n" for index in range(count))
    return ref, new, listing


def clip_names(listing: str) -> list[str]:
    """The clip paths (``<source>/bench_<index>.npz``) a listing written by ``write_clips`` holds."""
    with open(listing) as lines:
        return [line.strip() for line in lines]


def timed_compare(base: str, new: str, listing: str, out: str, extra: list[str]) -> tuple[int, float, str]:
    """(exit status, seconds, its last stderr line) of ``audit compare`` in this process."""
    from pipeline.audit.compare import main

    err = io.StringIO()
    started = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        status = main([base, new, "--clips", listing, "--out", out, *extra])
    lines = err.getvalue().strip().splitlines()
    return status, time.perf_counter() - started, lines[-1] if lines else ""


def bench(args: argparse.Namespace) -> list[str]:
    """The figures, one line each."""
    ref, new, listing = write_clips(args.workdir, args.clips)
    importlib.import_module("pipeline.audit.compare")  # its imports are not the compare's time
    lines = []
    with serve(pathlib.Path(ref), latency_s=args.latency_ms / 1000) as server:
        for jobs in args.jobs:
            out = os.path.join(args.workdir, f"compare_jobs{jobs}")
            status, seconds, _ = timed_compare(
                server.base_url, new, listing, out, ["--jobs", str(jobs), *args.set]
            )
            rate = args.clips / seconds
            lines.append(
                f"--jobs {jobs}: {args.clips} clips in {seconds:.1f} s, {rate:.1f} clips/s at "
                f"{args.latency_ms:g} ms a request (at most {server.most_at_once()} at once; exit {status}); "
                f"a release-size compare ({RELEASE_CLIPS:,} clips): {RELEASE_CLIPS / rate / 60:.1f} minutes"
            )
            server.reset()
        if args.dead:
            for index in range(args.clips):
                server.fail(clip_names(listing)[index], *["503"] * 50)
            out = os.path.join(args.workdir, "compare_dead")
            jobs = str(max(args.jobs))
            status, seconds, last = timed_compare(
                server.base_url, new, listing, out, ["--jobs", jobs, *args.set]
            )
            lines.append(f"a server answering 503: stopped after {seconds:.0f} s (exit {status}): {last}")
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = StrictParser(prog="python -m benchmarks.compare_server", description=__doc__)
    parser.add_argument("--clips", type=int, default=300, help="clips compared (default %(default)s)")
    parser.add_argument(
        "--latency-ms", type=float, default=50.0, help="delay of every answer (default %(default)s)"
    )
    parser.add_argument(
        "--jobs", default="1,8", help="--jobs values to time, comma-separated (default %(default)s)"
    )
    parser.add_argument(
        "--dead", action="store_true", help="also time a compare against a server answering 503"
    )
    parser.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="passed to compare's --set"
    )
    parser.add_argument(
        "--workdir", default="out/bench/compare", help="clips and reports (default %(default)s)"
    )
    args = parser.parse_args(argv)
    try:
        args.jobs = [int(value) for value in args.jobs.split(",")]
    except ValueError:
        parser.error(f"--jobs {args.jobs}: expected numbers separated by commas")
    if args.clips < 1 or not all(jobs >= 1 for jobs in args.jobs):
        parser.error("--clips and each --jobs value must be at least 1")
    args.set = [part for setting in args.set for part in ("--set", setting)]
    for line in bench(args):
        print(line, flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
