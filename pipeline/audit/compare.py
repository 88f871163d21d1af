"""``python -m pipeline.audit compare REF_DIR NEW_DIR [--clips LIST] [--out PREFIX]``: TAPVid-3D
metrics of NEW against REF, scored as tapnet's ``tapvid3d/evaluation/evaluate_model.py`` scores them.

Clips are matched by ``<source>/<clip>.npz``; REF's clips (or those named in ``--clips``, one
``<source>/<clip>.npz`` a line, e.g. a run's ``manifests/minival.txt``: tapnet's ``use_minival``)
are the benchmark, NEW's ``tracks_XYZ`` and ``visibility`` the prediction (other members are
ignored, so a file holding only those two is scored); tracks correspond by index. Per clip: 3D-AJ
and APD under each rescaling of ``pipeline.audit.metrics.SCALINGS``, OA (the visibility agreement)
and the median 3D error in metres (not a tapnet metric). As in tapnet:

- a REF clip whose prediction is missing, unreadable, refused or of another shape counts with
  every metric 0 (status ``zero``, named with the reason); under per-trajectory rescaling, so does
  a clip whose REF query frames are no frame indices;
- per source, each metric is the plain mean over its clips, whatever their length (a NaN metric,
  from a REF clip with no visible point, makes the mean NaN); ``all`` is the mean of the source means.

The median error is averaged over the clips whose prediction was read. A REF clip that cannot be
read (tapnet's evaluator would stop there) is named and left out of the means (status
``ref_error``). Writes ``PREFIX.md`` and ``PREFIX.json`` (default prefix ``NEW_DIR/compare``).
Nothing is unpickled and every size is bounded (``pipeline.io.clip_reader``): a prediction's
members may hold no more than REF's T frames and N tracks need. The frame size that sets the
evaluation scale comes from REF's first JPEG header.

Each clip counted as 0 or left out is named on stderr (``not scored: <source>/<clip>: <why>``).
Exit status: 0 when at least one prediction was scored (the means are tapnet's when the report
has no ``ref_error``); 1 when nothing could be scored (no REF clip, or no prediction scored);
2 on bad arguments, a missing folder, an unreadable ``--clips`` list or a report that cannot be
written.
"""

from __future__ import annotations

import json
import math
import os
import re
import sys

import numpy as np

from pipeline import sources as registry
from pipeline.audit.metrics import (
    SCALINGS,
    eval_intrinsics,
    median_error,
    query_frame_indices,
    tapvid3d_metrics,
)
from pipeline.commandline import StrictParser
from pipeline.core.images import jpeg_size
from pipeline.io.clip_reader import (
    DEFAULT_LIMITS,
    FRAMES,
    ReadLimits,
    add_limit_argument,
    limits_from,
    member_caps,
    read_clip_file,
)
from pipeline.io.files import is_local, list_files, read_bytes, write_atomic
from pipeline.io.npz_reader import NpzArchive, NpzError

NUMERIC_KEYS = ("queries_xyt", "tracks_XYZ", "visibility", "fx_fy_cx_cy")
PREDICTION_KEYS = ("tracks_XYZ", "visibility")
TAPNET_KEYS = (*(f"{key}_{scaling}" for scaling in SCALINGS for key in ("aj", "apd")), "oa")
SUMMARY_KEYS = (*TAPNET_KEYS, "median_error_m")
CLIP_ENTRY = re.compile(r"[^/\s]+/[^/\s]+\.npz")
MAX_LIST_BYTES = 16 << 20


class ClipError(Exception):
    """A clip that cannot be read or scored, with the reason."""


def clip_keys(root: str) -> dict[str, str]:
    """``<source>/<clip>.npz`` -> path, for every clip under ``root/<source>/``."""
    paths = list_files(f"{root.rstrip('/')}/*/*.npz")
    return {"/".join(path.replace("\\", "/").split("/")[-2:]): path for path in paths}


def read_clip_list(path: str) -> list[str]:
    """The ``<source>/<clip>.npz`` entries of a list file, one a line, in its order (blank lines
    and repeats skipped); ValueError naming a malformed line, OSError when unreadable."""
    lines = read_bytes(path, MAX_LIST_BYTES).decode("utf-8", errors="replace").splitlines()
    entries = [line.strip() for line in lines if line.strip()]
    malformed = [entry for entry in entries if not CLIP_ENTRY.fullmatch(entry)]
    if malformed:
        raise ValueError(f"{path}: {malformed[0]!r} is not <source>/<clip>.npz")
    return list(dict.fromkeys(entries))


def check_numbers(path: str, arrays: dict[str, np.ndarray], keys: tuple[str, ...]) -> None:
    """ClipError when one of ``keys`` holds bytes (no arithmetic applies to them)."""
    strings = [key for key in keys if arrays[key].dtype.kind == "S"]
    if strings:
        raise ClipError(f"{path}: {strings} hold bytes, not numbers")


def read_reference(path: str, limits: ReadLimits) -> tuple[dict[str, np.ndarray], tuple[int, int]]:
    """REF's numeric arrays, checked to be a clip's tracks [T, N, 3], visibility [T, N] and
    intrinsics [4], and its frame (height, width) from the first JPEG's header."""
    try:
        arrays = read_clip_file(path, limits, (*NUMERIC_KEYS, FRAMES))
    except NpzError as error:
        raise ClipError(str(error)) from error
    missing = [key for key in (*NUMERIC_KEYS, FRAMES) if key not in arrays]
    if missing:
        raise ClipError(f"{path}: missing {missing}")
    check_numbers(path, arrays, NUMERIC_KEYS)
    tracks, visible = arrays["tracks_XYZ"], arrays["visibility"]
    if tracks.ndim != 3 or tracks.shape[2] != 3 or visible.shape != tracks.shape[:2]:
        raise ClipError(
            f"{path}: tracks_XYZ {tracks.shape} and visibility {visible.shape} are not [T, N, 3], [T, N]"
        )
    if arrays["fx_fy_cx_cy"].shape != (4,):
        raise ClipError(f"{path}: fx_fy_cx_cy has shape {arrays['fx_fy_cx_cy'].shape}, not [4]")
    frames = arrays.pop(FRAMES)
    readable = frames.dtype.kind == "S" and frames.ndim == 1 and len(frames)
    size = jpeg_size(bytes(frames[0])) if readable else None
    if size is None:
        raise ClipError(f"{path}: no readable JPEG header in the first frame")
    return arrays, size


def read_prediction(path: str, num_frames: int, num_tracks: int, limits: ReadLimits) -> dict[str, np.ndarray]:
    """NEW's ``tracks_XYZ`` and ``visibility``, each refused before reading when it claims more
    than REF's T frames and N tracks need; ClipError saying why it cannot be read."""
    caps = member_caps(num_frames, num_tracks, limits)
    why = f"REF's clip has T = {num_frames} frames and N = {num_tracks} tracks"
    try:
        archive = NpzArchive(read_bytes(path, limits.max_file_bytes), path)
        missing = [key for key in PREDICTION_KEYS if key not in archive.keys]
        if missing:
            raise ClipError(f"{path}: missing {missing}")
        arrays = {key: archive.read(key, caps[key], why) for key in PREDICTION_KEYS}
    except OSError as error:
        raise ClipError(f"{path}: cannot be read ({error.strerror or error})") from error
    except NpzError as error:
        raise ClipError(str(error)) from error
    check_numbers(path, arrays, PREDICTION_KEYS)
    return arrays


def compare_clip(ref: dict[str, np.ndarray], new: dict[str, np.ndarray], height: int, width: int) -> dict:
    """Metrics of NEW's tracks [T, N, 3] / visibility [T, N] against REF's (REF's queries and
    intrinsics); ClipError when the shapes differ. ``note`` says when per-trajectory scored 0."""
    gt_tracks, pred_tracks = ref["tracks_XYZ"], new["tracks_XYZ"]
    gt_visible, pred_visible = ref["visibility"].astype(bool), new["visibility"].astype(bool)
    if gt_tracks.shape != pred_tracks.shape or gt_visible.shape != pred_visible.shape:
        raise ClipError(
            f"shapes differ: REF tracks {gt_tracks.shape} visibility {gt_visible.shape}, "
            f"NEW tracks {pred_tracks.shape} visibility {pred_visible.shape}"
        )
    num_frames, num_tracks = gt_visible.shape
    queries = ref["queries_xyt"]
    query_frames = (
        query_frame_indices(queries[:, 2], num_frames) if queries.shape == (num_tracks, 3) else None
    )
    intrinsics = eval_intrinsics(ref["fx_fy_cx_cy"], height, width)
    row = {}
    for scaling in SCALINGS:
        if scaling == "per_trajectory" and query_frames is None:
            row |= {"aj_per_trajectory": 0.0, "apd_per_trajectory": 0.0}
            row["note"] = "REF query frames are not frame indices: per_trajectory counted as 0"
            continue
        scores = tapvid3d_metrics(
            gt_tracks, gt_visible, pred_tracks, pred_visible, intrinsics, query_frames, scaling
        )
        row[f"aj_{scaling}"] = scores["average_jaccard"]
        row[f"apd_{scaling}"] = scores["average_pts_within"]
        if scaling == "median":
            row["oa"] = scores["occlusion_accuracy"]
    row["median_error_m"] = median_error(gt_tracks, gt_visible, pred_tracks)
    return row


def zero_row(error: str) -> dict:
    """A clip counted as tapnet's ``evaluate_model.py`` counts one it cannot score: every metric 0."""
    return {"status": "zero", "error": error, **dict.fromkeys(TAPNET_KEYS, 0.0), "median_error_m": math.nan}


def score_pair(
    key: str, ref_path: str | None, new_path: str | None, limits: ReadLimits = DEFAULT_LIMITS
) -> dict:
    """One per-clip row: status ``scored`` with the metrics, ``zero`` (the prediction is missing,
    unreadable or of another shape: every tapnet metric 0) or ``ref_error`` (REF unreadable)."""
    source, clip = key.split("/")
    try:
        if ref_path is None:
            raise ClipError("not in REF")
        ref, (height, width) = read_reference(ref_path, limits)
    except ClipError as error:
        return {"source": source, "clip": clip, "status": "ref_error", "error": str(error)}
    num_frames, num_tracks = ref["visibility"].shape
    row = {"source": source, "clip": clip, "frames": num_frames, "tracks": num_tracks}
    if new_path is None:
        return row | zero_row("no prediction file")
    try:
        new = read_prediction(new_path, num_frames, num_tracks, limits)
        return row | {"status": "scored", **compare_clip(ref, new, height, width)}
    except ClipError as error:
        return row | zero_row(str(error))


def plain_mean(values: list[float]) -> float:
    """np.mean of ``values`` (a NaN propagates, as in tapnet's averages); NaN when empty."""
    return float(np.mean(values)) if values else math.nan


def mean_row(rows: list[dict], source: str) -> dict:
    """Means over the clips of ``rows`` counted by tapnet (scored and zero); the median error over
    the scored ones."""
    counted = [row for row in rows if row["status"] != "ref_error"]
    scored = [row for row in counted if row["status"] == "scored"]
    summary = {"source": source, "clips": len(counted), "zero": len(counted) - len(scored)}
    summary["ref_errors"] = len(rows) - len(counted)
    for key in TAPNET_KEYS:
        summary[key] = plain_mean([row[key] for row in counted])
    summary["median_error_m"] = plain_mean([row["median_error_m"] for row in scored])
    return summary


def summarise(rows: list[dict]) -> list[dict]:
    """One row per source (the registry's order, tapnet's for the built-in sources; then others
    sorted), then ``all``: the mean of the source means (as tapnet's ``main``) over the sources with a
    counted clip."""
    present = {row["source"] for row in rows}
    order = registry.names()
    sources = [s for s in order if s in present] + sorted(present - set(order))
    per_source = [mean_row([row for row in rows if row["source"] == source], source) for source in sources]
    overall = {
        "source": "all",
        **{key: sum(r[key] for r in per_source) for key in ("clips", "zero", "ref_errors")},
    }
    for key in TAPNET_KEYS:
        overall[key] = plain_mean([r[key] for r in per_source if r["clips"]])
    overall["median_error_m"] = plain_mean(
        [r["median_error_m"] for r in per_source if r["clips"] > r["zero"]]
    )
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
    """The report as markdown: per-source table, per-clip table, clips only in NEW."""
    header = " | ".join(SUMMARY_KEYS)
    lines = [
        f"# TAPVid-3D metrics of `{report['new']}` against `{report['ref']}`",
        "",
        "aj/apd = 3D-AJ/APD under median, per-trajectory and no rescaling; oa = occlusion accuracy "
        "(= visibility agreement); means over clips as tapnet's evaluate_model.py, a clip whose "
        "prediction is missing or unreadable counting 0 (status zero); median_error_m = unscaled "
        "median 3D error over REF-visible points (not a tapnet metric; scored clips only).",
        "",
        f"| source | clips | zero | ref_errors | {header} |",
        "|" + "---|" * (4 + len(SUMMARY_KEYS)),
    ]
    for row in report["sources"]:
        cells = [
            row["source"],
            row["clips"],
            row["zero"],
            row["ref_errors"],
            *(row[key] for key in SUMMARY_KEYS),
        ]
        lines.append("| " + " | ".join(_cell(c) for c in cells) + " |")
    lines += ["", f"| source | clip | status | frames | tracks | {header} | error |"]
    lines.append("|" + "---|" * (6 + len(SUMMARY_KEYS)))
    for row in report["clips"]:
        metrics = [row.get(key, "") for key in SUMMARY_KEYS]
        cells = [
            row["source"],
            row["clip"],
            row["status"],
            row.get("frames", ""),
            row.get("tracks", ""),
            *metrics,
        ]
        why = row.get("error", row.get("note", ""))
        lines.append("| " + " | ".join(_cell(c) for c in [*cells, why]) + " |")
    if report["only_in_new"]:
        lines += [
            "",
            f"only_in_new (not scored): {len(report['only_in_new'])} clip(s): "
            + ", ".join(report["only_in_new"]),
        ]
    return "\n".join(lines) + "\n"


def compare_dirs(
    ref_dir: str, new_dir: str, limits: ReadLimits = DEFAULT_LIMITS, clips: list[str] | None = None
) -> dict:
    """The full report (JSON-ready) of NEW_DIR's clips against REF_DIR's (sorted), or against the
    entries ``clips`` (``<source>/<clip>.npz``) of REF_DIR in their order (each mean sums its clips
    in that order, as tapnet sums a split's)."""
    ref, new = clip_keys(ref_dir), clip_keys(new_dir)
    benchmark = sorted(ref) if clips is None else clips
    rows = [score_pair(key, ref.get(key), new.get(key), limits) for key in benchmark]
    return {
        "ref": ref_dir,
        "new": new_dir,
        "clips": rows,
        "sources": summarise(rows),
        "only_in_new": sorted(new.keys() - set(benchmark)),
    }


def main(argv: list[str] | None = None) -> int:
    """The ``compare`` subcommand; exit status as the module doc says."""
    parser = StrictParser(prog="python -m pipeline.audit compare", description=__doc__)
    parser.add_argument("ref_dir", help="reference output folder (<dir>/<source>/<clip>.npz): ground truth")
    parser.add_argument("new_dir", help="output folder to score as the prediction")
    parser.add_argument("--clips", help="score only these REF clips (a file of <source>/<clip>.npz lines)")
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
    try:
        clips = None if args.clips is None else read_clip_list(args.clips)
    except (OSError, ValueError) as error:
        print(f"compare: cannot use --clips {args.clips}: {error}", file=sys.stderr)
        return 2
    report = compare_dirs(args.ref_dir.rstrip("/"), args.new_dir.rstrip("/"), limits, clips)
    text = markdown(report)
    print(text, end="")
    prefix = args.out or f"{args.new_dir.rstrip('/')}/compare"
    try:
        write_atomic(f"{prefix}.md", text.encode())
        write_atomic(f"{prefix}.json", json.dumps(json_ready(report), indent=1, allow_nan=False).encode())
    except OSError as error:
        print(f"compare: cannot write the report {prefix}.md/.json: {error}", file=sys.stderr)
        return 2
    rows = report["clips"]
    for row in rows:
        if row["status"] == "zero":
            print(
                f"not scored: {row['source']}/{row['clip']}: {row['error']} (counted as 0)", file=sys.stderr
            )
        elif row["status"] == "ref_error":
            print(
                f"not scored: {row['source']}/{row['clip']}: {row['error']} (REF unreadable: left out "
                "of the means; tapnet's evaluator would stop here)",
                file=sys.stderr,
            )
    if not rows:
        print(f"no REF clip to score in {args.ref_dir}", file=sys.stderr)
        return 1
    if not any(row["status"] == "scored" for row in rows):
        print(f"none of the {len(rows)} prediction(s) could be scored", file=sys.stderr)
        return 1
    return 0
