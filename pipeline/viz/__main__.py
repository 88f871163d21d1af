"""Command line: ``python -m pipeline.viz CLIP.npz --out FILE`` or ``python -m pipeline.viz stats DIR``."""

from __future__ import annotations

import argparse
import os
import sys

from pipeline.viz.clip_figure import OUTPUT_KINDS, write_clip_figure
from pipeline.viz.stats_figure import dataset_stats, format_table, write_stats_figure


def clip_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m pipeline.viz",
        description="Draw a clip's tracks on its frames beside a 3D view of the trajectories. "
        "For dataset statistics: python -m pipeline.viz stats DIR [--out FILE.png].",
    )
    parser.add_argument("clip", help="clip .npz in the TAPVid-3D schema")
    parser.add_argument("--out", required=True, help="output .png (one frame), .gif or .mp4 (every frame)")
    parser.add_argument("--frame", type=int, help="frame index for .png (default: the middle frame)")
    parser.add_argument("--max-tracks", type=int, default=50, help="tracks drawn, evenly spaced (default 50)")
    parser.add_argument("--fps", type=float, default=10.0, help="frames per second of .gif/.mp4 (default 10)")
    parser.add_argument("--tail", type=int, default=5, help="frames of 2D tail behind each point (default 5)")
    return parser


def stats_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m pipeline.viz stats",
        description="Histograms per source of clip statistics over DIR/<source>/*.npz, and a table.",
    )
    parser.add_argument("directory", help="output folder holding <source>/*.npz")
    parser.add_argument("--out", help="figure .png (default: DIR/stats.png)")
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["stats"]:
        parser = stats_parser()
        args = parser.parse_args(argv[1:])
        out = args.out or os.path.join(args.directory, "stats.png")
        try:
            stats = dataset_stats(args.directory)
            print(format_table(stats))
            write_stats_figure(stats, out)
        except (OSError, ValueError) as error:
            print(f"viz stats: {error}", file=sys.stderr)
            return 2
        print(f"wrote {out}")
        return 0
    parser = clip_parser()
    args = parser.parse_args(argv)
    if os.path.splitext(args.out)[1].lower() not in OUTPUT_KINDS:
        parser.error(f"--out must end in one of {', '.join(OUTPUT_KINDS)}")
    if args.max_tracks < 1 or args.fps <= 0 or args.tail < 0:
        parser.error("--max-tracks must be >= 1, --fps > 0 and --tail >= 0")
    try:
        count = write_clip_figure(args.clip, args.out, args.frame, args.max_tracks, args.fps, args.tail)
    except (OSError, ValueError) as error:
        print(f"viz: {error}", file=sys.stderr)
        return 2
    print(f"wrote {args.out} ({count} frame(s))")
    return 0


if __name__ == "__main__":
    sys.exit(main())
