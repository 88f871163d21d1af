"""Thumbnails for the audit page: the middle frame of a written clip with its tracks drawn (as
``python -m pipeline.viz`` draws them), downscaled, as base64 JPEG."""

from __future__ import annotations

import base64
import os

import cv2

from pipeline.export.layout import clip_path
from pipeline.io.files import list_files
from pipeline.viz.clip_figure import camera_of, load_clip, render_clip, select_tracks

WIDTH = 320  # pixels
QUALITY = 80  # JPEG quality
MAX_TRACKS = 50  # tracks drawn, evenly spaced over the clip's


def thumbnail(path: str, width: int = WIDTH) -> str:
    """Base64 JPEG of the clip at ``path``: its middle frame [H, W] with tracks drawn, ``width`` wide."""
    clip = load_clip(path)
    middle = clip.num_frames // 2
    height, frame_width = camera_of(clip)[1]  # every frame's
    name = os.path.basename(path)[: -len(".npz")]
    (composed,) = render_clip(clip, name, [middle], MAX_TRACKS, tail=5)
    frame = composed[:height, :frame_width]  # the frame sits at the top-left of the composed figure
    size = (width, max(1, round(height * width / frame_width)))
    small = cv2.resize(frame, size, interpolation=cv2.INTER_AREA)
    bgr = cv2.cvtColor(small, cv2.COLOR_RGB2BGR)
    ok, jpeg = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, QUALITY])
    if not ok:
        raise ValueError(f"{path}: OpenCV cannot encode its thumbnail")
    return base64.b64encode(jpeg.tobytes()).decode("ascii")


def sampled_clips(output: str, source: str, clips: list[str], count: int) -> list[str]:
    """At most ``count`` of ``clips`` (sorted) that have a clip file, evenly spaced over them."""
    files = {path.rpartition("/")[2] for path in list_files(clip_path(output, source, "*"))}
    written = [clip for clip in sorted(clips) if f"{clip}.npz" in files]
    return [written[i] for i in select_tracks(len(written), count)] if count > 0 else []


def thumbnails(output: str, source: str, clips: list[str], count: int) -> tuple[dict[str, str], list[str]]:
    """clip -> base64 JPEG for the ``sampled_clips``, and one line per clip whose file cannot be drawn."""
    images, problems = {}, []
    for clip in sampled_clips(output, source, clips, count):
        try:
            images[clip] = thumbnail(clip_path(output, source, clip))
        except (ValueError, OSError) as error:
            problems.append(f"no thumbnail of {clip}: {error}")
    return images, problems
