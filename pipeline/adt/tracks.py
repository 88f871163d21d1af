"""One ADT chunk's candidate tracks: queries on object pixels, rigid attachment, depth-test visibility.

Pure NumPy on frames already re-rendered to the stored camera (``rectify.py``): no
projectaria-tools here. All geometry is in the stored (upright pinhole) camera with its true
intrinsics (``stored_intrinsics``: (280, 280, 255.5, 256.5) for the release's camera, which is
what the clip's ``fx_fy_cx_cy`` holds) and pixel centres at +0.5 (pixel [r, c] covers
[c, c+1) x [r, r+1)).

Paper (docs/formats.md, section 2): Q_cam = K^-1 (x, y, 1) D(x, y); Q_obj = P_obj<-world(t_q)
P_world<-cam(t_q) Q_cam; Q_cam(t) = P_cam<-world(t) P_world<-obj(t) Q_obj; visible when in front,
in the image, |z - D_t(u, v)| < delta and not on the wearer's (human) pixels.

Each frame is read once: pass 1 encodes it, draws its queries and keeps its depth (float32
millimetres, 1 MiB at 512x512) and ids (``IdRuns``, about 0.1 MiB); pass 2 carries every track
through every kept frame. A 300-frame chunk keeps about 0.35 GiB of frames besides its JPEG bytes
and [T, N] / [T, N, 3] track arrays.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from pipeline.adt.records import Chunk, Frame, IdRuns, Instances
from pipeline.adt.rectify import stored_intrinsics
from pipeline.adt.settings import AdtConfig
from pipeline.core.clip import ClipRecord
from pipeline.core.errors import InputError
from pipeline.core.geometry import in_image, invert_se3, project, unproject
from pipeline.core.sampling import rng_for
from pipeline.export.depth_export import dense_depth_mm, dense_record
from pipeline.io.given_queries import given_queries, given_query_frames

if TYPE_CHECKING:
    from pipeline.settings.run_config import RunConfig

# ------------------------------------------------------------------------------------ pixels


def pixel_centres(rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Continuous coordinates [N, 2] (x, y) of pixel centres."""
    return np.stack([cols + 0.5, rows + 0.5], axis=-1).astype(np.float64)


def pixel_at(xy: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols) [N] of the pixels containing points [N, 2] (clamped into the image)."""
    cols = np.clip(np.floor(xy[:, 0]), 0, size - 1).astype(np.int64)
    rows = np.clip(np.floor(xy[:, 1]), 0, size - 1).astype(np.int64)
    return rows, cols


def sample_depth(depth: np.ndarray, xy: np.ndarray, max_spread: float = np.inf) -> np.ndarray:
    """Depth [N] at continuous points [N, 2]: bilinear between the four nearest pixel centres
    when all four hold a surface and differ by at most ``max_spread`` (one surface, not an
    edge between two), else the containing pixel's value; NaN where there is none.

    At a pixel centre it returns that pixel's value exactly.
    """
    size_y, size_x = depth.shape
    x, y = xy[:, 0] - 0.5, xy[:, 1] - 0.5
    x0 = np.clip(np.floor(x), 0, size_x - 1).astype(np.int64)
    y0 = np.clip(np.floor(y), 0, size_y - 1).astype(np.int64)
    x1, y1 = np.minimum(x0 + 1, size_x - 1), np.minimum(y0 + 1, size_y - 1)
    fx, fy = np.clip(x - x0, 0.0, 1.0), np.clip(y - y0, 0.0, 1.0)
    d00, d01 = depth[y0, x0].astype(np.float64), depth[y0, x1].astype(np.float64)
    d10, d11 = depth[y1, x0].astype(np.float64), depth[y1, x1].astype(np.float64)
    bilinear = d00 * (1 - fx) * (1 - fy) + d01 * fx * (1 - fy) + d10 * (1 - fx) * fy + d11 * fx * fy
    rows, cols = pixel_at(xy, size_x)
    nearest = depth[rows, cols].astype(np.float64)
    corners = np.stack([d00, d01, d10, d11])
    complete = (corners.min(axis=0) > 0) & (corners.max(axis=0) - corners.min(axis=0) <= max_spread)
    out = np.where(complete, bilinear, nearest)
    return np.where(out > 0, out, np.nan)


def interior(ids: np.ndarray) -> np.ndarray:
    """[S, S] bool: pixels whose 3x3 neighbourhood (inside the image) holds one id (their depth
    is not a blend of two surfaces: the re-rendering interpolates depth bilinearly across edges).

    Each of the 4 neighbour directions is compared once; both pixels of an unequal pair fail.
    """
    height, width = ids.shape
    same = np.ones(ids.shape, bool)
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        here = (slice(0, height - dr), slice(max(0, -dc), width - max(0, dc)))
        there = (slice(dr, height), slice(max(0, dc), width + min(0, dc)))
        equal = ids[here] == ids[there]
        same[here] &= equal
        same[there] &= equal
    return same


# ------------------------------------------------------------------------------------ queries


def query_pixel_pools(frame: Frame, runs: IdRuns, instances: Instances) -> tuple[np.ndarray, np.ndarray]:
    """Flat pixel indices that may hold a query: (on dynamic objects, on static objects).

    A query pixel has a surface (depth > 0), an object id (not 0, not the human) and lies
    inside its object's region (``interior``). ``runs``: the frame's ids as ``IdRuns``.
    """
    ids = frame.ids
    ok = (frame.depth_mm > 0) & (ids != 0) & interior(ids)
    if instances.human:
        ok &= ~runs.isin(instances.human)
    dynamic = ok & runs.isin(instances.dynamic) if instances.dynamic else np.zeros_like(ok)
    return np.flatnonzero(dynamic), np.flatnonzero(ok & ~dynamic)


def draw_query_pixels(
    dynamic_pool: np.ndarray, static_pool: np.ndarray, count: int, dynamic_share: float, rng
) -> np.ndarray:
    """``count`` distinct flat pixel indices (fewer if the pools are smaller): a share
    ``dynamic_share`` from the dynamic pool when it is not empty, the rest from the static one
    (topped up from the other pool when one runs short)."""
    want_dynamic = min(len(dynamic_pool), int(round(dynamic_share * count))) if len(dynamic_pool) else 0
    want_static = min(len(static_pool), count - want_dynamic)
    want_dynamic = min(len(dynamic_pool), count - want_static)
    chosen = [
        rng.choice(dynamic_pool, size=want_dynamic, replace=False),
        rng.choice(static_pool, size=want_static, replace=False),
    ]
    return np.concatenate(chosen).astype(np.int64)


def attach(
    xy: np.ndarray,
    depth: np.ndarray,
    fx_fy_cx_cy: np.ndarray,
    cam_from_world: np.ndarray,
    world_from_object: np.ndarray,
) -> np.ndarray:
    """Query points in their objects' frames (paper eq. 1-2).

    Args:
      xy: [N, 2] query pixels; depth: [N] z-depth there (metres).
      cam_from_world: [4, 4] at the query frame; world_from_object: [N, 4, 4] each query's object.
    Returns:
      [N, 3] points in object coordinates.
    """
    points_cam = unproject(xy, depth, fx_fy_cx_cy)
    object_from_cam = invert_se3(world_from_object) @ invert_se3(cam_from_world)[None]
    return np.einsum("nij,nj->ni", object_from_cam[:, :3, :3], points_cam) + object_from_cam[:, :3, 3]


def carry(points_object: np.ndarray, cam_from_world: np.ndarray, world_from_object: np.ndarray) -> np.ndarray:
    """Paper eq. 3 at one frame: object points [N, 3] with their objects' poses [N, 4, 4] and the
    camera [4, 4] -> camera points [N, 3]."""
    cam_from_object = cam_from_world[None] @ world_from_object
    return np.einsum("nij,nj->ni", cam_from_object[:, :3, :3], points_object) + cam_from_object[:, :3, 3]


def frame_visibility(
    points_cam: np.ndarray,
    object_ids: np.ndarray,
    depth: np.ndarray,
    ids: np.ndarray | IdRuns,
    human_ids: frozenset[int],
    fx_fy_cx_cy: np.ndarray,
    delta: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Visibility (paper eq. 4) and own-id agreement of N points at one frame.

    Args:
      points_cam: [N, 3] stored-camera points; object_ids: [N] each point's object.
      depth: [S, S] metres; ids: [S, S] instance ids (an array or ``IdRuns``); human_ids: the
        wearer's ids (the hand term).
    Returns:
      visible: [N] bool, in front, inside the image, |z - D(u, v)| < delta, not on a human pixel.
        D is bilinear where the four pixels around (u, v) agree within delta, else the
        containing pixel's depth (no blending across a depth edge).
      on_own_id: [N] bool, the id at the point's pixel is its own object's.
    """
    size = depth.shape[1]
    xy = project(points_cam, fx_fy_cx_cy)
    inside = (points_cam[:, 2] > 0) & in_image(xy, size, depth.shape[0])
    visible = np.zeros(len(points_cam), bool)
    on_own = np.zeros(len(points_cam), bool)
    if not inside.any():
        return visible, on_own
    xy_in = xy[inside]
    rows, cols = pixel_at(xy_in, size)
    pixel_ids = ids[rows, cols]
    surface = sample_depth(depth, xy_in, max_spread=delta)
    with np.errstate(invalid="ignore"):
        close = np.abs(points_cam[inside, 2] - surface) < delta
    not_human = ~np.isin(pixel_ids, list(human_ids)) if human_ids else np.ones(len(rows), bool)
    visible[inside] = close & not_human
    on_own[inside] = pixel_ids == object_ids[inside]
    return visible, on_own


def check_object_poses(frame: Frame, present: np.ndarray, instances: Instances, where: str) -> None:
    """Every object id in the frame's segmentation (``present`` [K]) must have a pose."""
    for object_id in present.tolist():
        if object_id and object_id not in instances.human and object_id not in frame.world_from_object:
            raise InputError(f"{where}: object {object_id} has no pose at t={frame.timestamp} ns")


def check_given_queries(chunk, index, xy, depth, ids, instances: Instances, frame: Frame) -> None:
    """Given queries [K] must land on an object's surface, or the correspondence is lost."""
    bad = ~np.isfinite(depth) | (ids == 0) | np.isin(ids, list(instances.human) or [0])
    bad |= ~np.isin(ids, list(frame.world_from_object) or [0])
    if bad.any():
        k = int(np.nonzero(bad)[0][0])
        raise InputError(
            f"{chunk.unit}: given query {int(index[k])} of {chunk.name} at ({xy[k, 0]:.1f}, {xy[k, 1]:.1f}) "
            f"lands on no posed object surface (id {int(ids[k])}) in this re-annotation"
        )


@dataclasses.dataclass(frozen=True)
class Queries:
    """A chunk's queries, attached: pixel (x, y) [Q, 2], frame index [Q], the point in its object's
    frame [Q, 3] and the object's id [Q] (in the given queries' order, or in draw order)."""

    xy: np.ndarray
    t: np.ndarray
    points_object: np.ndarray
    object_ids: np.ndarray


@dataclasses.dataclass
class FirstPass:
    """What one read of a chunk's frames keeps: JPEGs [T], world-to-camera [T] x [4, 4], each frame
    (ids as runs) with its human ids, exported depth [T] (``--export-depth``), and the queries."""

    jpegs: list[bytes]
    extrinsics: list[np.ndarray]
    kept: list[tuple[Frame, frozenset[int]]]
    depth_maps: list[np.ndarray]
    queries: Queries


def query_frames_of(chunk: Chunk, given: np.ndarray | None, config: RunConfig) -> np.ndarray:
    """The frame index [Q] of each query: the given queries', or drawn uniformly (seeded)."""
    num_frames = len(chunk.timestamps)
    if given is not None:
        return given_query_frames(given, num_frames, f"{chunk.unit} ({chunk.name})")
    total = config.adt.oversample * config.adt.tracks_per_clip
    return rng_for(config.seed, f"{chunk.name}/query_frames").integers(0, num_frames, total)


def frame_queries(
    chunk: Chunk,
    t: int,
    count: int,
    frame: Frame,
    runs: IdRuns,
    instances: Instances,
    given,
    query_frames,
    config,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Frame t's ``count`` queries: (x, y) [K, 2], depth [K] (metres), object id [K], and each one's
    index among the given queries (or its draw order) [K]."""
    rules = config.adt
    if given is not None:
        index = np.nonzero(query_frames == t)[0]
        xy = given[index, :2]
        rows, cols = pixel_at(xy, rules.image_size)
        depth = sample_depth(frame.depth_m(), xy, max_spread=rules.depth_delta_m)
        check_given_queries(chunk, index, xy, depth, frame.ids[rows, cols], instances, frame)
    else:
        dynamic_pool, static_pool = query_pixel_pools(frame, runs, instances)
        rng = rng_for(config.seed, f"{chunk.name}/query_pixels/{t}")
        flat = draw_query_pixels(dynamic_pool, static_pool, count, rules.dynamic_share, rng)
        rows, cols = np.divmod(flat, rules.image_size)
        xy = pixel_centres(rows, cols)
        depth = frame.depth_mm[rows, cols].astype(np.float64) / 1000.0
        index = np.arange(len(flat))
    return xy, depth, frame.ids[rows, cols], index


def object_poses(frame: Frame, ids: np.ndarray) -> np.ndarray:
    """World-from-object poses [K, 4, 4] of the objects ``ids`` [K] (each looked up once)."""
    if not len(ids):
        return np.zeros((0, 4, 4))
    posed, which = np.unique(ids, return_inverse=True)
    return np.stack([frame.world_from_object[i] for i in posed.tolist()])[which]


def first_pass(
    chunk: Chunk, read_frame, read_jpeg, instances_of, given: np.ndarray | None, config: RunConfig
) -> FirstPass:
    """Read each frame once: encode it, keep it (ids as runs), draw (or match) its queries and
    attach them to their objects."""
    intrinsics = stored_intrinsics(config.adt.image_size, config.adt.focal)
    query_frames = query_frames_of(chunk, given, config)
    per_frame = np.bincount(query_frames, minlength=len(chunk.timestamps))
    made = FirstPass([], [], [], [], Queries(*(np.zeros(0),) * 4))
    q_xy, q_t, q_points, q_ids, q_index = [], [], [], [], []
    for t, timestamp in enumerate(chunk.timestamps.tolist()):
        made.jpegs.append(read_jpeg(timestamp))
        frame = read_frame(timestamp)
        made.extrinsics.append(frame.cam_from_world)
        runs = IdRuns.of(frame.ids)
        present = runs.unique()
        instances = instances_of(present)
        check_object_poses(frame, present, instances, chunk.unit)
        made.kept.append((dataclasses.replace(frame, ids=runs), instances.human))
        if config.export_depth:
            made.depth_maps.append(dense_depth_mm(frame.depth_m()))
        if not per_frame[t]:
            continue
        xy, depth, ids, index = frame_queries(
            chunk, t, int(per_frame[t]), frame, runs, instances, given, query_frames, config
        )
        q_points.append(attach(xy, depth, intrinsics, frame.cam_from_world, object_poses(frame, ids)))
        q_xy.append(xy)
        q_t.append(np.full(len(xy), t, dtype=np.int64))
        q_ids.append(ids)
        q_index.append(index)
    if not q_xy or not sum(len(x) for x in q_xy):
        raise InputError(f"{chunk.unit}: no pixel with depth on an object in any frame; no query")
    order = np.argsort(np.concatenate(q_index), kind="stable") if given is not None else slice(None)
    made.queries = Queries(
        np.concatenate(q_xy)[order],
        np.concatenate(q_t)[order],
        np.concatenate(q_points)[order],
        np.concatenate(q_ids)[order],
    )
    return made


def carry_tracks(
    chunk: Chunk, kept: list[tuple[Frame, frozenset[int]]], queries: Queries, config: RunConfig
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every track through every kept frame: points [T, N, 3], visibility [T, N], and per track the
    visible frames on its own object's pixels [N]."""
    rules = config.adt
    intrinsics = stored_intrinsics(rules.image_size, rules.focal)
    count = len(queries.xy)
    tracks = np.zeros((len(kept), count, 3))
    visibility = np.zeros((len(kept), count), bool)
    agree = np.zeros(count, np.int64)
    unique_ids, track_object = np.unique(queries.object_ids, return_inverse=True)
    for t, (frame, human) in enumerate(kept):
        missing = [i for i in unique_ids.tolist() if i not in frame.world_from_object]
        if missing:
            raise InputError(f"{chunk.unit}: object {missing[0]} has no pose at t={frame.timestamp} ns")
        poses = np.stack([frame.world_from_object[i] for i in unique_ids.tolist()])[track_object]
        points = carry(queries.points_object, frame.cam_from_world, poses)
        visible, on_own = frame_visibility(
            points, queries.object_ids, frame.depth_m(), frame.ids, human, intrinsics, rules.depth_delta_m
        )
        tracks[t], visibility[t] = points, visible
        agree += visible & on_own
    return tracks, visibility, agree


def annotate_chunk(
    chunk: Chunk,
    read_frame: Callable[[int], Frame],
    read_jpeg: Callable[[int], bytes],
    instances_of: Callable[[np.ndarray], Instances],
    config: RunConfig,
) -> ClipRecord:
    """Candidate tracks of one chunk (``oversample`` x ``tracks_per_clip`` before filtering).

    Args:
      read_frame: timestamp -> Frame (re-rendered depth, ids and poses), called once per frame.
      read_jpeg: timestamp -> the stored RGB frame as JPEG bytes, called once per frame.
      instances_of: the ids present in a frame [K] -> which are human / dynamic.
    """
    rules: AdtConfig = config.adt
    given = given_queries(config.queries_from, "adt", chunk.name, config.http)
    made = first_pass(chunk, read_frame, read_jpeg, instances_of, given, config)
    queries = made.queries
    tracks, visibility, agree = carry_tracks(chunk, made.kept, queries, config)
    visible_frames = visibility.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        agreement = np.where(visible_frames > 0, agree / np.maximum(visible_frames, 1), np.nan)
    dynamic_ids = instances_of(np.unique(queries.object_ids)).dynamic
    dynamic = (
        np.isin(queries.object_ids, list(dynamic_ids)) if dynamic_ids else np.zeros(len(queries.xy), bool)
    )
    return ClipRecord(
        source="adt",
        name=chunk.name,
        unit=chunk.unit,
        images_jpeg=made.jpegs,
        fx_fy_cx_cy=stored_intrinsics(rules.image_size, rules.focal),
        image_size=(rules.image_size, rules.image_size),
        extrinsics_w2c=np.stack(made.extrinsics),
        tracks_xyz=tracks,
        visibility=visibility,
        queries_xyt=np.concatenate([queries.xy, queries.t[:, None].astype(np.float64)], axis=1),
        frame_ids=np.asarray(chunk.timestamps, dtype=np.int64),
        track_stats={
            "mask_agreement": agreement,
            "visible_frames": visible_frames.astype(np.int64),
            "object_id": queries.object_ids.astype(np.uint64),
            "dynamic": dynamic,
        },
        target_tracks=rules.tracks_per_clip,
        given_queries=given is not None,
        depth_export=dense_record(made.depth_maps, chunk.timestamps) if config.export_depth else None,
    )
