"""The clip record every source's annotate stage emits, in one shared shape."""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass
class ClipRecord:
    """One clip with its candidate tracks, before or after filtering.

    T frames, N tracks. Tracks live in the camera frame of each frame (OpenCV axes, metres).

    Attributes:
      source: 'adt', 'drivetrack' or 'pstudio'.
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
      track_stats: per-track statistics the filters read, each [N].
      target_tracks: how many tracks the released clip keeps.
      depth_export: with ``--export-depth``, the depth the visibility test read
        (pipeline/export/depth_export.py), written beside the clip; else None.
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
    track_stats: dict[str, np.ndarray]
    target_tracks: int
    given_queries: bool = False
    depth_export: dict[str, np.ndarray] | None = None
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
            track_stats={key: value[indices] for key, value in self.track_stats.items()},
            track_keys=None if self.track_keys is None else self.track_keys[indices],
        )
