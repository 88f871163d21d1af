"""One clip as a Rerun recording (``.rrd``): its frames, camera, 3D tracks and queries, saved to a
file (no viewer, no network); open it with ``rerun CLIP.rrd``.

Timeline ``frame``: the frame index 0..T-1. Entities (positions in metres, pixels as in the clip):

- ``world/camera``: the camera's pose per frame, camera-to-world = inverse(``extrinsics_w2c[t]``).
  A clip without extrinsics has no world frame of its own: its world is then the first camera's
  frame (OpenCV axes, ``world`` logged as RDF) and the camera stays static at the identity, so
  every position below is in camera coordinates.
- ``world/camera/image``: the pinhole (the clip's fx, fy, cx, cy; width and height from the first
  JPEG's header) and each frame's JPEG as stored (an encoded image, not re-encoded).
- ``world/camera/image/tracks``: frame t's tracks that land inside the image (Z > 0, 0 <= x < W,
  0 <= y < H) in pixels, x = fx X / Z + cx, y = fy Y / Z + cy.
- ``world/tracks``: frame t's tracks in the world, camera-to-world applied to ``tracks_XYZ[t]``.
- ``world/tracks/trails``: per track, a line through its last ``tail`` + 1 world positions.
- ``world/queries``: at frame t, the world positions of the tracks queried at frame t
  (``queries_xyt[:, 2]``), larger; empty at the other frames.

The recording carries its blueprint (``recording_blueprint``): the viewer opens on the 3D scene
beside the frame with its projected tracks, and the time panel, and makes no view of its own.

Every track keeps one colour over all frames (``track_colors``). A visible point is drawn in its
track's colour at ``VISIBLE_RADIUS_UI``; an occluded one smaller (``OCCLUDED_RADIUS_UI``) in that
colour taken halfway to grey (``occluded_colors``), in 3D and over the image alike. Radii are in UI
points (Rerun's negative radii), so points keep their size on screen whatever the scene's scale.
"""

from __future__ import annotations

import os

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from pipeline.clips import Clip
from pipeline.core.geometry import invert_se3, project
from pipeline.io.clip_reader import DEFAULT_LIMITS, ReadLimits
from pipeline.viz.clip_figure import camera_of, load_clip, occluded_colors, select_tracks, track_colors

APPLICATION_ID = "tapvid3d"
TIMELINE = "frame"
VISIBLE_RADIUS_UI = 4.0
OCCLUDED_RADIUS_UI = 2.0
QUERY_RADIUS_UI = 8.0
TRAIL_RADIUS_UI = 1.0


def point_style(visible: np.ndarray, colors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Colours [K, 3] uint8 and radii [K] (negative: UI points) of points with visibility [K]
    whose tracks are coloured ``colors`` [K, 3]."""
    shown = np.where(visible[:, None], colors, occluded_colors(colors))
    return shown, np.where(visible, -VISIBLE_RADIUS_UI, -OCCLUDED_RADIUS_UI)


def camera_to_world(clip: Clip) -> np.ndarray:
    """Camera-to-world poses [T, 4, 4] (float64); the identity at every frame without extrinsics."""
    if clip.extrinsics is not None:
        return invert_se3(clip.extrinsics.astype(np.float64))
    return np.tile(np.eye(4), (clip.num_frames, 1, 1))


def recording_blueprint() -> rrb.Blueprint:
    """The viewer's layout: the 3D scene (``world``) beside the frame and its projected tracks
    (``world/camera/image``), the time panel open; no view the viewer would add on its own."""
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="world", name="tracks in 3D"),
            rrb.Spatial2DView(origin="world/camera/image", name="frame and projected tracks"),
        ),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(state="expanded"),
        auto_layout=False,
        auto_views=False,
    )


def inside_image(pixels: np.ndarray, depth: np.ndarray, width: int, height: int) -> np.ndarray:
    """[K] bool: points in front of the camera (``depth`` [K] > 0) whose ``pixels`` [K, 2] land in
    the image, 0 <= x < width and 0 <= y < height."""
    x, y = pixels[:, 0], pixels[:, 1]
    return (depth > 0) & (x >= 0) & (x < width) & (y >= 0) & (y < height)


def log_camera(recording: rr.RecordingStream, clip: Clip, c2w: np.ndarray) -> None:
    """The static pinhole (the clip's intrinsics and frame size), and the camera's pose: per frame
    with extrinsics, else static identity."""
    intrinsics, (height, width) = camera_of(clip)
    fx, fy, cx, cy = intrinsics
    pinhole = rr.Pinhole(
        focal_length=[fx, fy],
        principal_point=[cx, cy],
        width=width,
        height=height,
        camera_xyz=rr.ViewCoordinates.RDF,
    )
    rr.log("world/camera/image", pinhole, static=True, recording=recording)
    if clip.extrinsics is None:
        rr.log("world", rr.ViewCoordinates.RDF, static=True, recording=recording)
        identity = rr.Transform3D(translation=c2w[0, :3, 3], mat3x3=c2w[0, :3, :3])
        rr.log("world/camera", identity, static=True, recording=recording)
        return
    for t, pose in enumerate(c2w):
        rr.set_time_sequence(TIMELINE, t, recording=recording)
        camera = rr.Transform3D(translation=pose[:3, 3], mat3x3=pose[:3, :3])
        rr.log("world/camera", camera, recording=recording)


def write_recording(
    clip_path: str,
    out: str,
    max_tracks: int | None = None,
    tail: int = 5,
    limits: ReadLimits = DEFAULT_LIMITS,
) -> int:
    """Writes the clip's recording to ``out`` (.rrd): every track, or ``max_tracks`` evenly spaced
    ones; trails through the last ``tail`` frames. Returns the number of frames."""
    clip = load_clip(clip_path, limits=limits)
    assert clip.queries is not None, "load_clip opens whole clips (pipeline.clips.open)"
    intrinsics, (height, width) = camera_of(clip)
    tracks = clip.tracks.astype(np.float64)
    num_frames, num_tracks = tracks.shape[:2]
    chosen = np.arange(num_tracks) if max_tracks is None else select_tracks(num_tracks, max_tracks)
    tracks = tracks[:, chosen]
    visibility = clip.visibility[:, chosen]
    query_frames = np.round(clip.queries[chosen, 2]).astype(np.int64)
    colors = track_colors(len(chosen))
    c2w = camera_to_world(clip)
    world = np.einsum("tij,tnj->tni", c2w[:, :3, :3], tracks) + c2w[:, None, :3, 3]
    # Rerun draws an image's pixel [r, c] over [c, c + 1) x [r, r + 1) of its 2D space (top-left
    # corner at (0, 0), centre at (c + 0.5, r + 0.5)): the clip's own convention, so its pixel
    # coordinates are logged as they are, with no half-pixel shift.
    pixels = project(tracks, intrinsics)

    name = os.path.splitext(os.path.basename(clip_path))[0]
    recording = rr.new_recording(APPLICATION_ID, recording_id=name)
    try:
        rr.save(out, default_blueprint=recording_blueprint(), recording=recording)
    except RuntimeError as error:  # rerun's file sink cannot create the file
        raise OSError(str(error)) from error
    log_camera(recording, clip, c2w)
    for t in range(num_frames):
        rr.set_time_sequence(TIMELINE, t, recording=recording)
        image = rr.EncodedImage(contents=clip.frames[t], media_type="image/jpeg")
        rr.log("world/camera/image", image, recording=recording)
        shown, radii = point_style(visibility[t], colors)
        rr.log("world/tracks", rr.Points3D(world[t], colors=shown, radii=radii), recording=recording)
        seen = inside_image(pixels[t], tracks[t, :, 2], width, height)
        on_image = rr.Points2D(pixels[t, seen], colors=shown[seen], radii=radii[seen])
        rr.log("world/camera/image/tracks", on_image, recording=recording)
        queried = query_frames == t
        queries = rr.Points3D(world[t, queried], colors=colors[queried], radii=-QUERY_RADIUS_UI)
        rr.log("world/queries", queries, recording=recording)
        start = max(t - tail, 0)
        if t > start:
            strips = world[start : t + 1].transpose(1, 0, 2)
            trails = rr.LineStrips3D(strips, colors=colors, radii=-TRAIL_RADIUS_UI)
            rr.log("world/tracks/trails", trails, recording=recording)
    rr.disconnect(recording=recording)
    return num_frames
