"""``python -m pipeline.audit compare REF NEW_DIR [--clips LIST] [--out PREFIX]``: TAPVid-3D metrics of
NEW against REF, scored as tapnet's ``tapvid3d/evaluation/evaluate_model.py`` scores them, and each
clip's agreement with REF.

REF is a folder, or a base URL (``gs://``, ``http(s)://``, e.g. the release's bucket,
``https://storage.googleapis.com/dm-tapnet/tapvid3d/release_files/v1.0``). Clips are matched by
``<source>/<clip>.npz``; REF's clips (a URL cannot be listed: then the release clips of NEW_DIR's
verdicts, ``release_<source>.jsonl``), or those named in ``--clips`` (one ``<source>/<clip>.npz`` a
line, e.g. a run's ``manifests/minival.txt``: tapnet's ``use_minival``) are the benchmark, NEW's
``tracks_XYZ`` and ``visibility`` the prediction (other members are ignored, so a file holding only
those two is scored); tracks correspond by index. Per clip: 3D-AJ and APD under each rescaling of
``pipeline.audit.metrics.SCALINGS``, OA (the visibility agreement) and the median 3D error in metres
(not a tapnet metric); and its agreement (``pipeline/audit/agreement.py``): the share of equal query
frames, the visibility agreement, the median and 95th percentile of the track distance (mm), and
whether it agrees fully (``--agree-mm``). Over HTTP only the members scored are read, by Range
requests (``pipeline.io.http``): a clip's frames never, but the start of its first JPEG, for the
frame size; ``fetched_bytes`` counts each clip's bytes received. A reference without frames or
intrinsics (the release's ADT and Panoptic Studio files hold annotations only) takes them from NEW's
clip of the same video. As in tapnet:

- a REF clip whose prediction is missing, unreadable, refused or of another shape counts with
  every metric 0 (status ``zero``, named with the reason); under per-trajectory rescaling, so does
  a clip whose REF query frames are no frame indices;
- per source, each metric is the plain mean over its clips, whatever their length (a NaN metric,
  from a REF clip with no visible point, makes the mean NaN); ``all`` is the mean of the source means.

The median error is averaged over the clips whose prediction was read. A REF clip that cannot be
read (tapnet's evaluator would stop there) is named and left out of the means (status
``ref_error``), and so is one REF does not hold (HTTP 404: status ``not_in_ref``). Writes
``PREFIX.md`` and ``PREFIX.json`` (default prefix ``NEW_DIR/compare``); when NEW_DIR is a release
run, each of its verdict rows gains the clip's ``agreement``.
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

import contextlib
import dataclasses
import enum
import json
import math
import os
import re
import sys
from collections.abc import Mapping
from typing import Any, ClassVar, TypeAlias

import numpy as np

from pipeline import sources as registry
from pipeline.audit.agreement import AGREE_MM, Agreement, agreement
from pipeline.audit.metrics import (
    SCALINGS,
    eval_intrinsics,
    median_error,
    query_frame_indices,
    tapvid3d_metrics,
)
from pipeline.audit.verdict_rows import ClipAgreement, add_agreement, release_clip_keys
from pipeline.commandline import StrictParser
from pipeline.io.clip_reader import (
    DEFAULT_LIMITS,
    ReadLimits,
    add_limit_argument,
    first_frame_size,
    limits_from,
    member_caps,
    read_clip_archive,
)
from pipeline.io.files import is_local, list_files, read_bytes, write_atomic
from pipeline.io.http import HttpClient, HttpError, is_http, join, open_remote, shown
from pipeline.io.npz_reader import NpzArchive, NpzError

NUMERIC_KEYS = ("queries_xyt", "tracks_XYZ", "visibility", "fx_fy_cx_cy")
REQUIRED_KEYS = ("queries_xyt", "tracks_XYZ", "visibility")
PREDICTION_KEYS = ("tracks_XYZ", "visibility")
TAPNET_KEYS = (*(f"{key}_{scaling}" for scaling in SCALINGS for key in ("aj", "apd")), "oa")
SUMMARY_KEYS = (*TAPNET_KEYS, "median_error_m")
AGREEMENT_KEYS = ("query_frames_equal", "visibility", "median_mm", "p95_mm")
COUNT_KEYS = ("clips", "zero", "ref_errors", "not_in_ref", "agree", "fetched_bytes")
CLIP_ENTRY = re.compile(r"[^/\s]+/[^/\s]+\.npz")
MAX_LIST_BYTES = 16 << 20


class ClipError(Exception):
    """A clip that cannot be read or scored, with the reason."""


class Status(enum.Enum):
    """What became of a benchmark clip; the value names it in the report."""

    SCORED = "scored"
    ZERO = "zero"
    REF_ERROR = "ref_error"
    NOT_IN_REF = "not_in_ref"


@dataclasses.dataclass(frozen=True)
class Scores:
    """A clip's tapnet metrics, or their means: 3D-AJ and APD under each rescaling (``aj``, ``apd``:
    scaling of ``SCALINGS`` -> value) and OA; and the median 3D error in metres (not a tapnet metric;
    NaN where none was measured). ``note`` says when per-trajectory counted 0."""

    aj: Mapping[str, float]
    apd: Mapping[str, float]
    oa: float
    median_error_m: float
    note: str = ""

    def tapnet(self) -> dict[str, float]:
        """``TAPNET_KEYS`` -> value."""
        values: dict[str, float] = {}
        for scaling in SCALINGS:
            values |= {f"aj_{scaling}": self.aj[scaling], f"apd_{scaling}": self.apd[scaling]}
        return values | {"oa": self.oa}


# A clip counted as tapnet's ``evaluate_model.py`` counts one it cannot score: every metric 0.
ZERO_SCORES = Scores(dict.fromkeys(SCALINGS, 0.0), dict.fromkeys(SCALINGS, 0.0), 0.0, math.nan)


def _named(source: str, clip: str, frames: int, tracks: int, fetched_bytes: int | None) -> dict[str, Any]:
    """The first fields of a row whose REF clip was read."""
    return {"source": source, "clip": clip, "frames": frames, "tracks": tracks} | _fetched(fetched_bytes)


def _fetched(fetched_bytes: int | None) -> dict[str, int]:
    return {} if fetched_bytes is None else {"fetched_bytes": fetched_bytes}


@dataclasses.dataclass(frozen=True)
class RefUnread:
    """A benchmark clip left out of the means: REF cannot be read (``REF_ERROR``) or holds no such clip
    (``NOT_IN_REF``: HTTP 404); ``error`` says why, ``fetched_bytes`` counts the bytes received over
    HTTP (None for a REF that is not)."""

    source: str
    clip: str
    status: Status
    error: str
    fetched_bytes: int | None = None

    def as_row(self) -> dict[str, Any]:
        """The clip's row of the report."""
        row = {"source": self.source, "clip": self.clip, "status": self.status.value, "error": self.error}
        return row | _fetched(self.fetched_bytes)


@dataclasses.dataclass(frozen=True)
class Zero:
    """A benchmark clip whose prediction is missing, unreadable, refused or of another shape: counted
    with every metric 0 (``ZERO_SCORES``); ``error`` says why. ``frames``, ``tracks``: REF's T and N."""

    source: str
    clip: str
    frames: int
    tracks: int
    error: str
    fetched_bytes: int | None = None
    status: ClassVar[Status] = Status.ZERO
    scores: ClassVar[Scores] = ZERO_SCORES

    def as_row(self) -> dict[str, Any]:
        """The clip's row of the report."""
        named = _named(self.source, self.clip, self.frames, self.tracks, self.fetched_bytes)
        scores = self.scores.tapnet() | {"median_error_m": self.scores.median_error_m}
        return named | {"status": self.status.value, "error": self.error} | scores


@dataclasses.dataclass(frozen=True)
class Scored:
    """A prediction scored against REF: its scores, its agreement with REF and whether that is full
    (within the report's agree_mm); ``camera_note`` says when REF's frame size or intrinsics came
    from NEW's clip. ``frames``, ``tracks``: REF's T and N."""

    source: str
    clip: str
    frames: int
    tracks: int
    scores: Scores
    agreement: Agreement
    agrees: bool
    camera_note: str = ""
    fetched_bytes: int | None = None
    status: ClassVar[Status] = Status.SCORED

    @property
    def note(self) -> str:
        """The scores' note and the camera's, either, or none."""
        return "; ".join(text for text in (self.scores.note, self.camera_note) if text)

    def as_row(self) -> dict[str, Any]:
        """The clip's row of the report: the metrics per rescaling (OA after the median's, the scores'
        note after per-trajectory's), the median error, the agreement, ``agrees``, then a camera note
        alone."""
        row = _named(self.source, self.clip, self.frames, self.tracks, self.fetched_bytes)
        row["status"] = self.status.value
        for scaling in SCALINGS:
            row |= {f"aj_{scaling}": self.scores.aj[scaling], f"apd_{scaling}": self.scores.apd[scaling]}
            if scaling == "median":
                row["oa"] = self.scores.oa
            if scaling == "per_trajectory" and self.scores.note:
                row["note"] = self.note
        row["median_error_m"] = self.scores.median_error_m
        row |= {key: getattr(self.agreement, key) for key in AGREEMENT_KEYS}
        row["agrees"] = self.agrees
        return row | ({"note": self.note} if self.camera_note and not self.scores.note else {})


ClipRow: TypeAlias = RefUnread | Zero | Scored


@dataclasses.dataclass(frozen=True)
class SourceMeans:
    """One source's line of the report, or ``all``'s: the clips counted by tapnet (scored and zero),
    those zero, those left out (ref_errors, not_in_ref), those that agree fully, the bytes fetched over
    HTTP, and the means of the counted clips' scores."""

    source: str
    clips: int
    zero: int
    ref_errors: int
    not_in_ref: int
    agree: int
    fetched_bytes: int
    means: Scores

    def as_row(self) -> dict[str, Any]:
        """The source's row of the report."""
        counts = {key: getattr(self, key) for key in COUNT_KEYS}
        return {
            "source": self.source,
            **counts,
            **self.means.tapnet(),
            "median_error_m": self.means.median_error_m,
        }


@dataclasses.dataclass(frozen=True)
class CompareReport:
    """NEW_DIR's clips against REF's: REF as shown, NEW_DIR, agree_mm, a row per benchmark clip (in
    the benchmark's order), a ``SourceMeans`` per source then ``all``'s, and NEW's clips not in the
    benchmark."""

    ref: str
    new: str
    agree_mm: float
    clips: list[ClipRow]
    sources: list[SourceMeans]
    only_in_new: list[str]

    def to_json(self) -> dict[str, Any]:
        """The report as ``PREFIX.json`` holds it (strict JSON: NaN as None)."""
        return json_ready(
            {
                "ref": self.ref,
                "new": self.new,
                "agree_mm": self.agree_mm,
                "clips": [row.as_row() for row in self.clips],
                "sources": [row.as_row() for row in self.sources],
                "only_in_new": self.only_in_new,
            }
        )


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


def read_reference(
    path: str, limits: ReadLimits, client: HttpClient | None = None
) -> tuple[dict[str, np.ndarray], tuple[int, int] | None]:
    """REF's numeric arrays, checked to be a clip's queries [N, 3], tracks [T, N, 3], visibility
    [T, N] and intrinsics [4] when it has them, and its frame (height, width) from the first JPEG's
    header (None when it holds no frames). Over HTTP (``client``) only those members and the start
    of the first JPEG are fetched; HttpError when the file cannot be (kind not_found: REF has none)."""
    try:
        if is_http(path):
            with open_remote(client or HttpClient(), path, limits.max_file_bytes) as remote:
                return _reference(NpzArchive(remote, shown(path)), limits)
        return _reference(NpzArchive(read_bytes(path, limits.max_file_bytes), path), limits)
    except NpzError as error:
        raise ClipError(str(error)) from error
    except OSError as error:
        raise ClipError(f"{path}: cannot be read ({error.strerror or error})") from error


def _reference(
    archive: NpzArchive, limits: ReadLimits
) -> tuple[dict[str, np.ndarray], tuple[int, int] | None]:
    path = archive.name
    missing = [key for key in REQUIRED_KEYS if key not in archive.keys]
    if missing:
        raise ClipError(f"{path}: missing {missing}")
    arrays = read_clip_archive(archive, limits, tuple(key for key in NUMERIC_KEYS if key in archive.keys))
    check_numbers(path, arrays, tuple(arrays))
    tracks, visible = arrays["tracks_XYZ"], arrays["visibility"]
    if tracks.ndim != 3 or tracks.shape[2] != 3 or visible.shape != tracks.shape[:2]:
        raise ClipError(
            f"{path}: tracks_XYZ {tracks.shape} and visibility {visible.shape} are not [T, N, 3], [T, N]"
        )
    if "fx_fy_cx_cy" in arrays and arrays["fx_fy_cx_cy"].shape != (4,):
        raise ClipError(f"{path}: fx_fy_cx_cy has shape {arrays['fx_fy_cx_cy'].shape}, not [4]")
    size = first_frame_size(archive, limits)
    if size is None and "images_jpeg_bytes" in archive.keys:
        raise ClipError(f"{path}: no readable JPEG header in the first frame")
    return arrays, size


OPTIONAL_PREDICTION_KEYS = ("queries_xyt", "fx_fy_cx_cy")


def read_prediction(
    path: str, num_frames: int, num_tracks: int, limits: ReadLimits
) -> tuple[dict[str, np.ndarray], tuple[int, int] | None]:
    """NEW's ``tracks_XYZ`` and ``visibility``, each refused before reading when it claims more than
    REF's T frames and N tracks need; ClipError saying why they cannot be read. Also, where they can
    be read within the same bounds (else they are left out), its queries and intrinsics and its first
    frame's size (None without)."""
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
    for key in OPTIONAL_PREDICTION_KEYS:
        with contextlib.suppress(NpzError, KeyError):
            optional = archive.read(key, caps[key], why)
            if optional.dtype.kind in "fiu":
                arrays[key] = optional
    try:
        size = first_frame_size(archive, limits)
    except NpzError:
        size = None
    return arrays, size


def compare_clip(ref: dict[str, np.ndarray], new: dict[str, np.ndarray], height: int, width: int) -> Scores:
    """Scores of NEW's tracks [T, N, 3] / visibility [T, N] against REF's (REF's queries and
    intrinsics); ClipError when the shapes differ."""
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
    aj: dict[str, float] = {}
    apd: dict[str, float] = {}
    oa, note = math.nan, ""
    for scaling in SCALINGS:
        if scaling == "per_trajectory" and query_frames is None:
            aj[scaling] = apd[scaling] = 0.0
            note = "REF query frames are not frame indices: per_trajectory counted as 0"
            continue
        scores = tapvid3d_metrics(
            gt_tracks, gt_visible, pred_tracks, pred_visible, intrinsics, query_frames, scaling
        )
        aj[scaling], apd[scaling] = scores["average_jaccard"], scores["average_pts_within"]
        if scaling == "median":
            oa = scores["occlusion_accuracy"]
    return Scores(aj, apd, oa, median_error(gt_tracks, gt_visible, pred_tracks), note)


def score_pair(
    key: str,
    ref_path: str | None,
    new_path: str | None,
    limits: ReadLimits = DEFAULT_LIMITS,
    client: HttpClient | None = None,
    agree_mm: float = AGREE_MM,
) -> ClipRow:
    """One benchmark clip's row: ``Scored`` (``agrees``: fully, within ``agree_mm``), ``Zero`` (the
    prediction is missing, unreadable or of another shape) or ``RefUnread`` (REF unreadable, or
    holding no such clip: HTTP 404); over HTTP, with the bytes fetched."""
    source, clip = key.split("/")
    before = client.fetched if client is not None else 0

    def fetched() -> int | None:
        return client.fetched - before if client is not None else None

    try:
        if ref_path is None:
            raise ClipError("not in REF")
        ref, size = read_reference(ref_path, limits, client)
    except HttpError as error:
        status = Status.NOT_IN_REF if error.kind == "not_found" else Status.REF_ERROR
        return RefUnread(source, clip, status, f"{error.url}: {error}", fetched())
    except ClipError as error:
        return RefUnread(source, clip, Status.REF_ERROR, str(error), fetched())
    num_frames, num_tracks = ref["visibility"].shape
    fetched_bytes = fetched()
    if new_path is None:
        return Zero(source, clip, num_frames, num_tracks, "no prediction file", fetched_bytes)
    try:
        new, new_size = read_prediction(new_path, num_frames, num_tracks, limits)
        ref, size, note = _with_camera(ref, size, new, new_size)
        scores = compare_clip(ref, new, *size)
    except ClipError as error:
        return Zero(source, clip, num_frames, num_tracks, str(error), fetched_bytes)
    measured = agreement(ref, new)
    return Scored(
        source, clip, num_frames, num_tracks, scores, measured, measured.agrees(agree_mm), note, fetched_bytes
    )


def _with_camera(
    ref: dict[str, np.ndarray],
    size: tuple[int, int] | None,
    new: dict[str, np.ndarray],
    new_size: tuple[int, int] | None,
) -> tuple[dict[str, np.ndarray], tuple[int, int], str]:
    """REF with intrinsics, its frame size, and a note when either came from NEW's clip (the
    release's ADT and Panoptic Studio files hold annotations only); ClipError when neither has them."""
    taken = []
    if size is None:
        size = new_size
        taken.append("frame size")
    if "fx_fy_cx_cy" not in ref:
        if "fx_fy_cx_cy" not in new or new["fx_fy_cx_cy"].shape != (4,):
            raise ClipError("neither clip holds intrinsics (fx_fy_cx_cy)")
        ref = {**ref, "fx_fy_cx_cy": new["fx_fy_cx_cy"]}
        taken.append("intrinsics")
    if size is None:
        raise ClipError("neither clip holds frames to read the frame size from")
    note = f"{' and '.join(taken)} from the regenerated clip (the reference holds none)" if taken else ""
    return ref, size, note


def plain_mean(values: list[float]) -> float:
    """np.mean of ``values`` (a NaN propagates, as in tapnet's averages); NaN when empty."""
    return float(np.mean(values)) if values else math.nan


def mean_scores(counted: list[Scores], measured: list[Scores]) -> Scores:
    """Each tapnet metric's plain mean over ``counted``, the median error's over ``measured``."""
    return Scores(
        {scaling: plain_mean([scores.aj[scaling] for scores in counted]) for scaling in SCALINGS},
        {scaling: plain_mean([scores.apd[scaling] for scores in counted]) for scaling in SCALINGS},
        plain_mean([scores.oa for scores in counted]),
        plain_mean([scores.median_error_m for scores in measured]),
    )


def mean_row(rows: list[ClipRow], source: str) -> SourceMeans:
    """Means over the clips of ``rows`` counted by tapnet (scored and zero); the median error over
    the scored ones."""
    counted = [row for row in rows if not isinstance(row, RefUnread)]
    scored = [row for row in counted if isinstance(row, Scored)]
    return SourceMeans(
        source,
        clips=len(counted),
        zero=len(counted) - len(scored),
        ref_errors=sum(row.status is Status.REF_ERROR for row in rows),
        not_in_ref=sum(row.status is Status.NOT_IN_REF for row in rows),
        agree=sum(row.agrees for row in scored),
        fetched_bytes=sum(row.fetched_bytes or 0 for row in rows),
        means=mean_scores([row.scores for row in counted], [row.scores for row in scored]),
    )


def summarise(rows: list[ClipRow]) -> list[SourceMeans]:
    """One row per source (the registry's order, tapnet's for the built-in sources; then others
    sorted), then ``all``: the mean of the source means (as tapnet's ``main``) over the sources with a
    counted clip."""
    present = {row.source for row in rows}
    order = registry.names()
    sources = [s for s in order if s in present] + sorted(present - set(order))
    per_source = [mean_row([row for row in rows if row.source == source], source) for source in sources]
    counts = {key: sum(getattr(row, key) for row in per_source) for key in COUNT_KEYS}
    means = mean_scores(
        [row.means for row in per_source if row.clips],
        [row.means for row in per_source if row.clips > row.zero],
    )
    return [*per_source, SourceMeans("all", **counts, means=means)]


def json_ready(value):
    """``value`` with every non-finite float replaced by None (strict JSON has no NaN)."""
    if isinstance(value, dict):
        return {key: json_ready(item) for key, item in value.items()}
    if isinstance(value, list):
        return [json_ready(item) for item in value]
    return None if isinstance(value, float) and not math.isfinite(value) else value


def _cell(value) -> str:
    return f"{value:.4f}" if isinstance(value, float) else str(value)


def markdown(report: CompareReport) -> str:
    """The report as markdown: per-source table, per-clip table, clips only in NEW."""
    header = " | ".join(SUMMARY_KEYS)
    agree = " | ".join(AGREEMENT_KEYS)
    lines = [
        f"# TAPVid-3D metrics of `{report.new}` against `{report.ref}`",
        "",
        "aj/apd = 3D-AJ/APD under median, per-trajectory and no rescaling; oa = occlusion accuracy "
        "(= visibility agreement); means over clips as tapnet's evaluate_model.py, a clip whose "
        "prediction is missing or unreadable counting 0 (status zero); median_error_m = unscaled "
        "median 3D error over REF-visible points (not a tapnet metric; scored clips only). Agreement "
        f"per clip: query_frames_equal and visibility are shares of equal query frames and visibility "
        f"values, median_mm and p95_mm the track distance; agree: clips with all of them equal and "
        f"p95_mm <= {report.agree_mm:g} mm. fetched_bytes: bytes received over HTTP.",
        "",
        f"| source | clips | zero | ref_errors | not_in_ref | agree | fetched_bytes | {header} |",
        "|" + "---|" * (7 + len(SUMMARY_KEYS)),
    ]
    for means in report.sources:
        row = means.as_row()
        cells = [row["source"], *(row[key] for key in COUNT_KEYS), *(row[key] for key in SUMMARY_KEYS)]
        lines.append("| " + " | ".join(_cell(c) for c in cells) + " |")
    lines += [
        "",
        f"| source | clip | status | frames | tracks | fetched_bytes | {header} | {agree} | agrees | error |",
    ]
    lines.append("|" + "---|" * (9 + len(SUMMARY_KEYS) + len(AGREEMENT_KEYS)))
    for clip in report.clips:
        row = clip.as_row()
        named = ("source", "clip", "status", "frames", "tracks", "fetched_bytes")
        cells = [row.get(key, "") for key in (*named, *SUMMARY_KEYS, *AGREEMENT_KEYS, "agrees")]
        why = row.get("error", row.get("note", ""))
        lines.append("| " + " | ".join(_cell(c) for c in [*cells, why]) + " |")
    if report.only_in_new:
        lines += [
            "",
            f"only_in_new (not scored): {len(report.only_in_new)} clip(s): " + ", ".join(report.only_in_new),
        ]
    return "\n".join(lines) + "\n"


def benchmark_clips(ref_dir: str, new_dir: str, clips: list[str] | None) -> tuple[list[str], dict[str, str]]:
    """The clips to score (``<source>/<clip>.npz``, in order) and REF's path of each: ``clips``, else
    REF's own (sorted), else, for a REF that cannot be listed (HTTP), the release clips of NEW_DIR's
    verdicts; ValueError when there is no way to know them."""
    if is_http(ref_dir):
        keys = clips if clips is not None else release_clip_keys(new_dir)
        if keys is None:
            raise ValueError(
                f"{shown(ref_dir)} cannot be listed: give --clips, or compare a --release run "
                "(its verdicts name the release's clips)"
            )
        return keys, {key: join(ref_dir, key) for key in keys}
    ref = clip_keys(ref_dir)
    return (sorted(ref) if clips is None else clips), ref


def compare_dirs(
    ref_dir: str,
    new_dir: str,
    limits: ReadLimits = DEFAULT_LIMITS,
    clips: list[str] | None = None,
    agree_mm: float = AGREE_MM,
    client: HttpClient | None = None,
) -> CompareReport:
    """The full report of NEW_DIR's clips against REF's (``benchmark_clips``, in their
    order: each mean sums its clips in that order, as tapnet sums a split's); REF over HTTP through
    ``client`` (one with the default policy when None)."""
    benchmark, ref = benchmark_clips(ref_dir, new_dir, clips)
    new = clip_keys(new_dir)
    if client is None and is_http(ref_dir):
        client = HttpClient(note=lambda text: print(text, file=sys.stderr))
    rows = [score_pair(key, ref.get(key), new.get(key), limits, client, agree_mm) for key in benchmark]
    only_in_new = sorted(new.keys() - set(benchmark))
    return CompareReport(shown(ref_dir), new_dir, agree_mm, rows, summarise(rows), only_in_new)


def main(argv: list[str] | None = None) -> int:
    """The ``compare`` subcommand; exit status as the module doc says."""
    parser = StrictParser(prog="python -m pipeline.audit compare", description=__doc__)
    parser.add_argument(
        "ref_dir",
        metavar="REF",
        help="the reference: a folder or base URL of <source>/<clip>.npz files (e.g. the release's bucket)",
    )
    parser.add_argument("new_dir", metavar="NEW_DIR", help="output folder to score (e.g. a --release run)")
    parser.add_argument("--clips", help="score only these REF clips (a file of <source>/<clip>.npz lines)")
    parser.add_argument("--out", help="write OUT.md and OUT.json (default NEW_DIR/compare)")
    parser.add_argument(
        "--agree-mm",
        type=float,
        default=AGREE_MM,
        help="a clip agrees fully when its query frames and visibility are REF's and the 95th "
        "percentile of its track distance is at most this (millimetres; default %(default)s)",
    )
    add_limit_argument(parser)
    args = parser.parse_args(argv)
    try:
        limits = limits_from(args.limit)
    except ValueError as error:
        parser.error(str(error))
    if not args.agree_mm >= 0:
        parser.error(f"--agree-mm {args.agree_mm}: must be a number of millimetres >= 0")
    for folder in (args.ref_dir, args.new_dir):
        if is_local(folder) and not os.path.isdir(folder):
            print(f"compare: {folder} is not a folder", file=sys.stderr)
            return 2
    try:
        clips = None if args.clips is None else read_clip_list(args.clips)
    except (OSError, ValueError) as error:
        print(f"compare: cannot use --clips {args.clips}: {error}", file=sys.stderr)
        return 2
    ref_dir = args.ref_dir if is_http(args.ref_dir) else args.ref_dir.rstrip("/")
    new_dir = args.new_dir.rstrip("/")
    try:
        report = compare_dirs(ref_dir, new_dir, limits, clips, args.agree_mm)
    except ValueError as error:
        print(f"compare: {error}", file=sys.stderr)
        return 2
    text = markdown(report)
    print(text, end="")
    prefix = args.out or f"{new_dir}/compare"
    try:
        write_atomic(f"{prefix}.md", text.encode())
        write_atomic(f"{prefix}.json", json.dumps(report.to_json(), indent=1, allow_nan=False).encode())
        agreements = {f"{row.source}/{row.clip}": agreement_entry(row, args.agree_mm) for row in report.clips}
        updated = add_agreement(new_dir, agreements)
    except OSError as error:
        print(f"compare: cannot write the report {prefix}.md/.json: {error}", file=sys.stderr)
        return 2
    return _closing(report, args.ref_dir, updated)


def agreement_entry(row: ClipRow, agree_mm: float) -> ClipAgreement:
    """A verdict row's agreement from a clip's row: its status, the agreement and two of tapnet's
    metrics when scored, else why not."""
    if isinstance(row, Scored):
        measured = row.agreement
        return ClipAgreement(
            row.status.value,
            agree_mm,
            query_frames_equal=_plain(measured.query_frames_equal),
            visibility=_plain(measured.visibility),
            median_mm=_plain(measured.median_mm),
            p95_mm=_plain(measured.p95_mm),
            agrees=row.agrees,
            aj_median=_plain(row.scores.aj["median"]),
            oa=_plain(row.scores.oa),
        )
    return ClipAgreement(row.status.value, agree_mm, row.error)


def _plain(value: float) -> float | None:
    """A JSON value: NaN as None."""
    return None if math.isnan(value) else value


def _closing(report: CompareReport, ref_dir: str, updated: list[str]) -> int:
    """The lines after the report (clips not scored, bytes fetched, verdicts updated); the status."""
    rows = report.clips
    for row in rows:
        where = f"{row.source}/{row.clip}"
        if isinstance(row, Zero):
            print(f"not scored: {where}: {row.error} (counted as 0)", file=sys.stderr)
        elif isinstance(row, RefUnread) and row.status is Status.REF_ERROR:
            print(
                f"not scored: {where}: {row.error} (REF unreadable: left out of the means; tapnet's "
                "evaluator would stop here)",
                file=sys.stderr,
            )
        elif isinstance(row, RefUnread):
            print(f"not scored: {where}: not in REF ({row.error}): left out of the means", file=sys.stderr)
    total = report.sources[-1]
    if is_http(ref_dir) and rows:
        print(
            f"fetched {total.fetched_bytes:,} bytes over HTTP for {len(rows)} clip(s), "
            f"{total.fetched_bytes / len(rows):,.0f} a clip"
        )
    if updated:
        print(f"agreement added to the verdicts in {', '.join(updated)}")
    if not rows:
        print(f"no REF clip to score in {shown(ref_dir)}", file=sys.stderr)
        return 1
    if not any(isinstance(row, Scored) for row in rows):
        print(f"none of the {len(rows)} prediction(s) could be scored", file=sys.stderr)
        return 1
    return 0
