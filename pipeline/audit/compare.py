"""``python -m pipeline.audit compare REF_DIR NEW_DIR [--out PREFIX]``: TAPVid-3D metrics of NEW against REF.

Clips are matched by ``<source>/<clip>.npz``; NEW's tracks are the prediction, REF's the ground
truth, and tracks correspond by index. Per clip: 3D-AJ and APD under each rescaling of
``pipeline.audit.metrics.SCALINGS``, OA (which is the visibility agreement: the fraction of
(frame, track) pairs whose two visibility flags agree) and the median 3D error in metres. Per source
and over all sources: means over the scored clips. Writes ``PREFIX.md`` and ``PREFIX.json``
(default prefix ``NEW_DIR/compare``). Nothing is unpickled and every size is bounded
(``pipeline.export.clip_reader``); the frame size that sets the evaluation scale comes from the
first JPEG's header. Every clip that cannot be scored is named with the reason; the command exits 1
when none could be.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys

import numpy as np

from pipeline.audit.metrics import SCALINGS, eval_intrinsics, median_error, tapvid3d_metrics
from pipeline.core.images import jpeg_size
from pipeline.export.clip_reader import (
    DEFAULT_LIMITS,
    FRAMES,
    ReadLimits,
    add_limit_argument,
    limits_from,
    read_clip_file,
)
from pipeline.export.files import is_local, list_files, write_atomic
from pipeline.export.npz_reader import NpzError

NUMERIC_KEYS = ("queries_xyt", "tracks_XYZ", "visibility", "fx_fy_cx_cy")
SUMMARY_KEYS = (
    *(f"{key}_{scaling}" for scaling in SCALINGS for key in ("aj", "apd")),
    "oa",
    "median_error_m",
)


class ClipError(Exception):
    """A clip pair that cannot be scored (unreadable, missing keys, different N or T)."""


def clip_keys(root: str) -> dict[str, str]:
    """``<source>/<clip>.npz`` -> path, for every clip under ``root/<source>/``."""
    paths = list_files(f"{root.rstrip('/')}/*/*.npz")
    return {"/".join(path.replace("\\", "/").split("/")[-2:]): path for path in paths}


def read_members(path: str, keys: tuple[str, ...], limits: ReadLimits) -> dict[str, np.ndarray]:
    """The members ``keys`` of a clip, read with ``pipeline.export.clip_reader`` (nothing unpickled,
    sizes bounded by the clip's T and N); ClipError naming the file when one is missing or refused."""
    try:
        arrays = read_clip_file(path, limits, keys)
    except NpzError as error:
        raise ClipError(str(error)) from error
    missing = [key for key in keys if key not in arrays]
    if missing:
        raise ClipError(f"{path}: missing {missing}")
    return arrays


def read_reference(path: str, limits: ReadLimits) -> tuple[dict[str, np.ndarray], tuple[int, int]]:
    """REF's numeric arrays and its frame (height, width), from the first JPEG's header."""
    arrays = read_members(path, (*NUMERIC_KEYS, FRAMES), limits)
    frames = arrays.pop(FRAMES)
    readable = frames.dtype.kind == "S" and frames.ndim == 1 and len(frames)
    size = jpeg_size(bytes(frames[0])) if readable else None
    if size is None:
        raise ClipError(f"{path}: no readable JPEG header in the first frame")
    return arrays, size


def compare_clip(ref: dict[str, np.ndarray], new: dict[str, np.ndarray], height: int, width: int) -> dict:
    """Metrics of NEW's tracks [T, N, 3] / visibility [T, N] against REF's (REF's queries and intrinsics)."""
    gt_tracks, pred_tracks = ref["tracks_XYZ"], new["tracks_XYZ"]
    gt_visible, pred_visible = ref["visibility"].astype(bool), new["visibility"].astype(bool)
    if gt_tracks.shape != pred_tracks.shape or gt_visible.shape != pred_visible.shape:
        raise ClipError(
            f"shapes differ: REF tracks {gt_tracks.shape} visibility {gt_visible.shape}, "
            f"NEW tracks {pred_tracks.shape} visibility {pred_visible.shape}"
        )
    num_frames, num_tracks = gt_visible.shape
    query_frames = np.round(ref["queries_xyt"][:, 2]).astype(np.int64)
    if query_frames.shape != (num_tracks,) or not ((query_frames >= 0) & (query_frames < num_frames)).all():
        raise ClipError("REF query frames are not frame indices of its tracks")
    intrinsics = eval_intrinsics(ref["fx_fy_cx_cy"], height, width)
    row = {"frames": num_frames, "tracks": num_tracks}
    for scaling in SCALINGS:
        scores = tapvid3d_metrics(
            gt_tracks, gt_visible, pred_tracks, pred_visible, intrinsics, query_frames, scaling
        )
        row[f"aj_{scaling}"] = scores["average_jaccard"]
        row[f"apd_{scaling}"] = scores["average_pts_within"]
    row["oa"] = scores["occlusion_accuracy"]
    row["median_error_m"] = median_error(gt_tracks, gt_visible, pred_tracks)
    return row


def score_pair(key: str, ref_path: str, new_path: str, limits: ReadLimits = DEFAULT_LIMITS) -> dict:
    """One per-clip row: metrics, or ``error`` saying why the pair could not be scored. NEW is read
    for its prediction only (``tracks_XYZ``, ``visibility``)."""
    source, clip = key.split("/")
    try:
        ref, (height, width) = read_reference(ref_path, limits)
        new = read_members(new_path, ("tracks_XYZ", "visibility"), limits)
        return {"source": source, "clip": clip, **compare_clip(ref, new, height, width)}
    except ClipError as error:
        return {"source": source, "clip": clip, "error": str(error)}


def mean_row(rows: list[dict], source: str) -> dict:
    """Means over the scored clips of ``rows`` (NaN-valued clips skipped per metric)."""
    scored = [row for row in rows if "error" not in row]
    summary = {"source": source, "clips": len(scored), "errors": len(rows) - len(scored)}
    for key in SUMMARY_KEYS:
        values = [row[key] for row in scored if math.isfinite(row[key])]
        summary[key] = float(np.mean(values)) if values else float("nan")
    return summary


def summarise(rows: list[dict]) -> list[dict]:
    """One row per source, then ``all``: the mean of the source means (as the official evaluation)."""
    sources = sorted({row["source"] for row in rows})
    per_source = [mean_row([row for row in rows if row["source"] == source], source) for source in sources]
    overall = {"source": "all", "clips": sum(r["clips"] for r in per_source)}
    overall["errors"] = sum(r["errors"] for r in per_source)
    for key in SUMMARY_KEYS:
        values = [r[key] for r in per_source if math.isfinite(r[key])]
        overall[key] = float(np.mean(values)) if values else float("nan")
    return [*per_source, overall]


def json_ready(value):
    """``value`` with every non-finite float replaced by None (strict JSON has no NaN)."""
    if isinstance(value, dict):
        return {key: json_ready(item) for key, item in value.items()}
    if isinstance(value, list):
        return [json_ready(item) for item in value]
    return None if isinstance(value, float) and not math.isfinite(value) else value


def _cell(value) -> str:
    return f"{value:.4f}" if isinstance(value, float) else str(value)


def markdown(report: dict) -> str:
    """The report as markdown: per-source table, per-clip table, unmatched clips."""
    header = " | ".join(SUMMARY_KEYS)
    lines = [
        f"# TAPVid-3D metrics of `{report['new']}` against `{report['ref']}`",
        "",
        "aj/apd = 3D-AJ/APD under median, per-trajectory and no rescaling; oa = occlusion accuracy "
        "(= visibility agreement); median_error_m = unscaled median 3D error over REF-visible points.",
        "",
        f"| source | clips | errors | {header} |",
        "|" + "---|" * (3 + len(SUMMARY_KEYS)),
    ]
    for row in report["sources"]:
        cells = [row["source"], row["clips"], row["errors"], *(row[key] for key in SUMMARY_KEYS)]
        lines.append("| " + " | ".join(_cell(c) for c in cells) + " |")
    lines += ["", f"| source | clip | frames | tracks | {header} | error |"]
    lines.append("|" + "---|" * (5 + len(SUMMARY_KEYS)))
    for row in report["clips"]:
        metrics = [row.get(key, "") for key in SUMMARY_KEYS]
        cells = [row["source"], row["clip"], row.get("frames", ""), row.get("tracks", ""), *metrics]
        lines.append("| " + " | ".join(_cell(c) for c in [*cells, row.get("error", "")]) + " |")
    for side in ("only_in_ref", "only_in_new"):
        if report[side]:
            lines += ["", f"{side}: {len(report[side])} clip(s): " + ", ".join(report[side])]
    return "\n".join(lines) + "\n"


def compare_dirs(ref_dir: str, new_dir: str, limits: ReadLimits = DEFAULT_LIMITS) -> dict:
    """The full report (JSON-ready) of NEW_DIR's clips against REF_DIR's."""
    ref, new = clip_keys(ref_dir), clip_keys(new_dir)
    common = sorted(ref.keys() & new.keys())
    rows = [score_pair(key, ref[key], new[key], limits) for key in common]
    return {
        "ref": ref_dir,
        "new": new_dir,
        "clips": rows,
        "sources": summarise(rows),
        "only_in_ref": sorted(ref.keys() - new.keys()),
        "only_in_new": sorted(new.keys() - ref.keys()),
    }


def main(argv: list[str] | None = None) -> int:
    """The ``compare`` subcommand; exit 1 when no clip could be scored (none in common, or every
    pair unreadable), 2 on bad arguments or folders. Each unscored clip is named on stderr."""
    parser = argparse.ArgumentParser(prog="python -m pipeline.audit compare", description=__doc__)
    parser.add_argument("ref_dir", help="reference output folder (<dir>/<source>/<clip>.npz): ground truth")
    parser.add_argument("new_dir", help="output folder to score as the prediction")
    parser.add_argument("--out", help="write OUT.md and OUT.json (default NEW_DIR/compare)")
    add_limit_argument(parser)
    args = parser.parse_args(argv)
    try:
        limits = limits_from(args.limit)
    except ValueError as error:
        parser.error(str(error))
    for folder in (args.ref_dir, args.new_dir):
        if is_local(folder) and not os.path.isdir(folder):
            print(f"compare: {folder} is not a folder", file=sys.stderr)
            return 2
    report = compare_dirs(args.ref_dir.rstrip("/"), args.new_dir.rstrip("/"), limits)
    text = markdown(report)
    print(text, end="")
    prefix = args.out or f"{args.new_dir.rstrip('/')}/compare"
    try:
        write_atomic(f"{prefix}.md", text.encode())
        write_atomic(f"{prefix}.json", json.dumps(json_ready(report), indent=1, allow_nan=False).encode())
    except OSError as error:
        print(f"compare: cannot write the report {prefix}.md/.json: {error}", file=sys.stderr)
        return 2
    unscored = [row for row in report["clips"] if "error" in row]
    for row in unscored:
        print(f"not scored: {row['source']}/{row['clip']}: {row['error']}", file=sys.stderr)
    if not report["clips"]:
        print(f"no clip in common between {args.ref_dir} and {args.new_dir}", file=sys.stderr)
        return 1
    if len(unscored) == len(report["clips"]):
        print(f"none of the {len(unscored)} clip(s) in common could be scored", file=sys.stderr)
        return 1
    return 0
