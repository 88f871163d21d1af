"""One ADT chunk's candidate clip: queries on object pixels (``queries.py``), rigid attachment,
depth-test visibility (``visibility.py``), the ``ClipRecord``.

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

import numpy as np

from pipeline.adt.queries import check_given_queries, draw_query_pixels, query_pixel_pools
from pipeline.adt.records import Chunk, DepthMetres, Frame, IdRuns, Instances
from pipeline.adt.rectify import stored_intrinsics
from pipeline.adt.settings import AdtConfig
from pipeline.adt.visibility import frame_visibility, pixel_at, pixel_centres, sample_depth
from pipeline.core.clip import ClipRecord, TrackStats
from pipeline.core.errors import InputError
from pipeline.core.geometry import invert_se3, unproject
from pipeline.core.sampling import rng_for
from pipeline.export.depth_export import dense_depth_mm, dense_export
from pipeline.filters.mask import agreement
from pipeline.io.given_queries import given_query_frames
from pipeline.sources import RunChoices


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


def carry(
    points_object: np.ndarray, cam_from_world: np.ndarray, world_from_object: np.ndarray, which: np.ndarray
) -> np.ndarray:
    """Paper eq. 3 at one frame: object points [N, 3], each of object ``which`` [N] among the
    objects' poses [K, 4, 4], and the camera [4, 4] -> camera points [N, 3] (one camera-from-object
    matrix per object, each track's product with it as when each track had its own)."""
    cam_from_object = (cam_from_world[None] @ world_from_object)[which]
    return np.einsum("nij,nj->ni", cam_from_object[:, :3, :3], points_object) + cam_from_object[:, :3, 3]


def check_object_poses(frame: Frame, present: np.ndarray, instances: Instances, where: str) -> None:
    """Every object id in the frame's segmentation (``present`` [K]) must have a pose."""
    for object_id in present.tolist():
        if object_id and object_id not in instances.human and object_id not in frame.world_from_object:
            raise InputError(f"{where}: object {object_id} has no pose at t={frame.timestamp} ns")


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
    kept: list[tuple[Frame[IdRuns], frozenset[int]]]
    depth_maps: list[np.ndarray]
    queries: Queries


def query_frames_of(chunk: Chunk, given: np.ndarray | None, settings: AdtConfig, seed: int) -> np.ndarray:
    """The frame index [Q] of each query: the given queries', or drawn uniformly (seeded)."""
    num_frames = len(chunk.timestamps)
    if given is not None:
        return given_query_frames(given, num_frames, f"{chunk.unit} ({chunk.name})")
    total = settings.oversample * settings.tracks_per_clip
    return rng_for(seed, f"{chunk.name}/query_frames").integers(0, num_frames, total)


@dataclasses.dataclass(frozen=True)
class QueryPlan:
    """Where a chunk's queries come from: the given queries [Q, 3] (or None: drawn, seeded from
    ``seed``) and each query's frame index [Q]."""

    given: np.ndarray | None
    query_frames: np.ndarray
    seed: int


def frame_queries(
    chunk: Chunk,
    t: int,
    count: int,
    frame: Frame[np.ndarray],
    runs: IdRuns,
    instances: Instances,
    plan: QueryPlan,
    settings: AdtConfig,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Frame t's ``count`` queries: (x, y) [K, 2], depth [K] (metres), object id [K], and each one's
    index among the given queries (or its draw order) [K]."""
    if plan.given is not None:
        index = np.nonzero(plan.query_frames == t)[0]
        xy = plan.given[index, :2]
        rows, cols = pixel_at(xy, settings.image_size)
        depth = sample_depth(DepthMetres(frame.depth_mm), xy, max_spread=settings.depth_delta_m)
        check_given_queries(chunk, index, xy, depth, frame.ids[rows, cols], instances, frame)
    else:
        dynamic_pool, static_pool = query_pixel_pools(frame, runs, instances)
        rng = rng_for(plan.seed, f"{chunk.name}/query_pixels/{t}")
        flat = draw_query_pixels(dynamic_pool, static_pool, count, settings.dynamic_share, rng)
        rows, cols = np.divmod(flat, settings.image_size)
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
    chunk: Chunk,
    read_frame: Callable[[int], Frame[np.ndarray]],
    read_jpeg: Callable[[int], bytes],
    instances_of: Callable[[np.ndarray], Instances],
    plan: QueryPlan,
    settings: AdtConfig,
    export_depth: bool,
) -> FirstPass:
    """Read each frame once: encode it, keep it (ids as runs), draw (or match) its queries and
    attach them to their objects."""
    intrinsics = stored_intrinsics(settings.image_size, settings.focal)
    per_frame = np.bincount(plan.query_frames, minlength=len(chunk.timestamps))
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
        made.kept.append((frame.with_runs(runs), instances.human))
        if export_depth:
            made.depth_maps.append(dense_depth_mm(frame.depth_m()))
        if not per_frame[t]:
            continue
        count = int(per_frame[t])
        xy, depth, ids, index = frame_queries(chunk, t, count, frame, runs, instances, plan, settings)
        q_points.append(attach(xy, depth, intrinsics, frame.cam_from_world, object_poses(frame, ids)))
        q_xy.append(xy)
        q_t.append(np.full(len(xy), t, dtype=np.int64))
        q_ids.append(ids)
        q_index.append(index)
    if not q_xy or not sum(len(x) for x in q_xy):
        raise InputError(f"{chunk.unit}: no pixel with depth on an object in any frame; no query")
    order = np.argsort(np.concatenate(q_index), kind="stable") if plan.given is not None else slice(None)
    made.queries = Queries(
        np.concatenate(q_xy)[order],
        np.concatenate(q_t)[order],
        np.concatenate(q_points)[order],
        np.concatenate(q_ids)[order],
    )
    return made


def carry_tracks(
    chunk: Chunk, kept: list[tuple[Frame[IdRuns], frozenset[int]]], queries: Queries, settings: AdtConfig
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every track through every kept frame: points [T, N, 3], visibility [T, N], and whether each
    point lies on its own object's pixels [T, N]."""
    intrinsics = stored_intrinsics(settings.image_size, settings.focal)
    count = len(queries.xy)
    tracks = np.zeros((len(kept), count, 3))
    visibility = np.zeros((len(kept), count), bool)
    on_own_object = np.zeros((len(kept), count), bool)
    unique_ids, which = np.unique(queries.object_ids, return_inverse=True)
    objects = unique_ids.tolist()
    for t, (frame, human) in enumerate(kept):
        missing = [i for i in objects if i not in frame.world_from_object]
        if missing:
            raise InputError(f"{chunk.unit}: object {missing[0]} has no pose at t={frame.timestamp} ns")
        poses = np.stack([frame.world_from_object[i] for i in objects])
        points = carry(queries.points_object, frame.cam_from_world, poses, which)
        tracks[t] = points
        depth = DepthMetres(frame.depth_mm)
        visibility[t], on_own_object[t] = frame_visibility(
            points, queries.object_ids, depth, frame.ids, human, intrinsics, settings.depth_delta_m
        )
    return tracks, visibility, on_own_object


def candidate_clip(
    chunk: Chunk,
    read_frame: Callable[[int], Frame[np.ndarray]],
    read_jpeg: Callable[[int], bytes],
    instances_of: Callable[[np.ndarray], Instances],
    settings: AdtConfig,
    choices: RunChoices,
) -> ClipRecord:
    """Candidate tracks of one chunk (``oversample`` x ``tracks_per_clip`` before filtering).

    Args:
      read_frame: timestamp -> Frame (re-rendered depth, ids and poses), called once per frame.
      read_jpeg: timestamp -> the stored RGB frame as JPEG bytes, called once per frame.
      instances_of: the ids present in a frame [K] -> which are human / dynamic.
    """
    given = choices.given.of(chunk.name)
    plan = QueryPlan(given, query_frames_of(chunk, given, settings, choices.seed), choices.seed)
    made = first_pass(chunk, read_frame, read_jpeg, instances_of, plan, settings, choices.export_depth)
    queries = made.queries
    tracks, visibility, on_own_object = carry_tracks(chunk, made.kept, queries, settings)
    dynamic_ids = instances_of(np.unique(queries.object_ids)).dynamic
    dynamic = (
        np.isin(queries.object_ids, list(dynamic_ids)) if dynamic_ids else np.zeros(len(queries.xy), bool)
    )
    return ClipRecord(
        source="adt",
        name=chunk.name,
        unit=chunk.unit,
        images_jpeg=made.jpegs,
        fx_fy_cx_cy=stored_intrinsics(settings.image_size, settings.focal),
        image_size=(settings.image_size, settings.image_size),
        extrinsics_w2c=np.stack(made.extrinsics),
        tracks_xyz=tracks,
        visibility=visibility,
        queries_xyt=np.concatenate([queries.xy, queries.t[:, None].astype(np.float64)], axis=1),
        frame_ids=np.asarray(chunk.timestamps, dtype=np.int64),
        track_stats=TrackStats(
            agreement(on_own_object, visibility, np.ones(len(made.kept), bool)),
            {"object_id": queries.object_ids.astype(np.uint64), "dynamic": dynamic},
        ),
        target_tracks=settings.tracks_per_clip,
        given_queries=given is not None,
        depth_export=dense_export(made.depth_maps, chunk.timestamps) if choices.export_depth else None,
    )
