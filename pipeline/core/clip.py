"""The clip record every source's annotate stage emits, in one shared shape."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping

import numpy as np


@dataclasses.dataclass(frozen=True)
class TrackStats:
    """What a source records of each candidate track for the filters and the audit, each [N].

    mask_agreement: [N] float64, the share of a track's visible frames (with a mask) where it lies
      on its own object's mask, NaN where it has none; None: the source has no masks (the mask
      filter passes every track).
    extra: name -> [N], the source's own statistics, kept in the audit table (ADT: object_id,
      dynamic; Panoptic Studio: attach_distance_m, gaussian_index).
    """

    mask_agreement: np.ndarray | None = None
    extra: Mapping[str, np.ndarray] = dataclasses.field(default_factory=dict)

    def select(self, indices: np.ndarray) -> TrackStats:
        """The statistics of the tracks at ``indices`` [K] (in that order)."""
        return TrackStats(
            None if self.mask_agreement is None else self.mask_agreement[indices],
            {name: values[indices] for name, values in self.extra.items()},
        )


@dataclasses.dataclass(frozen=True)
class DenseDepth:
    """The depth images a clip's visibility test read (ADT's re-rendered depth, Panoptic Studio's
    splat depth): depth_mm uint16 [T, H, W] millimetres of z-depth, 0 where there is no surface;
    frame_ids int64 [T]."""

    depth_mm: np.ndarray
    frame_ids: np.ndarray


@dataclasses.dataclass(frozen=True)
class SparseDepth:
    """The depth points a clip's visibility test read (DriveTrack's projected lidar): uv float32
    [M, 2] pixels, z float32 [M] metres, frame_offsets int64 [T + 1] (frame t's points are rows
    ``frame_offsets[t]:frame_offsets[t + 1]``), frame_ids int64 [T]."""

    uv: np.ndarray
    z: np.ndarray
    frame_offsets: np.ndarray
    frame_ids: np.ndarray


@dataclasses.dataclass
class ClipRecord:
    """One clip with its candidate tracks, before or after filtering.

    T frames, N tracks. Tracks live in the camera frame of each frame (OpenCV axes, metres).

    Attributes:
      source: the name of the registered source that made it (its folder, ``<out>/<source>/``).
      name: clip name without '.npz' (the release's naming).
      unit: the unit of work this clip came from, for tracing and error messages.
      images_jpeg: T JPEG-encoded frames, passed through from the source.
      fx_fy_cx_cy: [4] pinhole intrinsics of the stored frames.
      image_size: (width, height) of the stored frames in pixels.
      extrinsics_w2c: [T, 4, 4] world-to-camera, or None for static cameras.
      tracks_xyz: [T, N, 3] float64 points in the camera frame.
      visibility: [T, N] bool.
      queries_xyt: [N, 3] float64 (x, y, query frame index).
      frame_ids: [T] int64 source frame identifiers (timestamps or indices).
      track_stats: per-track statistics the filters and the audit read (``TrackStats``).
      target_tracks: how many tracks the released clip keeps.
      depth_export: with ``--export-depth``, the depth the visibility test read, written beside the
        clip (pipeline/export/depth_export.py); else None.
      given_queries: the queries came from an existing clip (``--queries-from``): filters report
        on every track but drop none, so old and new tracks correspond one to one.
      track_keys: [N] uint64 per-track draw keys, or None. With keys, the final subsample keeps
        the survivors with the lowest keys, so whether a track is kept does not depend on which
        other tracks exist (DriveTrack); without, a seeded draw among the survivors.
    """

    source: str
    name: str
    unit: str
    images_jpeg: list[bytes]
    fx_fy_cx_cy: np.ndarray
    image_size: tuple[int, int]
    extrinsics_w2c: np.ndarray | None
    tracks_xyz: np.ndarray
    visibility: np.ndarray
    queries_xyt: np.ndarray
    frame_ids: np.ndarray
    track_stats: TrackStats
    target_tracks: int
    given_queries: bool = False
    depth_export: DenseDepth | SparseDepth | None = None
    track_keys: np.ndarray | None = None

    @property
    def num_frames(self) -> int:
        return int(self.tracks_xyz.shape[0])

    @property
    def num_tracks(self) -> int:
        return int(self.tracks_xyz.shape[1])

    def select_tracks(self, indices: np.ndarray) -> ClipRecord:
        """A copy keeping only the tracks at ``indices`` [K] (in that order)."""
        return dataclasses.replace(
            self,
            tracks_xyz=self.tracks_xyz[:, indices],
            visibility=self.visibility[:, indices],
            queries_xyt=self.queries_xyt[indices],
            track_stats=self.track_stats.select(indices),
            track_keys=None if self.track_keys is None else self.track_keys[indices],
        )
