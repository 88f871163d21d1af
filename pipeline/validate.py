"""``python -m pipeline.validate PATH``: check one clip, or every clip under a folder; exit 1 on any
violation (2 when PATH holds no clip).

Also prints, per clip, quality findings that do not fail the run (queries hidden at their own
query frame, tracks visible off the image or behind the camera, flickering tracks); ``--report
FILE`` writes the same table as JSON.
"""

from __future__ import annotations

import json
import os
import sys
from typing import Any

from pipeline.commandline import StrictParser
from pipeline.export.invariants import FINDINGS, FLICKER_MAX_FRACTION, NO_FINDINGS, inspect_clip_bytes
from pipeline.io.clip_reader import add_limit_argument, limits_from
from pipeline.io.files import file_size, is_local, list_files, read_bytes, write_atomic
from pipeline.pipes import run_command


def findings_table(rows: list[dict[str, Any]]) -> str:
    """Plain-text table: clip, tracks, then one column per finding ('-' where it could not be looked at)."""
    header = ("clip", "tracks", *FINDINGS)
    cells = [header] + [tuple("-" if row[key] is None else str(row[key]) for key in header) for row in rows]
    widths = [max(len(line[i]) for line in cells) for i in range(len(header))]
    return "\n".join(
        "  ".join(cell.ljust(width) for cell, width in zip(line, widths, strict=True)) for line in cells
    )


def clip_paths(path: str) -> list[str]:
    """The clips to check: ``path`` itself when it is a file, else ``<path>/*.npz`` and
    ``<path>/*/*.npz``; ValueError saying when there is none."""
    root = path.rstrip("/") or "/"
    if is_local(root) and not os.path.exists(root):
        raise ValueError(f"{root} does not exist")
    if (is_local(root) and os.path.isfile(root)) or (not is_local(root) and file_size(root) is not None):
        return [root]
    paths = list_files(f"{root}/*.npz") + list_files(f"{root}/*/*.npz")
    if not paths:
        raise ValueError(f"no .npz clips in {root} (<folder>/*.npz or <folder>/<source>/*.npz)")
    return paths


def main(argv: list[str] | None = None) -> int:
    parser = StrictParser(prog="python -m pipeline.validate", description=__doc__)
    parser.add_argument(
        "path", help="a clip (.npz), an output folder (<out>/<source>/*.npz) or a folder of clips"
    )
    parser.add_argument(
        "--flicker-max-fraction",
        type=float,
        default=FLICKER_MAX_FRACTION,
        help="a track flickers when its visibility changes state more than this fraction of T times",
    )
    parser.add_argument("--report", help="write the per-clip findings and violations to this JSON file")
    add_limit_argument(parser)
    args = parser.parse_args(argv)
    try:
        limits = limits_from(args.limit)
    except ValueError as error:
        parser.error(str(error))
    try:
        paths = clip_paths(args.path)
    except ValueError as error:
        print(f"validate: {error}", file=sys.stderr)
        return 2
    bad = 0
    rows: list[dict[str, Any]] = []  # a clip's path, findings (counts, residuals, None) and violations
    for path in paths:
        try:
            data = read_bytes(path, limits.max_file_bytes)
        except OSError as error:
            problems, findings = [f"cannot be read ({error.strerror or error})"], dict(NO_FINDINGS)
        else:
            problems, findings = inspect_clip_bytes(data, args.flicker_max_fraction, limits)
        if problems:
            bad += 1
            for problem in problems:
                print(f"{path}: {problem}")
        rows.append({"clip": path, **findings, "violations": problems})
    print(findings_table(rows))
    totals = {key: sum(row[key] or 0 for row in rows) for key in FINDINGS}
    print("quality findings (tracks): " + ", ".join(f"{key} {count}" for key, count in totals.items()))
    if args.report:
        report = {"flicker_max_fraction": args.flicker_max_fraction, "totals": totals, "clips": rows}
        write_atomic(args.report, json.dumps(report, indent=1).encode())
    print(f"{len(paths)} clip(s) checked, {len(paths) - bad} valid, {bad} with violations")
    return 1 if bad else 0


if __name__ == "__main__":
    run_command(main)
