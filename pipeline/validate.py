"""``python -m pipeline.validate DIR``: check every clip under DIR; exit 1 on any violation."""

from __future__ import annotations

import argparse
import sys

from pipeline.export.files import list_files, read_bytes
from pipeline.export.validator import check_clip_bytes
from pipeline.graph import SOURCES


def source_of(path: str) -> str | None:
    """The source a clip belongs to, from its folder name (``<out>/<source>/<clip>.npz``)."""
    parts = path.replace("\\", "/").split("/")
    return parts[-2] if len(parts) >= 2 and parts[-2] in SOURCES else None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m pipeline.validate", description=__doc__)
    parser.add_argument("directory", help="an output folder (<out>/<source>/*.npz) or a folder of clips")
    args = parser.parse_args(argv)
    root = args.directory.rstrip("/")
    paths = list_files(f"{root}/*.npz") + list_files(f"{root}/*/*.npz")
    if not paths:
        print(f"no .npz clips under {root}", file=sys.stderr)
        return 1
    bad = 0
    for path in paths:
        problems = check_clip_bytes(read_bytes(path), source_of(path))
        if problems:
            bad += 1
            for problem in problems:
                print(f"{path}: {problem}")
    print(f"{len(paths)} clip(s) checked, {len(paths) - bad} valid, {bad} with violations")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
