"""The ``adt`` section of the run's settings (``--set adt.<field>=...``): every choice and threshold of
the source, with its default and its allowed range."""

from __future__ import annotations

import dataclasses

from pipeline.settings.fields import NOT_KNOWN, clip_length, flag, not_in_clips, ranged


@dataclasses.dataclass(frozen=True)
class AdtConfig:
    """Aria Digital Twin choices: the TAPVid-3D release's (docs/formats.md, section 4), and ours
    where marked (``rules=release`` sets ours to the release's: docs/release.md).

    chunk_frames: frames per clip (chunk k = frames [k * chunk_frames, (k + 1) * chunk_frames)
      of the RGB frames strictly inside the ground-truth window).
    min_frames: a chunk with fewer frames (the end of a sequence) is skipped. A training run sets
      both to ``training.clip_frames`` unless a ``--set`` gives one of them.
    with_skeleton: read the depth and segmentation that render the wearer's body and hands.
    max_gt_offset_ms: the largest time between an RGB frame and the depth, segmentation and
      poses used for it (projectaria-tools' CLOSEST sample); a frame beyond it fails its unit
      (ours; 0: no limit, as the release's generator, which takes the closest sample however far).
      Real sequences are within 0.1 ms; the shared 3-frame excerpt needs 40 (its depth stops
      one frame early, 33.2 ms before its last RGB frame).
    image_size, focal: the square pinhole camera every frame is re-rendered to (principal point
      size / 2 in projectaria-tools' integer-centre pixels, as the release's generator), then
      rotated 90 degrees clockwise; written intrinsics are the stored frames' true ones,
      (focal, focal, size / 2 - 0.5, size / 2 + 0.5) with pixel centres at +0.5.
    depth_delta_m: depth-test tolerance |z - D(u, v)| < delta. On the real sample, points on
      objects carried between its two depth frames match the rendered depth within 2.1 mm
      (95%), 11.3 mm (99%), with 99.5% under 2 cm; points that land on another object's pixels
      are 95 mm (10th percentile) from its depth. 2 cm (the release's value) keeps 99.5% of the
      genuinely visible points.
    dynamic_share: share of each frame's queries drawn on dynamic objects when any are in view.
    mask_min_agreement: keep a track when (visible frames on its own object's id) /
      (visible frames) >= this.
    tracks_per_clip, oversample: tracks written per clip; candidates drawn = oversample x that.
    scratch_dir: where sequences fetched from a download-URLs JSON (``--input``) are unpacked, one
      at a time per worker, and deleted after; empty = a folder under the system's temporary folder.
    """

    chunk_frames: int = clip_length(300, "[1, 100000]")
    min_frames: int = clip_length(300, "[1, chunk_frames]")
    with_skeleton: bool = flag(True, release=NOT_KNOWN)
    max_gt_offset_ms: float = ranged(5.0, "[0, 1000]", release=0.0)
    image_size: int = ranged(512, "[2, 8192]", even=True)
    focal: float = ranged(280.0, "(0, 100000]")
    depth_delta_m: float = ranged(0.02, "(0, 10]")
    dynamic_share: float = ranged(0.5, "[0, 1]", release=NOT_KNOWN)
    mask_min_agreement: float = ranged(0.5, "[0, 1]", release=NOT_KNOWN)
    tracks_per_clip: int = ranged(1024, "[1, 100000]")
    oversample: int = ranged(4, "[1, 10000]", release=NOT_KNOWN)
    scratch_dir: str = not_in_clips("")


# The source as the settings page (``python -m pipeline.settings.doc``) titles its section.
TITLE = "Aria Digital Twin"
SETTINGS = AdtConfig
