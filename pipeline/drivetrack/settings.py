"""The ``drivetrack`` section of the run's settings (``--set drivetrack.<field>=...``): every choice and
threshold of the source, with its default and its allowed range."""

from __future__ import annotations

import dataclasses

from pipeline.settings.fields import NOT_KNOWN, clip_length, flag, path_setting, ranged


@dataclasses.dataclass(frozen=True)
class DriveTrackConfig:
    """DriveTrack (Balasingam et al., CVPR 2024) choices: the generator's, and ours where marked
    (``rules=release`` sets ours to the generator's: docs/release.md).

    facing_test and parallax_cleanup are ours, not the generator's. Beyond ~30 m the 5% depth
    margin exceeds a car's width, so the depth test alone calls the far side of a car visible;
    the lidar sits about 0.3 m above the camera and sees surfaces behind an occluder's edge that
    the camera cannot.

    cameras: the unit cameras, Waymo camera names (1 FRONT, 2 FRONT_LEFT, 3 FRONT_RIGHT,
      4 SIDE_LEFT, 5 SIDE_RIGHT); the release's are 1-3.
    object_types: the Waymo box types tracked (1 vehicle, 2 pedestrian, 3 sign, 4 cyclist); the
      release tracks vehicles.
    box_shrink_m: each box dimension shrinks by this (metres) before the lidar points inside the
      box are attached to the object.
    min_contiguous_frames: an object makes a clip only when its box projects into the camera on at
      least this many contiguous frames (the clip is the longest such run).
    clip_frames: frames per clip: an object's run longer than this is cut into consecutive windows
      of this many frames, each a clip named ``<run's name>_w<k>`` (k = 0, 1, ...), a shorter last
      one kept only with at least min_contiguous_frames; 0: the whole run (the release's). A
      training run sets it (``training.clip_frames``).
    max_corner_distance_m: an object makes a clip only when some box corner comes within this
      distance (metres) of the camera during the clip.
    occlusion_margin: a track point is occluded when the lidar depth at its pixel is below
      (1 - margin) x its own depth (the lidar's own parallax cleanup uses twice the margin).
    facing_test: a track is also invisible where its surface (normal from the lidar points) faces
      away from the camera; ours, not the generator's: false reproduces its decisions.
    parallax_cleanup: before the depth lookup, drop the lidar points a nearer lidar point hides
      from the camera (one of their 8 nearest projected neighbours, within twice the median point
      spacing, nearer by more than twice occlusion_margin); ours, not the generator's.
    refined_visibility: ours: visibility from the lidar footprints of the sweeps around each frame
      (objects moved by their boxes), the object's own surface from all its sweeps and its normals
      fitted on that surface (docs/sources/drivetrack.md); it replaces the depth test, the parallax
      cleanup and facing_test. False keeps the depth test (the generator's, with the two above).
    stable_query_frames: ours: a track's query frame is, of its visible frames, the one with the
      lowest key (of the track and the frame): uniform among them, and left in place by a visibility
      change at another frame. False takes the frame of rank floor(draw x count) among them, which
      any change before it moves.
    tracks_per_clip, oversample: tracks written per clip; candidates drawn = oversample x that.
    mask_min_agreement: keep a track when (visible frames on the object's mask) / (visible
      frames) >= this. 0.5 trims 1-3% of the sample world's candidates, the share the
      generator's Segment Anything masks trimmed (2-3%); 0.8 trimmed 13-22% there, mostly true
      surface points the one-sweep lidar silhouette missed.
    masks_dir: optional per-frame masks instead of the default lidar silhouette,
      read as ``<masks_dir>/<clip name>/<frame id>.png`` (non-zero = object; a window's: its whole
      run's clip name), on the undistorted frames' pixels.
    mask_closing_px: kernel of the morphological closing of the lidar silhouette;
      0 picks it from the spacing of the projected lidar points in each frame.
    undistort_frames: Waymo's frames carry lens distortion (up to ~8 px at the corners of a
      1920x1280 frame), which no pinhole ``fx_fy_cx_cy`` describes. Tracks and queries are the same
      either way (queries are the pinhole projections of the tracks, rolling shutter included:
      drivetrack/camera_model.py); true writes each frame undistorted with OpenCV (same intrinsics,
      re-encoded JPEG), so a point appears in the stored frame at its query; false keeps Waymo's
      JPEGs as the release did, where a point appears off its query by the lens distortion.
    """

    cameras: tuple[int, ...] = ranged((1, 2, 3), "[1, 5]", nonempty=True)
    object_types: tuple[int, ...] = ranged((1,), "[1, 4]", nonempty=True)
    box_shrink_m: float = ranged(0.1, "[0, 10]")
    min_contiguous_frames: int = ranged(24, "[1, 100000]")
    clip_frames: int = clip_length(0, "[0, 100000]", release_fixed=True)
    max_corner_distance_m: float = ranged(50.0, "(0, 10000]")
    occlusion_margin: float = ranged(0.05, "[0, 1)")
    facing_test: bool = flag(True, release=False)
    parallax_cleanup: bool = flag(True, release=False)
    refined_visibility: bool = flag(True, release=False)
    tracks_per_clip: int = ranged(256, "[1, 100000]")
    oversample: int = ranged(4, "[1, 10000]", release=NOT_KNOWN)
    mask_min_agreement: float = ranged(0.5, "[0, 1]", release=NOT_KNOWN)
    masks_dir: str = path_setting()
    mask_closing_px: int = ranged(0, "[0, 1000]", release=NOT_KNOWN)
    undistort_frames: bool = flag(True, release=False)
    stable_query_frames: bool = flag(True, release=False)


# The source as the settings page (``python -m pipeline.settings.doc``) titles its section.
TITLE = "DriveTrack (Waymo Open v2)"
SETTINGS = DriveTrackConfig
