"""Check clips against every invariant of the released TAPVid-3D schema (docs/formats.md, section 1).

Files are read with ``pipeline.io.clip_reader`` (nothing unpickled, sizes bounded by the
clip's own T and N) and accepted as the release writes them: frames as a ``|S`` bytes array,
float32 or float64 geometry, ``extrinsics_w2c`` optional (the release's ADT files have none),
extra keys ignored.
"""

from __future__ import annotations

import numpy as np

from pipeline.core.geometry import in_image, project
from pipeline.core.images import jpeg_size
from pipeline.filters.flicker import passes_flicker, visibility_flips
from pipeline.io.clip_reader import DEFAULT_LIMITS, ReadLimits, read_clip_bytes
from pipeline.io.npz_reader import NpzError
from pipeline.settings.run_config import FlickerConfig

REQUIRED_KEYS = ("images_jpeg_bytes", "queries_xyt", "tracks_XYZ", "visibility", "fx_fy_cx_cy")
FLOATS = (np.dtype(np.float32), np.dtype(np.float64))
QUERY_TOLERANCE_PX = 0.5
FLICKER_MAX_FRACTION = FlickerConfig().max_fraction
FINDINGS = ("hidden_queries", "off_image_visible", "flickering")
# Per clip, how far queries lie from their track's pinhole projection (pixels), median and worst.
RESIDUALS = ("query_residual_median_px", "query_residual_max_px")
NO_FINDINGS = dict.fromkeys(("tracks", "frames", "image_hw", *FINDINGS, *RESIDUALS))


def check_arrays(arrays: dict[str, np.ndarray]) -> list[str]:
    """Every violated invariant of one clip, as sentences; empty when the clip is valid."""
    return structure_problems(arrays) or query_problems(arrays)


def structure_problems(arrays: dict[str, np.ndarray]) -> list[str]:
    """What keeps the arrays from being read as a clip: keys, dtypes, shapes [T, N, ...], frames
    that are not JPEGs of one size, non-finite values, non-positive focals, query frames that are
    not frame indices. Empty when a reader may index the clip freely."""
    problems = []
    missing = [key for key in REQUIRED_KEYS if key not in arrays]
    if missing:
        return [f"keys: missing {missing}"]
    images = arrays["images_jpeg_bytes"]
    queries, tracks = arrays["queries_xyt"], arrays["tracks_XYZ"]
    visibility, intrinsics = arrays["visibility"], arrays["fx_fy_cx_cy"]
    for name, array, dtypes, ndim in (
        ("queries_xyt", queries, FLOATS, 2),
        ("tracks_XYZ", tracks, FLOATS, 3),
        ("visibility", visibility, (np.dtype(np.bool_),), 2),
        ("fx_fy_cx_cy", intrinsics, FLOATS, 1),
    ):
        if array.dtype not in dtypes or array.ndim != ndim:
            expected = " or ".join(dtype.name for dtype in dtypes) + f" ndim {ndim}"
            problems.append(f"{name}: dtype {array.dtype} ndim {array.ndim}, expected {expected}")
    if images.dtype.kind != "S" or images.ndim != 1:
        problems.append(
            f"images_jpeg_bytes: dtype {images.dtype} ndim {images.ndim}, expected a 1-D bytes array"
        )
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
        if extrinsics.dtype not in FLOATS or extrinsics.shape != (num_frames, 4, 4):
            problems.append(
                f"extrinsics_w2c: {extrinsics.dtype} {extrinsics.shape}, "
                f"expected float32 or float64 ({num_frames}, 4, 4)"
            )
        elif not np.isfinite(extrinsics).all():
            problems.append("extrinsics_w2c: non-finite values")
    problems += frame_problems(images)
    if problems:
        return problems
    for name, array in (("queries_xyt", queries), ("tracks_XYZ", tracks), ("fx_fy_cx_cy", intrinsics)):
        if not np.isfinite(array).all():
            problems.append(f"{name}: non-finite values")
    if problems:
        return problems
    if not (intrinsics[:2] > 0).all():
        problems.append(f"fx_fy_cx_cy: focal lengths {intrinsics[:2].tolist()} must be positive")
        return problems
    query_frames = queries[:, 2]
    integral = (query_frames == np.round(query_frames)) & (query_frames >= 0)
    integral &= query_frames < num_frames
    if not integral.all():
        problems.append(f"queries_xyt: {int((~integral).sum())} query frame(s) not a frame index")
    return problems


def query_problems(arrays: dict[str, np.ndarray]) -> list[str]:
    """Violations of the query invariants of a structurally sound clip: each track visible, in front
    of the camera and projecting onto its query (within 0.5 px) at its query frame, each query
    inside the frame. ValueError for a clip whose first frame gives no size (``structure_problems``
    refuses it)."""
    problems = []
    queries, tracks, visibility = arrays["queries_xyt"], arrays["tracks_XYZ"], arrays["visibility"]
    intrinsics, num_tracks = arrays["fx_fy_cx_cy"], len(arrays["queries_xyt"])
    height, width = frame_size(arrays)
    outside = ~in_image(queries[:, :2].astype(np.float64), width, height)
    if outside.any():
        problems.append(f"{int(outside.sum())} query point(s) outside the {width}x{height} frame")
    t_q = queries[:, 2].astype(np.int64)
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


def frame_size(arrays: dict[str, np.ndarray]) -> tuple[int, int]:
    """(height, width) of the frames of a clip ``structure_problems`` accepts (every frame a JPEG
    of one size); ValueError for a clip whose first frame gives no size."""
    size = jpeg_size(bytes(arrays["images_jpeg_bytes"][0]))
    if size is None:
        raise ValueError("images_jpeg_bytes[0]: not JPEG bytes with a readable size header")
    return size


def frame_problems(images: np.ndarray) -> list[str]:
    """The first frame [T] that is not a JPEG with a readable size header, or whose size differs
    from frame 0's (a clip's frames share one size)."""
    first = None
    for index, frame in enumerate(images):
        size = jpeg_size(bytes(frame))
        if size is None:
            return [f"images_jpeg_bytes[{index}]: not JPEG bytes with a readable size header"]
        if first is None:
            first = size
        elif size != first:
            return [
                f"images_jpeg_bytes[{index}]: {size[1]}x{size[0]} pixels, frame 0 is {first[1]}x{first[0]}"
            ]
    return []


def check_clip_bytes(data: bytes, limits: ReadLimits = DEFAULT_LIMITS) -> list[str]:
    """Invariant violations of a clip file's bytes, including unreadable or refused files."""
    return inspect_clip_bytes(data, limits=limits)[0]


def inspect_clip_bytes(
    data: bytes,
    flicker_max_fraction: float = FLICKER_MAX_FRACTION,
    limits: ReadLimits = DEFAULT_LIMITS,
) -> tuple[list[str], dict]:
    """Invariant violations (``check_arrays``) and ``quality_findings`` of a clip file's bytes."""
    try:
        arrays = read_clip_bytes(data, "clip", limits)
    except NpzError as error:
        return [error.cause], dict(NO_FINDINGS)
    return check_arrays(arrays), quality_findings(arrays, flicker_max_fraction)


def quality_findings(
    arrays: dict[str, np.ndarray], flicker_max_fraction: float = FLICKER_MAX_FRACTION
) -> dict:
    """Counts of defects that do not break the schema but matter to users of a clip.

    ``hidden_queries``: tracks with visibility[t_q, i] False; ``off_image_visible``: tracks marked
    visible [T, N] on some frame where tracks_XYZ [T, N, 3] has z <= 0 or projects outside
    [0, W) x [0, H) (None when the first frame's JPEG header gives no size); ``flickering``: tracks
    whose visibility changes state more than ``flicker_max_fraction`` x T times;
    ``query_residual_median_px`` and ``query_residual_max_px``: the distance from each query to the
    pinhole projection of its track at its query frame (tracks in front of the camera; None when
    none is), which the schema bounds by 0.5 px and a lens left in the frames exceeds (DriveTrack
    with ``drivetrack.undistort_frames=false``). Every value is None when the arrays are too
    malformed to look at (``check_arrays`` says why).
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
    size = jpeg_size(bytes(images[0])) if num_frames and images.dtype.kind == "S" else None
    off_image = None
    if size is not None:
        height, width = size
        xyz = tracks.astype(np.float64)
        inside = in_image(project(xyz, intrinsics.astype(np.float64)), width, height) & (xyz[..., 2] > 0)
        off_image = int(np.count_nonzero((visibility & ~inside).any(axis=0)))
    flicker_ok = passes_flicker(visibility_flips(visibility), num_frames, flicker_max_fraction)
    at_query = tracks[t_q, np.arange(num_tracks)].astype(np.float64)
    front = (at_query[:, 2] > 0) & np.isfinite(at_query).all(1) & np.isfinite(queries[:, :2]).all(1)
    residual = np.linalg.norm(
        project(at_query[front], intrinsics.astype(np.float64)) - queries[front, :2], axis=1
    )
    return {
        "tracks": num_tracks,
        "frames": num_frames,
        "image_hw": list(size) if size else None,
        "hidden_queries": int(np.count_nonzero(~visibility[t_q, np.arange(num_tracks)])),
        "off_image_visible": off_image,
        "flickering": int(np.count_nonzero(~flicker_ok)),
        "query_residual_median_px": round(float(np.median(residual)), 4) if len(residual) else None,
        "query_residual_max_px": round(float(residual.max()), 4) if len(residual) else None,
    }
