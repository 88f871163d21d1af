"""``python -m pipeline.audit release OUT``: the release verdicts of a run, per source and split.

Reads ``<OUT>/release_<source>.jsonl`` (written by a ``--release`` run) and prints, per source, a
table of the verdicts per split (written, not produced, input absent, failed), the most common
reasons of each status (numbers and names folded so that alike reasons count together), then a row
per clip: its verdict, the tracks each filter dropped (never_visible, flicker, mask) and its reason.
"""

from __future__ import annotations

import sys
from collections import Counter
from collections.abc import Callable

from pipeline import sources
from pipeline.audit.verdict_rows import VerdictRow, agreement_lines, agreement_summary, read_verdicts
from pipeline.commandline import StrictParser
from pipeline.core.outcomes import FILTER_ORDER, reason_kind
from pipeline.runner.splits import SPLITS
from pipeline.runner.verdicts import STATUSES, Verdict

SHOWN_REASONS = 3
# The per-clip table's columns: header, and the cell of a verdict. The reason comes last.
CLIP_COLUMNS: tuple[tuple[str, Callable[[Verdict], object]], ...] = (
    ("clip", lambda row: row.clip),
    ("split", lambda row: row.split),
    ("status", lambda row: row.status),
    ("tracks", lambda row: row.tracks),
    ("candidates", lambda row: row.candidates),
    *((name, lambda row, name=name: row.dropped[name]) for name in FILTER_ORDER),
    ("passed", lambda row: row.passed),
    ("reason", lambda row: row.reason),
)


def clip_table(rows: list[Verdict]) -> str:
    """A row per clip (``CLIP_COLUMNS``), columns padded to their widest cell, numbers to the right."""
    cells: list[list[object]] = [[header for header, _ in CLIP_COLUMNS]]
    cells += [[cell(row) for _, cell in CLIP_COLUMNS] for row in rows]
    padded = len(CLIP_COLUMNS) - 1
    widths = [max(len(str(line[i])) for line in cells) for i in range(padded)]
    numeric = [all(isinstance(line[i], int) for line in cells[1:]) for i in range(padded)]

    def shown(line: list) -> str:
        fields = [f"{line[i]:{'>' if numeric[i] else '<'}{widths[i]}}" for i in range(padded)]
        return "  ".join([*fields, str(line[-1])])

    return "\n".join(map(shown, cells))


def source_table(source: str, verdict_rows: list[VerdictRow]) -> str:
    """The verdicts of one source per split, then the most common reasons of each status."""
    rows = [row.verdict for row in verdict_rows]
    header = f"{'split':<10}{'named':>7}" + "".join(f"{status:>14}" for status in STATUSES)
    lines = [f"{source}: {len(rows)} release clip(s)", header]
    for split in (*SPLITS, "all"):
        chosen = [row for row in rows if split in ("all", row.split)]
        counts = Counter(row.status for row in chosen)
        lines.append(f"{split:<10}{len(chosen):>7}" + "".join(f"{counts[s]:>14}" for s in STATUSES))
    for status in STATUSES[1:] + STATUSES[:1]:
        kinds = Counter(reason_kind(row.reason) for row in rows if row.status == status)
        if not kinds:
            continue
        lines.append(f"  {status}, most common reasons:")
        for kind, count in kinds.most_common(SHOWN_REASONS):
            example = next(row for row in rows if row.status == status and reason_kind(row.reason) == kind)
            lines.append(f"    {count:>6} x {kind}   (e.g. {example.clip}: {example.reason})")
    lines += [f"  per clip: tracks dropped by each filter ({', '.join(FILTER_ORDER)})", clip_table(rows)]
    agreement = agreement_summary(verdict_rows)
    if agreement is not None:
        lines += agreement_lines(agreement)
    return "\n".join(lines)


def main(argv: list[str]) -> int:
    parser = StrictParser(prog="python -m pipeline.audit release", description=__doc__)
    parser.add_argument("output", help="the output folder of a --release run")
    parser.add_argument(
        "--source", choices=sources.names(), help="one source (default: every one with verdicts)"
    )
    args = parser.parse_args(argv)
    chosen = [args.source] if args.source else list(sources.names())
    found = 0
    for source in chosen:
        try:
            rows = read_verdicts(args.output, source)
        except (OSError, ValueError) as error:
            print(f"release: {error}", file=sys.stderr)
            return 2
        if rows is None:
            continue
        found += 1
        print(source_table(source, rows) + "\n")
    if not found:
        print(
            f"release: no release_<source>.jsonl in {args.output}: run python -m pipeline.run --release "
            "SPLITS_JSON first",
            file=sys.stderr,
        )
        return 2
    return 0
