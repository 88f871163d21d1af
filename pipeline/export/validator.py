"""Check clips against every invariant of the released TAPVid-3D schema (SOURCES.md section 1)."""

from __future__ import annotations

import io
import pickle
import zipfile

import numpy as np

from pipeline.core.config import FlickerConfig
from pipeline.core.geometry import in_image, project
from pipeline.filters.flicker import passes_flicker, visibility_flips

BASE_KEYS = {"images_jpeg_bytes", "queries_xyt", "tracks_XYZ", "visibility", "fx_fy_cx_cy"}
QUERY_TOLERANCE_PX = 0.5
FLICKER_MAX_FRACTION = FlickerConfig().max_fraction
FINDINGS = ("hidden_queries", "off_image_visible", "flickering")
NO_FINDINGS = dict.fromkeys(("tracks", "frames", "image_hw", *FINDINGS))
# Start-of-frame markers (baseline, progressive, lossless, arithmetic): they carry the image size.
SOF_MARKERS = frozenset({0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF})


def expected_keys(source: str | None) -> set[str]:
    """Keys a clip of ``source`` must hold exactly (pstudio omits extrinsics)."""
    return BASE_KEYS if source == "pstudio" else BASE_KEYS | {"extrinsics_w2c"}


def check_arrays(arrays: dict[str, np.ndarray], source: str | None) -> list[str]:
    """Every violated invariant of one clip, as sentences; empty when the clip is valid."""
    problems = []
    keys = set(arrays)
    wanted = expected_keys(source)
    if source is None:
        wanted = BASE_KEYS | (keys & {"extrinsics_w2c"})
    if keys != wanted:
        missing, extra = sorted(wanted - keys), sorted(keys - wanted)
        problems.append(f"keys: missing {missing}, unexpected {extra}")
        if missing:
            return problems
    images = arrays["images_jpeg_bytes"]
    queries, tracks = arrays["queries_xyt"], arrays["tracks_XYZ"]
    visibility, intrinsics = arrays["visibility"], arrays["fx_fy_cx_cy"]
    for name, array, dtype, ndim in (
        ("queries_xyt", queries, np.float32, 2),
        ("tracks_XYZ", tracks, np.float32, 3),
        ("visibility", visibility, np.bool_, 2),
        ("fx_fy_cx_cy", intrinsics, np.float32, 1),
    ):
        if array.dtype != dtype or array.ndim != ndim:
            expected = f"{np.dtype(dtype).name} ndim {ndim}"
            problems.append(f"{name}: dtype {array.dtype} ndim {array.ndim}, expected {expected}")
    if images.dtype != object or images.ndim != 1:
        problems.append("images_jpeg_bytes: expected a 1-D object array of bytes")
    if problems:
        return problems
    num_frames, num_tracks = len(images), queries.shape[0]
    if num_tracks == 0:
        problems.append("no tracks (N = 0)")
    if tracks.shape != (num_frames, num_tracks, 3):
        problems.append(f"tracks_XYZ shape {tracks.shape}, expected ({num_frames}, {num_tracks}, 3)")
    if visibility.shape != (num_frames, num_tracks):
        problems.append(f"visibility shape {visibility.shape}, expected ({num_frames}, {num_tracks})")
    if queries.shape != (num_tracks, 3):
        problems.append(f"queries_xyt shape {queries.shape}, expected ({num_tracks}, 3)")
    if intrinsics.shape != (4,):
        problems.append(f"fx_fy_cx_cy shape {intrinsics.shape}, expected (4,)")
    if "extrinsics_w2c" in arrays:
        extrinsics = arrays["extrinsics_w2c"]
        if extrinsics.dtype != np.float32 or extrinsics.shape != (num_frames, 4, 4):
            problems.append(
                f"extrinsics_w2c: {extrinsics.dtype} {extrinsics.shape}, "
                f"expected float32 ({num_frames}, 4, 4)"
            )
        elif not np.isfinite(extrinsics).all():
            problems.append("extrinsics_w2c: non-finite values")
    for index, frame in enumerate(images):
        if not isinstance(frame, bytes) or frame[:2] != b"\xff\xd8":
            problems.append(f"images_jpeg_bytes[{index}]: not JPEG bytes")
            break
    if problems:
        return problems
    for name, array in (("queries_xyt", queries), ("tracks_XYZ", tracks), ("fx_fy_cx_cy", intrinsics)):
        if not np.isfinite(array).all():
            problems.append(f"{name}: non-finite values")
    if problems:
        return problems
    query_frames = queries[:, 2]
    integral = (query_frames == np.round(query_frames)) & (query_frames >= 0)
    integral &= query_frames < num_frames
    if not integral.all():
        problems.append(f"queries_xyt: {int((~integral).sum())} query frame(s) not a frame index")
        return problems
    t_q = query_frames.astype(np.int64)
    at_query = tracks[t_q, np.arange(num_tracks)].astype(np.float64)
    hidden = ~visibility[t_q, np.arange(num_tracks)]
    if hidden.any():
        problems.append(f"{int(hidden.sum())} track(s) not visible at their query frame")
    behind = at_query[:, 2] <= 0
    if behind.any():
        problems.append(f"{int(behind.sum())} track(s) with z <= 0 at their query frame")
    error = np.linalg.norm(project(at_query, intrinsics.astype(np.float64)) - queries[:, :2], axis=1)
    far = ~(error <= QUERY_TOLERANCE_PX)
    if far.any():
        problems.append(
            f"{int(far.sum())} query point(s) more than {QUERY_TOLERANCE_PX} px from their "
            f"track's projection (worst {np.nanmax(np.where(np.isfinite(error), error, np.inf)):.3f} px)"
        )
    return problems


def load_clip(data: bytes) -> dict[str, np.ndarray]:
    """Arrays of a clip file's bytes (the frames are a pickled object array of bytes)."""
    with np.load(io.BytesIO(data), allow_pickle=True) as archive:
        return {key: archive[key] for key in archive.files}


def check_clip_bytes(data: bytes, source: str | None) -> list[str]:
    """Invariant violations of a clip file's bytes, including unreadable files."""
    return inspect_clip_bytes(data, source)[0]


def inspect_clip_bytes(
    data: bytes, source: str | None, flicker_max_fraction: float = FLICKER_MAX_FRACTION
) -> tuple[list[str], dict]:
    """Invariant violations (``check_arrays``) and ``quality_findings`` of a clip file's bytes."""
    try:
        arrays = load_clip(data)
    except (zipfile.BadZipFile, pickle.UnpicklingError, ValueError, OSError, EOFError) as error:
        return [f"unreadable .npz ({error})"], dict(NO_FINDINGS)
    return check_arrays(arrays, source), quality_findings(arrays, flicker_max_fraction)


def jpeg_size(data: bytes) -> tuple[int, int] | None:
    """(height, width) from a JPEG's start-of-frame header, or None when there is none to read."""
    if data[:2] != b"\xff\xd8":
        return None
    pos = 2
    while pos + 4 <= len(data):
        if data[pos] != 0xFF:
            return None
        marker = data[pos + 1]
        if marker == 0xFF:  # fill byte before a marker
            pos += 1
            continue
        if marker in SOF_MARKERS:
            if pos + 9 > len(data):
                return None
            height = int.from_bytes(data[pos + 5 : pos + 7], "big")
            width = int.from_bytes(data[pos + 7 : pos + 9], "big")
            return (height, width) if height and width else None
        if marker in (0xD9, 0xDA):  # end of image or start of scan before any frame header
            return None
        pos += 2 + int.from_bytes(data[pos + 2 : pos + 4], "big")
    return None


def quality_findings(
    arrays: dict[str, np.ndarray], flicker_max_fraction: float = FLICKER_MAX_FRACTION
) -> dict:
    """Counts of defects that do not break the schema but matter to users of a clip.

    ``hidden_queries``: tracks with visibility[t_q, i] False; ``off_image_visible``: tracks marked
    visible [T, N] on some frame where tracks_XYZ [T, N, 3] has z <= 0 or projects outside
    [0, W) x [0, H) (None when the first frame's JPEG header gives no size); ``flickering``: tracks
    whose visibility changes state more than ``flicker_max_fraction`` x T times. Every value is
    None when the arrays are too malformed to look at (``check_arrays`` says why).
    """
    names = ("images_jpeg_bytes", "queries_xyt", "tracks_XYZ", "visibility", "fx_fy_cx_cy")
    if not set(names) <= set(arrays):
        return dict(NO_FINDINGS)
    images, queries, tracks, visibility, intrinsics = (arrays[name] for name in names)
    numeric = all(array.dtype.kind in "fiu" for array in (queries, tracks, intrinsics))
    if not numeric or visibility.dtype != np.bool_ or images.ndim != 1 or queries.ndim != 2:
        return dict(NO_FINDINGS)
    num_frames, num_tracks = len(images), len(queries)
    shapes_ok = queries.shape == (num_tracks, 3) and intrinsics.shape == (4,)
    shapes_ok &= tracks.shape == (num_frames, num_tracks, 3) and visibility.shape == (num_frames, num_tracks)
    if not shapes_ok:
        return dict(NO_FINDINGS)
    query_frames = queries[:, 2]
    integral = (query_frames == np.round(query_frames)) & (query_frames >= 0) & (query_frames < num_frames)
    if not integral.all():
        return dict(NO_FINDINGS)
    t_q = query_frames.astype(np.int64)
    size = jpeg_size(images[0]) if num_frames and isinstance(images[0], bytes) else None
    off_image = None
    if size is not None:
        height, width = size
        xyz = tracks.astype(np.float64)
        inside = in_image(project(xyz, intrinsics.astype(np.float64)), width, height) & (xyz[..., 2] > 0)
        off_image = int(np.count_nonzero((visibility & ~inside).any(axis=0)))
    flicker_ok = passes_flicker(visibility_flips(visibility), num_frames, flicker_max_fraction)
    return {
        "tracks": num_tracks,
        "frames": num_frames,
        "image_hw": list(size) if size else None,
        "hidden_queries": int(np.count_nonzero(~visibility[t_q, np.arange(num_tracks)])),
        "off_image_visible": off_image,
        "flickering": int(np.count_nonzero(~flicker_ok)),
    }
