"""Refined visibility of a DriveTrack clip (``drivetrack.refined_visibility``): a track point is
visible in a frame when it is in view, its surface faces the camera, its own object does not hide it
and no other surface covers it.

- Facing: the normal fitted on the object's points of every sweep of the clip
  (``surface_normals``), not one sweep's range-image neighbours.
- Its own object: the camera's ray to the point crosses the object's surface seen in the sweeps of
  both halves of the clip (``object_surface.OwnSurface``) in front of the point.
- Other surfaces: the footprints of the sweeps of the frame and of its neighbours, objects moved to
  the frame by their boxes (``footprints``), cover the point nearer than it, weighed sweep by sweep
  (the frame's own counting double) and by how deep inside them the point lies. A surface that
  really passes in front of the point, even for one frame, covers it in the moved footprints of all
  three sweeps; one that only one sweep's sampling puts over the point's pixel is outvoted.

Nearer than the point means, for other surfaces, by the occlusion margin (a share of its depth), for
its own object by OWN_CLEARANCE_M; and always by SURFACE_TOLERANCE_M measured across the point's own
surface, which along a ray grazing that surface is far more: a surface seen edge-on is not hidden by
its own neighbourhood.

A clip's tracks read the other surfaces a frame at a time, as the lidar's second pass brings each
frame's footprints (``lidar.stream_occluders``): a unit holds a few frames' footprints, not all.
"""

from __future__ import annotations

import numpy as np

from pipeline.drivetrack.footprints import FrameOccluders, occluded_by_others, occluder_reach
from pipeline.drivetrack.object_surface import OwnSurface

OWN_CLEARANCE_M = 0.1
SURFACE_TOLERANCE_M = 0.03
# Below this cosine between a point's normal and its ray, the clearance across its surface counts as
# at this cosine.
MIN_RAY_COSINE = 0.05


class RefinedTracks:
    """The refined visibility of a clip's track points, its frames' occluders read one frame at a
    time as they come (``see``, in any order), its own object's surface at the end (``visibility``).

    tracks [T, N, 3] (camera frame, as seen), pixels [T, N, 2], in view where ``in_view`` [T, N]
    (``camera_model.Projection``); box_points, box_normals: [N, 3] each, the points and their fitted
    normals in the box frame; cam_from_box: [T, 4, 4]; surface: the object's own surface;
    own_label: the object's label among the footprints; occlusion_margin: the share of a point's
    depth another surface must be nearer by."""

    def __init__(
        self,
        tracks: np.ndarray,
        pixels: np.ndarray,
        in_view: np.ndarray,
        box_points: np.ndarray,
        box_normals: np.ndarray,
        cam_from_box: np.ndarray,
        surface: OwnSurface,
        own_label: int,
        occlusion_margin: float,
    ):
        self.tracks, self.pixels, self.in_view = tracks, pixels, in_view
        self.box_points, self.box_normals, self.cam_from_box = box_points, box_normals, cam_from_box
        self.surface, self.own_label, self.occlusion_margin = surface, own_label, occlusion_margin
        # Per frame seen: the candidates no other surface covers, and their rays to the own surface.
        self.uncovered: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = {}

    def see(self, i: int, occluders: FrameOccluders) -> None:
        """Frame i's candidates (in view, facing the camera) that no other surface covers."""
        rotation = self.cam_from_box[i, :3, :3]
        points = self.tracks[i]
        distance = np.linalg.norm(points, axis=1)
        cosine = -np.einsum("ni,ni->n", self.box_normals @ rotation.T, points) / distance
        candidates = np.flatnonzero(self.in_view[i] & (cosine > 0))
        seen = points[candidates]
        across = SURFACE_TOLERANCE_M / np.maximum(cosine[candidates], MIN_RAY_COSINE)
        depth = seen[:, 2]
        limits = depth - np.maximum(self.occlusion_margin * depth, across * depth / distance[candidates])
        reach = occluder_reach(occluders, self.pixels[i, candidates], seen, limits, self.own_label)
        uncovered = np.flatnonzero(~occluded_by_others(reach, occluders.sources))
        self.uncovered[i] = (
            candidates[uncovered],
            self.box_points[candidates[uncovered]],
            seen[uncovered] @ rotation,
            np.maximum(OWN_CLEARANCE_M, across[uncovered]),
        )

    def visibility(self) -> np.ndarray:
        """Visibility [T, N] bool: uncovered (``see``) and not hidden by the object's own surface."""
        frames = len(self.in_view)
        assert sorted(self.uncovered) == list(range(frames)), "every frame's occluders are seen"
        rows, ends, rays, clearances = zip(*(self.uncovered[i] for i in range(frames)), strict=True)
        hidden = self.surface.hides(np.concatenate(ends), np.concatenate(rays), np.concatenate(clearances))
        visibility = np.zeros(self.in_view.shape, bool)
        start = 0
        for i, frame_rows in enumerate(rows):
            visibility[i, frame_rows] = ~hidden[start : start + len(frame_rows)]
            start += len(frame_rows)
        return visibility
