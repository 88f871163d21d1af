"""``python -m pipeline.bench {drivetrack,pstudio,adt}``: speed figures, printed with ratios.

Each source's figures live in ``pipeline/<source>/bench.py`` (its ``run`` function):

drivetrack: the occlusion decision for one 1920x1280 frame, ours (nearest lidar point of the
  four integer pixels around each track point) against the DriveTrack generator's (a dense
  NearestNDInterpolator depth map of the whole image), on the same points, with the agreement.
"""

from __future__ import annotations

import argparse
import importlib
import sys

BENCHES = {
    "adt": "pipeline.adt.bench",
    "drivetrack": "pipeline.drivetrack.bench",
    "pstudio": "pipeline.pstudio.bench",
}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m pipeline.bench",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("source", choices=sorted(BENCHES))
    parser.add_argument("--frames", type=int, default=3, help="frames to time (default %(default)s)")
    args = parser.parse_args(argv)
    importlib.import_module(BENCHES[args.source]).run(args.frames)
    return 0


if __name__ == "__main__":
    sys.exit(main())
