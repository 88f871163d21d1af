"""``python -m pipeline.validate DIR``: check every clip under DIR; exit 1 on any violation.

Also prints, per clip, quality findings that do not fail the run (queries hidden at their own
query frame, tracks visible off the image or behind the camera, flickering tracks); ``--report
FILE`` writes the same table as JSON.
"""

from __future__ import annotations

import argparse
import json
import sys

from pipeline.export.clip_reader import add_limit_argument, limits_from
from pipeline.export.files import list_files, read_bytes, write_atomic
from pipeline.export.validator import FINDINGS, FLICKER_MAX_FRACTION, NO_FINDINGS, inspect_clip_bytes


def findings_table(rows: list[dict]) -> str:
    """Plain-text table: clip, tracks, then one column per finding ('-' where it could not be looked at)."""
    header = ("clip", "tracks", *FINDINGS)
    cells = [header] + [tuple("-" if row[key] is None else str(row[key]) for key in header) for row in rows]
    widths = [max(len(line[i]) for line in cells) for i in range(len(header))]
    return "\n".join(
        "  ".join(cell.ljust(width) for cell, width in zip(line, widths, strict=True)) for line in cells
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m pipeline.validate", description=__doc__)
    parser.add_argument("directory", help="an output folder (<out>/<source>/*.npz) or a folder of clips")
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
    root = args.directory.rstrip("/")
    paths = list_files(f"{root}/*.npz") + list_files(f"{root}/*/*.npz")
    if not paths:
        print(f"no .npz clips under {root}", file=sys.stderr)
        return 1
    bad = 0
    rows = []
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
    sys.exit(main())
