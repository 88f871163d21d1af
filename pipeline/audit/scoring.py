"""Scoring one benchmark clip for ``audit compare``: REF's clip read (over HTTP, only the members
scored and the start of its first JPEG), NEW's prediction read within REF's sizes, each as a
``pipeline.clips.Clip`` of the members read, tapnet's metrics and the agreement computed, and the
clip's row (``pipeline.audit.compare_rows``) made.

Nothing is unpickled and every size is bounded (``pipeline.io.clip_reader``): a prediction's members
may hold no more than REF's T frames and N tracks need. The frame size that sets the evaluation scale
comes from REF's first JPEG header; a reference without frames or intrinsics (the release's ADT and
Panoptic Studio files hold annotations only) takes them from NEW's clip of the same video.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import math

import numpy as np

from pipeline.audit.agreement import AGREE_MM, agreement
from pipeline.audit.compare_rows import ClipRow, RefUnread, Scored, Scores, Status, Zero
from pipeline.audit.metrics import (
    SCALINGS,
    eval_intrinsics,
    median_error,
    query_frame_indices,
    tapvid3d_metrics,
)
from pipeline.clips import Clip, from_members
from pipeline.io.clip_reader import (
    DEFAULT_LIMITS,
    FRAME_HEAD_BYTES,
    FRAMES,
    MERGED_FETCH_BYTES,
    ReadLimits,
    first_frame_size,
    member_caps,
    read_clip_archive,
)
from pipeline.io.files import read_bytes
from pipeline.io.http import HttpClient, HttpError, is_http, open_remote, shown
from pipeline.io.npz_reader import NpzArchive, NpzError

NUMERIC_KEYS = ("queries_xyt", "tracks_XYZ", "visibility", "fx_fy_cx_cy")
REQUIRED_KEYS = ("queries_xyt", "tracks_XYZ", "visibility")
PREDICTION_KEYS = ("tracks_XYZ", "visibility")


class ClipError(Exception):
    """A clip that cannot be read or scored, with the reason."""


def check_numbers(path: str, members: dict[str, np.ndarray], keys: tuple[str, ...]) -> None:
    """ClipError when one of the file's members ``keys`` holds bytes (no arithmetic applies to them)."""
    strings = [key for key in keys if members[key].dtype.kind == "S"]
    if strings:
        raise ClipError(f"{path}: {strings} hold bytes, not numbers")


def read_reference(path: str, limits: ReadLimits, client: HttpClient | None = None) -> Clip:
    """REF's clip: its queries, tracks [T, N, 3], visibility [T, N] and intrinsics [4] when it has
    them, and its ``frame_size`` from the first JPEG's header (None when it holds no frames; the
    frames are not read). Over HTTP (``client``) only those members and the start of the first JPEG
    are fetched; HttpError when the file cannot be (kind not_found: REF has none)."""
    try:
        if is_http(path):
            with open_remote(client or HttpClient(), path, limits.max_file_bytes) as remote:
                return _reference(NpzArchive(remote, shown(path)), limits)
        return _reference(NpzArchive(read_bytes(path, limits.max_file_bytes), path), limits)
    except NpzError as error:
        raise ClipError(str(error)) from error
    except OSError as error:
        raise ClipError(f"{path}: cannot be read ({error.strerror or error})") from error


def _reference(archive: NpzArchive, limits: ReadLimits) -> Clip:
    path = archive.name
    wanted: dict[str, int | None] = dict.fromkeys(NUMERIC_KEYS) | {FRAMES: FRAME_HEAD_BYTES}
    archive.prefetch(wanted, MERGED_FETCH_BYTES)  # over HTTP: the members and the first JPEG's start at once
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
    return from_members(path, arrays, size)


OPTIONAL_PREDICTION_KEYS = ("queries_xyt", "fx_fy_cx_cy")


def read_prediction(path: str, num_frames: int, num_tracks: int, limits: ReadLimits) -> tuple[Clip, str]:
    """NEW's clip of its ``tracks_XYZ`` and ``visibility``, each refused before reading when it claims
    more than REF's T frames and N tracks need (ClipError saying why they cannot be read), and, where
    they can be read within the same bounds (else None), its queries and intrinsics and its
    ``frame_size``; and the SHA-256 of its file."""
    caps = member_caps(num_frames, num_tracks, limits)
    why = f"REF's clip has T = {num_frames} frames and N = {num_tracks} tracks"
    try:
        data = read_bytes(path, limits.max_file_bytes)
        archive = NpzArchive(data, path)
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
    return from_members(path, arrays, size), hashlib.sha256(data).hexdigest()


def compare_clip(ref: Clip, new: Clip) -> Scores:
    """Scores of NEW's tracks [T, N, 3] / visibility [T, N] against REF's (REF's queries, intrinsics
    and frame size: ``with_camera`` completes them); ClipError when the shapes differ or REF lacks
    its intrinsics or frame size."""
    gt_tracks, pred_tracks = ref.tracks, new.tracks
    gt_visible, pred_visible = ref.visibility, new.visibility
    if gt_tracks.shape != pred_tracks.shape or gt_visible.shape != pred_visible.shape:
        raise ClipError(
            f"shapes differ: REF tracks {gt_tracks.shape} visibility {gt_visible.shape}, "
            f"NEW tracks {pred_tracks.shape} visibility {pred_visible.shape}"
        )
    if ref.intrinsics is None or ref.frame_size is None:
        raise ClipError("REF's clip holds no intrinsics or no frame size")
    num_frames, num_tracks = gt_visible.shape
    queries = ref.queries
    query_frames = (
        query_frame_indices(queries[:, 2], num_frames)
        if queries is not None and queries.shape == (num_tracks, 3)
        else None
    )
    intrinsics = eval_intrinsics(ref.intrinsics, *ref.frame_size)
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
    at: str,
    limits: ReadLimits = DEFAULT_LIMITS,
    client: HttpClient | None = None,
    agree_mm: float = AGREE_MM,
    not_made: str = "",
) -> ClipRow:
    """One benchmark clip's row (``compare_rows``), found at ``at``: ``Scored`` (``agrees``: fully,
    within ``agree_mm``), ``Zero`` (the prediction is missing, unreadable or of another shape; or,
    given ``not_made``, the reason a release run made no clip of this name: then REF is not read) or
    ``RefUnread`` (REF unreadable, or holding no such clip: ``ref_path`` None, or HTTP 404); over HTTP,
    with the bytes fetched."""
    source, clip = key.split("/")
    if not_made and new_path is None:
        return Zero(source, clip, 0, 0, f"not made by the run: {not_made}", at, status=Status.NOT_MADE)
    if ref_path is None:
        return RefUnread(source, clip, Status.NOT_IN_REF, "REF holds no clip of this name", at)
    before = client.fetched if client is not None else 0

    def fetched() -> int | None:
        return client.fetched - before if client is not None else None

    try:
        ref = read_reference(ref_path, limits, client)
    except HttpError as error:
        status = Status.NOT_IN_REF if error.kind == "not_found" else Status.REF_ERROR
        return RefUnread(source, clip, status, f"{error.url}: {error}", at, fetched())
    except ClipError as error:
        return RefUnread(source, clip, Status.REF_ERROR, str(error), at, fetched())
    num_frames, num_tracks = ref.visibility.shape
    fetched_bytes = fetched()
    if new_path is None:
        return Zero(source, clip, num_frames, num_tracks, "no prediction file", at, fetched_bytes)
    try:
        new, digest = read_prediction(new_path, num_frames, num_tracks, limits)
        ref, note = with_camera(ref, new)
        scores = compare_clip(ref, new)
    except ClipError as error:
        return Zero(source, clip, num_frames, num_tracks, str(error), at, fetched_bytes)
    measured = agreement(ref, new)
    agrees = measured.agrees(agree_mm)
    return Scored(
        source, clip, num_frames, num_tracks, scores, measured, agrees, at, note, fetched_bytes, digest
    )


def with_camera(ref: Clip, new: Clip) -> tuple[Clip, str]:
    """REF with intrinsics and a frame size, and a note when either came from NEW's clip (the
    release's ADT and Panoptic Studio files hold annotations only); ClipError when neither has them."""
    taken = []
    size = ref.frame_size
    if size is None:
        size = new.frame_size
        taken.append("frame size")
    intrinsics = ref.intrinsics
    if intrinsics is None:
        if new.intrinsics is None or new.intrinsics.shape != (4,):
            raise ClipError("neither clip holds intrinsics (fx_fy_cx_cy)")
        intrinsics = new.intrinsics
        taken.append("intrinsics")
    if size is None:
        raise ClipError("neither clip holds frames to read the frame size from")
    note = f"{' and '.join(taken)} from the regenerated clip (the reference holds none)" if taken else ""
    return dataclasses.replace(ref, intrinsics=intrinsics, frame_size=size), note
