"""A release run's verdict rows (``<out>/release_<source>.jsonl``) as the audit commands read them,
and as ``audit compare`` amends them: the release clips to score when the reference cannot be
listed, and each clip's agreement with the reference, added to its row and summed up per split."""

from __future__ import annotations

import json
import os

from pipeline import sources
from pipeline.core.outcomes import FILTER_ORDER
from pipeline.export.layout import release_verdicts_path
from pipeline.io.files import read_bytes, write_atomic
from pipeline.runner.splits import SPLITS
from pipeline.runner.verdicts import STATUSES

MAX_VERDICT_BYTES = 256 << 20
# The fields of a verdict row (``pipeline.runner.verdicts.Verdict``) the audit commands read.
ROW_FIELDS = ("clip", "split", "status", "tracks", "reason", "candidates", "dropped", "passed")


def read_verdicts(output: str, source: str) -> list[dict] | None:
    """The verdict rows of ``source`` in ``output``, None when the run wrote none."""
    path = release_verdicts_path(output, source)
    if not os.path.exists(path) and "://" not in output:
        return None
    rows = []
    for number, line in enumerate(read_bytes(path, MAX_VERDICT_BYTES).decode().splitlines(), 1):
        try:
            row = json.loads(line)
            if row["status"] not in STATUSES or row["split"] not in SPLITS:
                raise ValueError(f"status {row['status']!r}, split {row['split']!r}")
            missing = [key for key in ROW_FIELDS if key not in row] + [
                f"dropped {name}" for name in FILTER_ORDER if name not in row["dropped"]
            ]
            if missing:
                raise ValueError(f"no {', '.join(missing)}")
        except (ValueError, KeyError, TypeError) as error:
            raise ValueError(f"{path} line {number}: not a release verdict ({error})") from None
        rows.append(row)
    return rows

# What a verdict row's ``agreement`` holds of a compare row, when the compare scored the clip.
AGREEMENT_FIELDS = ("query_frames_equal", "visibility", "median_mm", "p95_mm", "agrees", "aj_median", "oa")


def release_clip_keys(output: str) -> list[str] | None:
    """``<source>/<clip>.npz`` of every release clip a run in ``output`` has a verdict on (sources in
    the registry's order, clips as sorted in each file); None when it has none."""
    keys, found = [], False
    for source in sources.names():
        rows = read_verdicts(output, source)
        if rows is not None:
            found = True
            keys += [f"{source}/{row['clip']}.npz" for row in rows]
    return keys if found else None


def agreement_entry(row: dict, agree_mm: float) -> dict:
    """A verdict row's ``agreement`` from a compare row: its status (scored, zero: no clip of ours to
    score, ref_error, not_in_ref), the agreement and two of tapnet's metrics when scored, else why."""
    entry = {"status": row["status"], "agree_mm": agree_mm}
    if row["status"] == "scored":
        return entry | {key: _plain(row[key]) for key in AGREEMENT_FIELDS}
    return entry | {"error": row.get("error", "")}


def _plain(value):
    """A JSON value: NaN as None."""
    return None if isinstance(value, float) and value != value else value


def add_agreement(output: str, rows: list[dict], agree_mm: float) -> list[str]:
    """Rewrite each verdict file of ``output`` with the ``agreement`` of every clip ``rows`` (compare
    rows) scored or tried; the files rewritten. A row without a compare row keeps no agreement."""
    updated = []
    for source in sources.names():
        verdicts = read_verdicts(output, source)
        if verdicts is None:
            continue
        compared = {row["clip"].removesuffix(".npz"): row for row in rows if row["source"] == source}
        for verdict in verdicts:
            verdict.pop("agreement", None)
            if verdict["clip"] in compared:
                verdict["agreement"] = agreement_entry(compared[verdict["clip"]], agree_mm)
        text = "".join(json.dumps(verdict, sort_keys=True) + "\n" for verdict in verdicts)
        path = release_verdicts_path(output, source)
        write_atomic(path, text.encode())
        updated.append(path)
    return updated


LEAST_SHOWN = 5


def agreement_summary(rows: list[dict]) -> dict | None:
    """Per split (and ``all``): release clips, clips scored against the reference, those that agree
    fully, those the reference does not hold; and the ``LEAST_SHOWN`` least-agreeing scored clips
    (lowest visibility agreement, then largest p95 distance). None when no row has an agreement
    (``audit compare`` has not run on this run)."""
    compared = [row for row in rows if "agreement" in row]
    if not compared:
        return None
    per_split = []
    for split in (*SPLITS, "all"):
        chosen = [row for row in rows if split in ("all", row["split"])]
        entries = [row["agreement"] for row in chosen if "agreement" in row]
        per_split.append(
            {
                "split": split,
                "clips": len(chosen),
                "scored": sum(entry["status"] == "scored" for entry in entries),
                "agree": sum(bool(entry.get("agrees")) for entry in entries),
                "not_in_ref": sum(entry["status"] == "not_in_ref" for entry in entries),
            }
        )
    short = [row["agreement"] | row for row in compared if row["agreement"]["status"] == "scored"]
    short = [row for row in short if not row["agrees"]]
    short.sort(key=lambda row: (_number(row["visibility"]), -_number(row["p95_mm"])))
    least = [{key: row[key] for key in ("clip", "split", *LEAST_FIELDS)} for row in short[:LEAST_SHOWN]]
    return {"agree_mm": compared[0]["agreement"]["agree_mm"], "splits": per_split, "least": least}


LEAST_FIELDS = ("query_frames_equal", "visibility", "median_mm", "p95_mm")


def _number(value) -> float:
    return float("nan") if value is None else float(value)


def agreement_lines(summary: dict) -> list[str]:
    """``agreement_summary`` as the lines ``audit release`` prints."""
    lines = [
        f"  agreement with the reference (audit compare; agree fully: the same query frames and "
        f"visibility, tracks within {summary['agree_mm']:g} mm at p95):",
        f"  {'split':<10}{'clips':>7}{'scored':>8}{'agree fully':>13}{'not in reference':>18}",
    ]
    for row in summary["splits"]:
        counts = f"{row['clips']:>7}{row['scored']:>8}{row['agree']:>13}{row['not_in_ref']:>18}"
        lines.append(f"  {row['split']:<10}{counts}")
    if summary["least"]:
        lines.append("  least agreeing (query frames equal, visibility, median mm, p95 mm):")
        for row in summary["least"]:
            values = ", ".join("-" if row[key] is None else f"{row[key]:.4g}" for key in LEAST_FIELDS)
            lines.append(f"    {row['clip']} ({row['split']}): {values}")
    return lines
