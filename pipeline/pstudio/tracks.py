"""One Panoptic Studio camera's candidate clip, on arrays (no Beam, no files). Every camera's masks
are read first (``read_masks``), so a bad one fails the unit before the Gaussian work.

1. Queries: pixels on the unit camera's foreground mask at random frames; the splats' median
   depth (pipeline/pstudio/render.py) rendered at those pixels' centres; unprojected; attached
   to the nearest foreground Gaussian centre at that frame (pipeline/pstudio/nearest.py). The
   track is that centre at every frame, in the camera frame.
2. Visibility per frame: in the image, in front, and |z - D(u, v)| < delta, with D the median
   depth of all Gaussians at the track's projection, where the transmittance drops below 0.5
   there (no hand term for this source).
3. A candidate is kept only if it is visible at its own query frame; the query (x, y) is the
   centre's projection there.
4. Multi-view mask statistic (``multiview_masks.py``): over every (frame, camera) pair where the
   centre projects into the image, the fraction that lands on that camera's foreground mask.
"""

from __future__ import annotations

import numpy as np

from pipeline.core.clip import ClipRecord, TrackStats
from pipeline.core.errors import InputError
from pipeline.core.geometry import invert_se3, project, transform_points, unproject
from pipeline.core.sampling import rng_for
from pipeline.core.visibility import in_view, passes_dense_depth_test
from pipeline.core.windows import Window
from pipeline.export.depth_export import dense_depth_mm, dense_export
from pipeline.io.given_queries import given_query_frames
from pipeline.pstudio.multiview_masks import multiview_mask_fraction
from pipeline.pstudio.nearest import nearest_centres
from pipeline.pstudio.records import UnitInput
from pipeline.pstudio.render import render_depth_at, render_depth_image
from pipeline.pstudio.settings import PstudioConfig
from pipeline.pstudio.splats import Splats2D, project_splats
from pipeline.pstudio.units import SequenceCamera, clip_name
from pipeline.sources import RunChoices


def unit_clip(unit: UnitInput) -> Window:
    """The unit's clip: its window of a cut sequence, else the camera's whole sequence, named
    ``<sequence>_<camera>``."""
    return unit.window or Window(clip_name(unit.sequence, unit.camera_id), 0, unit.gaussians.num_frames)


def splats_in_view(
    unit: UnitInput, view: int, t: int, points_uv: np.ndarray | None = None, limits: np.ndarray | None = None
) -> Splats2D:
    """The Gaussians of frame t projected into camera ``view`` (all of them are occluders);
    with ``points_uv`` [P, 2], only those that can reach the blocks of those points; with
    ``limits`` [P], only those no deeper than a limit there (``project_splats``)."""
    g, v = unit.gaussians, unit.views
    return project_splats(
        g.means[t],
        g.quaternions[t],
        unit.constants,
        v.w2c[view],
        v.fx_fy_cx_cy[view],
        v.width,
        v.height,
        points_uv,
        limits,
    )


def attach_queries(
    unit: UnitInput, attempts: int, max_attach_distance_m: float, seed: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Draw ``attempts`` query pixels on the unit camera's mask at random frames; attach the
    surface rendered at each pixel's centre to the nearest foreground Gaussian centre there.

    Returns (query frames [A], Gaussian indices [A], attachment distances [A] in metres) for the
    attempts that hit a surface within ``max_attach_distance_m`` of a centre (0: at any distance),
    in draw order, each Gaussian at most once.
    """
    view = unit.views.index(unit.camera_id)
    intrinsics = unit.views.fx_fy_cx_cy[view]
    world_from_cam = invert_se3(unit.views.w2c[view])
    foreground = np.nonzero(unit.gaussians.foreground)[0]
    rng = rng_for(seed, f"{unit_clip(unit).name}/queries")
    frames = rng.integers(0, unit.gaussians.num_frames, size=attempts)
    draws = rng.random(attempts)
    gaussian = np.full(attempts, -1)
    distance = np.full(attempts, np.nan)
    within = max_attach_distance_m or np.inf
    for t in np.unique(frames):
        on_mask = np.flatnonzero(unit.mask(view, int(t)))  # row-major, as np.nonzero's (row, column)
        picked = np.nonzero(frames == t)[0]
        if not len(on_mask):
            continue
        choice = on_mask[np.minimum((draws[picked] * len(on_mask)).astype(np.int64), len(on_mask) - 1)]
        rows, cols = np.divmod(choice, unit.views.width)
        pixels = np.stack([cols, rows], axis=1) + 0.5
        depth, surface = render_depth_at(splats_in_view(unit, view, int(t), pixels), pixels)
        points = transform_points(world_from_cam, unproject(pixels[surface], depth[surface], intrinsics))
        nearest_distance, nearest = nearest_centres(unit.gaussians.means[t], foreground, points, within)
        close = nearest >= 0  # a centre within reach (nearest_centres gives -1 where none is)
        gaussian[picked[surface][close]] = foreground[nearest[close]]
        distance[picked[surface][close]] = nearest_distance[close]
    hit = np.nonzero(gaussian >= 0)[0]
    _, first = np.unique(gaussian[hit], return_index=True)
    keep = hit[np.sort(first)]
    return frames[keep], gaussian[keep], distance[keep]


def match_given_queries(unit: UnitInput, queries: np.ndarray) -> np.ndarray:
    """The foreground Gaussian behind each given query [N, 3] (x, y, t): among the centres that
    project within half a pixel of (x, y) at t, the one whose depth is nearest the rendered
    depth there (the release moved each query onto its centre's projection); failing that, the
    centre nearest the unprojected query point. Returns Gaussian indices [N]."""
    view = unit.views.index(unit.camera_id)
    intrinsics = unit.views.fx_fy_cx_cy[view]
    world_from_cam = invert_se3(unit.views.w2c[view])
    foreground = np.nonzero(unit.gaussians.foreground)[0]
    name = unit_clip(unit).name
    frames = given_query_frames(queries, unit.gaussians.num_frames, name)
    chosen = np.empty(len(queries), np.int64)
    for t in np.unique(frames):
        rows = np.nonzero(frames == t)[0]
        pixels = queries[rows, :2]
        depth, surface = render_depth_at(splats_in_view(unit, view, int(t), pixels), pixels)
        centres = transform_points(
            unit.views.w2c[view], unit.gaussians.means[t, foreground].astype(np.float64)
        )
        projected = project(centres, intrinsics)
        for row, pixel, z, hit in zip(rows, pixels, depth, surface, strict=True):
            near = np.nonzero((centres[:, 2] > 0) & (np.linalg.norm(projected - pixel, axis=1) <= 0.5))[0]
            if len(near) and hit:
                chosen[row] = foreground[near[np.argmin(np.abs(centres[near, 2] - z))]]
            elif hit:
                point = transform_points(world_from_cam, unproject(pixel[None], np.array([z]), intrinsics))
                chosen[row] = foreground[nearest_centres(unit.gaussians.means[t], foreground, point)[1][0]]
            else:
                raise InputError(
                    f"{name}: given query {row} at ({pixel[0]:.1f}, {pixel[1]:.1f}, t={t}) "
                    "has no splat surface and no foreground centre within half a pixel"
                )
    return chosen


def track_visibility(
    unit: UnitInput, gaussians: np.ndarray, delta: float, export_depth: bool = False
) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """Tracks [T, K, 3] (camera frame) of Gaussian centres [K] and their visibility [T, K] (depth
    test within ``delta`` metres); with ``export_depth``, also each frame's full depth map as uint16
    millimetres [H, W], 0 where there is no surface (else [])."""
    view = unit.views.index(unit.camera_id)
    intrinsics = unit.views.fx_fy_cx_cy[view]
    frames = unit.gaussians.num_frames
    tracks = np.empty((frames, len(gaussians), 3))
    visible = np.zeros((frames, len(gaussians)), bool)
    depth_maps = []
    for t in range(frames):
        tracks[t] = transform_points(
            unit.views.w2c[view], unit.gaussians.means[t, gaussians].astype(np.float64)
        )
        seen = in_view(tracks[t], intrinsics, unit.views.width, unit.views.height)
        pixels = project(tracks[t, seen], intrinsics)
        # Where no splat takes the transmittance below 0.5 the depth is the 15 m background:
        # nothing is seen there, whatever the track's depth. A median depth beyond z + delta fails
        # the test whatever it is, so no splat deeper than that is projected or composited (the
        # limit's micrometre covers rounding).
        z = tracks[t, seen, 2]
        limits = z + delta + 1e-6
        if export_depth:  # every splat, for the full frame; the same projection serves the tracks
            splats = splats_in_view(unit, view, t)
            depth_image, surface_image = render_depth_image(splats)
            depth_maps.append(dense_depth_mm(np.where(surface_image, depth_image, np.nan)))
        elif seen.any():
            splats = splats_in_view(unit, view, t, pixels, limits)
        if seen.any():
            depth, surface = render_depth_at(splats, pixels, limits)
            visible[t, seen] = surface & passes_dense_depth_test(z, depth, delta)
    return tracks, visible, depth_maps


def track_first_visible(
    unit: UnitInput,
    query_frames: np.ndarray,
    gaussians: np.ndarray,
    wanted: int,
    delta: float,
    export_depth: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[np.ndarray]]:
    """``track_visibility`` of the first ``wanted`` candidates (query frames [A], Gaussians [A],
    in draw order) that are visible at their own query frame.

    A track's visibility does not depend on the tracks computed with it, so the candidates are
    tracked a batch at a time: the number still wanted and a margin (nearly every attached centre
    is seen at its query frame), more only if that fell short. The candidates past the batches
    (on the bench's dome, about 40% of them) are never tracked.

    Returns (kept [V] indices into the candidates, V <= wanted, tracks [T, V, 3], visible
    [T, V], the depth maps of ``track_visibility``, from the first batch).
    """
    kept, tracks, visible, depth_maps = [], [], [], None
    done = found = 0
    while depth_maps is None or (found < wanted and done < len(gaussians)):
        short = wanted - found
        batch = np.arange(done, min(len(gaussians), done + short + short // 16 + 8))
        first = depth_maps is None
        batch_tracks, batch_visible, maps = track_visibility(
            unit, gaussians[batch], delta, export_depth and first
        )
        depth_maps = maps if depth_maps is None else depth_maps
        seen = np.nonzero(batch_visible[query_frames[batch], np.arange(len(batch))])[0][:short]
        kept.append(batch[seen])
        tracks.append(batch_tracks[:, seen])
        visible.append(batch_visible[:, seen])
        done, found = done + len(batch), found + len(seen)
    return np.concatenate(kept), np.concatenate(tracks, axis=1), np.concatenate(visible, axis=1), depth_maps


def read_masks(unit: UnitInput) -> None:
    """Read every camera's mask at every frame, as the multi-view mask statistic will: a missing or
    bad mask fails the unit before any Gaussian is projected (each is decoded once, then cached).
    A mask is checked by its packed length, without unpacking it: the statistic's kernel reads
    its bits by pixel index."""
    views, clip = unit.views, unit_clip(unit)
    size = -(-views.width * views.height // 8)
    for t in range(unit.gaussians.num_frames):
        for view in range(len(views.camera_ids)):
            packed = unit.packed_mask(view, t)
            if packed.dtype != np.uint8 or packed.shape != (size,):
                raise InputError(
                    f"{clip.name}: the mask of camera {views.camera_ids[view]} at frame {clip.start + t} "
                    f"is {packed.dtype} {packed.shape}, not {views.width}x{views.height} pixels bit-packed "
                    f"(uint8 ({size},))"
                )


def candidate_clip(unit: UnitInput, settings: PstudioConfig, choices: RunChoices) -> ClipRecord:
    """The unit's candidate clip: oversampled tracks with their statistics (the queries of
    ``--queries-from``'s clip of its name, when it holds one)."""
    wanted = settings.tracks_per_clip * settings.oversample
    delta, export_depth = settings.depth_delta_m, choices.export_depth
    clip = unit_clip(unit)
    queries = choices.given.of(clip.name)
    read_masks(unit)
    if queries is not None:
        gaussians = match_given_queries(unit, queries)
        query_frames, distance = queries[:, 2].astype(np.int64), np.full(len(queries), np.nan)
        tracks, visible, depth_maps = track_visibility(unit, gaussians, delta, export_depth)
        valid = np.arange(len(gaussians))
    else:
        query_frames, gaussians, distance = attach_queries(
            unit, 2 * wanted, settings.max_attach_distance_m, choices.seed
        )
        valid, tracks, visible, depth_maps = track_first_visible(
            unit, query_frames, gaussians, wanted, delta, export_depth
        )
    query_frames, gaussians, distance = query_frames[valid], gaussians[valid], distance[valid]
    view = unit.views.index(unit.camera_id)
    intrinsics = unit.views.fx_fy_cx_cy[view]
    query_xy = project(tracks[query_frames, np.arange(len(valid))], intrinsics)
    frame_ids = np.arange(clip.start, clip.stop, dtype=np.int64)
    return ClipRecord(
        source="pstudio",
        name=clip.name,
        unit=SequenceCamera(unit.sequence, unit.camera_id).name,
        images_jpeg=unit.frames_jpeg,
        fx_fy_cx_cy=intrinsics,
        image_size=(unit.views.width, unit.views.height),
        extrinsics_w2c=None,
        tracks_xyz=tracks,
        visibility=visible,
        queries_xyt=np.concatenate([query_xy, query_frames[:, None].astype(np.float64)], axis=1),
        frame_ids=frame_ids,
        track_stats=TrackStats(
            multiview_mask_fraction(unit, gaussians),
            {"attach_distance_m": distance, "gaussian_index": gaussians.astype(np.int64)},
        ),
        target_tracks=settings.tracks_per_clip,
        given_queries=queries is not None,
        depth_export=dense_export(depth_maps, frame_ids) if export_depth else None,
    )
