"""Command line: ``python -m pipeline.viz CLIP.npz --out FILE``, ``python -m pipeline.viz FOLDER --out
OUT_FOLDER`` (one recording per clip) or ``python -m pipeline.viz stats DIR``."""

from __future__ import annotations

import argparse
import glob
import os
import sys

from pipeline.commandline import StrictParser
from pipeline.io.clip_reader import ReadLimits, add_limit_argument, limits_from
from pipeline.pipes import run_command
from pipeline.viz.clip_figure import OUTPUT_KINDS, write_clip_figure
from pipeline.viz.recording import write_recording
from pipeline.viz.stats_figure import dataset_stats, format_table, write_stats_figure

RECORDING = ".rrd"
FIGURE_TRACKS = 50


def clip_parser() -> StrictParser:
    parser = StrictParser(
        prog="python -m pipeline.viz",
        description="Draw a clip's tracks on its frames beside a 3D view of the trajectories, or write "
        "it as a Rerun recording (.rrd). For dataset statistics: python -m pipeline.viz stats DIR "
        "[--out FILE.png].",
    )
    parser.add_argument(
        "clip",
        help="clip .npz in the TAPVid-3D schema, or a folder of them (FOLDER/*.npz) to record one by one",
    )
    parser.add_argument(
        "--out",
        required=True,
        help="output .png (one frame), .gif or .mp4 (every frame), or .rrd (a Rerun recording); "
        "for a folder of clips, the folder (made if missing) that receives one <clip>.rrd per clip",
    )
    parser.add_argument("--frame", type=int, help="frame index for .png (default: the middle frame)")
    parser.add_argument(
        "--max-tracks",
        type=int,
        help=f"tracks drawn, evenly spaced (default: {FIGURE_TRACKS} in pictures, all in recordings)",
    )
    parser.add_argument("--fps", type=float, default=10.0, help="frames per second of .gif/.mp4 (default 10)")
    parser.add_argument("--tail", type=int, default=5, help="frames of tail behind each point (default 5)")
    add_limit_argument(parser)
    return parser


def stats_parser() -> StrictParser:
    parser = StrictParser(
        prog="python -m pipeline.viz stats",
        description="Histograms per source of clip statistics over DIR/<source>/*.npz, and a table.",
    )
    parser.add_argument("directory", help="output folder holding <source>/*.npz")
    parser.add_argument("--out", help="figure .png (default: DIR/stats.png)")
    add_limit_argument(parser)
    return parser


def read_limits(parser: StrictParser, assignments: list[str]) -> ReadLimits:
    try:
        return limits_from(assignments)
    except ValueError as error:
        parser.error(str(error))


def stats_main(argv: list[str]) -> int:
    parser = stats_parser()
    args = parser.parse_args(argv)
    limits = read_limits(parser, args.limit)
    if not os.path.isdir(args.directory):
        what = "is a file, not a folder" if os.path.exists(args.directory) else "does not exist"
        print(f"viz stats: {args.directory} {what}", file=sys.stderr)
        return 2
    out = args.out or os.path.join(args.directory, "stats.png")
    try:
        stats = dataset_stats(args.directory, limits)
        print(format_table(stats))
        write_stats_figure(stats, out)
    except (OSError, ValueError) as error:
        print(f"viz stats: {error}", file=sys.stderr)
        return 2
    print(f"wrote {out}")
    return 0


def record_folder(parser: StrictParser, args: argparse.Namespace, limits: ReadLimits) -> int:
    """One ``<clip>.rrd`` in ``args.out`` per ``args.clip/*.npz``; 2 when any clip failed."""
    if os.path.splitext(args.out)[1].lower() in (*OUTPUT_KINDS, RECORDING) or os.path.isfile(args.out):
        parser.error(f"a folder of clips gives one <clip>{RECORDING} each: --out must name a folder")
    paths = sorted(glob.glob(os.path.join(args.clip, "*.npz")))
    if not paths:
        print(f"viz: no clips in {args.clip}/*.npz", file=sys.stderr)
        return 2
    os.makedirs(args.out, exist_ok=True)
    failed = 0
    for path in paths:
        out = os.path.join(args.out, os.path.splitext(os.path.basename(path))[0] + RECORDING)
        try:
            count = write_recording(path, out, args.max_tracks, args.tail, limits)
        except (OSError, ValueError) as error:
            print(f"viz: {error}", file=sys.stderr)
            failed += 1
            continue
        print(f"wrote {out} ({count} frame(s))")
    return 2 if failed else 0


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["stats"]:
        return stats_main(argv[1:])
    parser = clip_parser()
    args = parser.parse_args(argv)
    limits = read_limits(parser, args.limit)
    if (args.max_tracks is not None and args.max_tracks < 1) or args.fps <= 0 or args.tail < 0:
        parser.error("--max-tracks must be >= 1, --fps > 0 and --tail >= 0")
    if os.path.isdir(args.clip):
        return record_folder(parser, args, limits)
    kind = os.path.splitext(args.out)[1].lower()
    if kind not in (*OUTPUT_KINDS, RECORDING):
        parser.error(f"--out must end in one of {', '.join((*OUTPUT_KINDS, RECORDING))}")
    try:
        if kind == RECORDING:
            count = write_recording(args.clip, args.out, args.max_tracks, args.tail, limits)
        else:
            tracks = FIGURE_TRACKS if args.max_tracks is None else args.max_tracks
            count = write_clip_figure(args.clip, args.out, args.frame, tracks, args.fps, args.tail, limits)
    except (OSError, ValueError) as error:
        print(f"viz: {error}", file=sys.stderr)
        return 2
    print(f"wrote {args.out} ({count} frame(s))")
    return 0


if __name__ == "__main__":
    run_command(main)
