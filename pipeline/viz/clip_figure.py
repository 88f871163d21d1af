"""One clip as a figure: tracks drawn on the frames beside a 3D view of the trajectories.

Layout of every output image: the frame at its stored resolution at the top-left (pixel
(row, col) of the frame is pixel (row, col) of the output), the 3D panel to its right.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterator

import cv2
import numpy as np
from matplotlib import colormaps
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from PIL import Image

import pipeline.clips
from pipeline.clips import Clip
from pipeline.core.geometry import invert_se3, project
from pipeline.io.clip_reader import DEFAULT_LIMITS, ReadLimits

COLORMAP = "gist_rainbow"
PANEL_MIN_PX = 480  # the 3D panel is square, max(frame height, this) pixels a side
PANEL_INCHES = 6.4  # fixed figure size in inches, so fonts keep their share of the panel
SUBPIXEL_BITS = 4  # cv2 drawing precision: 1/16 pixel
BACKGROUND = (255, 255, 255)
GREY = 128  # occluded points take their track's colour halfway to this grey
OCCLUDED_EDGE = (64, 64, 64)  # dark grey rim of an occluded point on the frame
TITLE_WIDTH = 60  # characters per line of the 3D panel's title
OUTPUT_KINDS = (".png", ".gif", ".mp4")


def load_clip(path: str, limits: ReadLimits = DEFAULT_LIMITS) -> Clip:
    """The clip in a ``.npz`` (``pipeline.clips.open``: nothing unpickled, sizes bounded by the clip's
    T and N); ValueError naming the file when it is not a clip or its frames hold more pixels than
    ``limits.max_image_pixels``."""
    clip = pipeline.clips.open(path, limits)
    height, width = camera_of(clip)[1]
    if height * width > limits.max_image_pixels:
        raise ValueError(f"{path}: frames of {width}x{height} pixels, more than {limits.max_image_pixels}")
    return clip


def camera_of(clip: Clip) -> tuple[np.ndarray, tuple[int, int]]:
    """The intrinsics [4] (float64) and the frames' (height, width) of a clip to draw; ValueError
    naming it when it holds no frames or no intrinsics (a reader of some members made it)."""
    if not clip.frames or clip.intrinsics is None or clip.frame_size is None:
        raise ValueError(f"{clip.name}: no frames or no intrinsics to draw")
    return clip.intrinsics, clip.frame_size


def world_tracks(tracks_xyz: np.ndarray, extrinsics_w2c: np.ndarray) -> np.ndarray:
    """Camera-frame tracks [T, N, 3] to world coordinates [T, N, 3] (float64) with w2c [T, 4, 4]."""
    c2w = invert_se3(extrinsics_w2c.astype(np.float64))
    return np.einsum("tij,tnj->tni", c2w[:, :3, :3], tracks_xyz.astype(np.float64)) + c2w[:, None, :3, 3]


def select_tracks(num_tracks: int, max_tracks: int) -> np.ndarray:
    """Indices [K] of at most ``max_tracks`` tracks, evenly spaced over [0, num_tracks)."""
    if num_tracks <= max_tracks:
        return np.arange(num_tracks)
    return np.linspace(0, num_tracks - 1, max_tracks).round().astype(np.int64)


def track_colors(count: int) -> np.ndarray:
    """RGB uint8 [count, 3]: one colour per track, sampled evenly from the fixed colormap."""
    rgba = colormaps[COLORMAP](np.linspace(0.0, 1.0, count))
    return (rgba[:, :3] * 255).round().astype(np.uint8)


def occluded_colors(colors: np.ndarray) -> np.ndarray:
    """RGB uint8 [K, 3]: the track colours [K, 3] taken halfway to grey, for occluded points."""
    return ((colors.astype(np.int64) + GREY) // 2).astype(np.uint8)


def wrap_title(text: str, width: int) -> str:
    """``text`` on lines of at most ``width`` characters, broken only after an underscore (kept at
    the end of its line) or at a space (dropped); a longer unbroken piece keeps a line to itself."""
    lines = [""]
    for piece in filter(None, re.findall(r"[^_ ]*(?:_| +|$)", text)):
        if lines[-1] and len((lines[-1] + piece).rstrip()) > width:
            lines[-1] = lines[-1].rstrip()
            lines.append("")
        lines[-1] += piece
    return "\n".join(line.rstrip() for line in lines)


def marker_radius(height: int, width: int) -> int:
    """Circle radius in pixels for frames of this size."""
    return max(4, round(min(height, width) / 100))


def decode_frame(jpeg: bytes) -> np.ndarray:
    """JPEG bytes to an RGB uint8 image [H, W, 3]."""
    bgr = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
    if bgr is None:
        raise ValueError("a frame of the clip is not a decodable JPEG")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def draw_tracks(
    frame: np.ndarray,
    pixels: np.ndarray,
    drawable: np.ndarray,
    visibility: np.ndarray,
    colors: np.ndarray,
    t: int,
    tail: int,
) -> np.ndarray:
    """Frame t [H, W, 3] with its tracks drawn; returns a new image.

    pixels [T, K, 2] (x, y) with pixel (row, col) covering [row, row + 1) x [col, col + 1);
    drawable [T, K] where the point is in front of the camera and near the image;
    visibility [T, K]; colors [K, 3]. Occluded points first: small discs in their track's colour
    taken halfway to grey, rimmed dark grey; then visible ones over them: larger discs filled in
    their track's colour. The tail joins the last ``tail`` frames' positions where both ends are
    visible.
    """
    image = frame.copy()
    height, width = image.shape[:2]
    radius = marker_radius(height, width)
    scale = 1 << SUBPIXEL_BITS
    fixed = np.round((pixels - 0.5) * scale).astype(np.int64)  # cv2 puts pixel centres on integers
    shown = drawable & visibility
    for k, color in enumerate(colors.tolist()):
        for s in range(max(t - tail, 0), t):
            if shown[s, k] and shown[s + 1, k]:
                start, end = tuple(fixed[s, k].tolist()), tuple(fixed[s + 1, k].tolist())
                cv2.line(image, start, end, color, 2, cv2.LINE_AA, SUBPIXEL_BITS)
    small = max(2, radius // 2)
    greyed = occluded_colors(colors)
    for k in np.flatnonzero(drawable[t] & ~visibility[t]).tolist():
        centre = tuple(fixed[t, k].tolist())
        cv2.circle(image, centre, small * scale, greyed[k].tolist(), -1, cv2.LINE_AA, SUBPIXEL_BITS)
        cv2.circle(image, centre, small * scale, OCCLUDED_EDGE, 1, cv2.LINE_AA, SUBPIXEL_BITS)
    for k in np.flatnonzero(drawable[t] & visibility[t]).tolist():
        centre = tuple(fixed[t, k].tolist())
        cv2.circle(image, centre, radius * scale, colors[k].tolist(), -1, cv2.LINE_AA, SUBPIXEL_BITS)
    return image


class TrajectoryView:
    """Matplotlib 3D axes (Agg) holding every trajectory; ``render(t)`` marks frame t's points.

    points [T, K, 3] in an OpenCV-axes frame (x right, y down, z forward), plotted with
    z as depth and -y as up; visibility [T, K]; colors [K, 3] uint8. Marked as on the frame:
    occluded points small, greyed and grey-rimmed, under the visible ones, large and filled.
    """

    def __init__(
        self,
        points: np.ndarray,
        visibility: np.ndarray,
        colors: np.ndarray,
        size_px: int,
        title: str,
        frame_name: str,
    ) -> None:
        self.points = np.stack([points[..., 0], points[..., 2], -points[..., 1]], axis=-1)
        self.visibility = visibility
        self.colors = colors / 255.0
        self.greyed = occluded_colors(colors) / 255.0
        self.title = wrap_title(title, TITLE_WIDTH)
        self.figure = Figure(figsize=(PANEL_INCHES, PANEL_INCHES), dpi=size_px / PANEL_INCHES)
        self.canvas = FigureCanvasAgg(self.figure)
        self.axes = self.figure.add_subplot(projection="3d", computed_zorder=False)  # drawn by zorder
        for k, color in enumerate(self.colors):
            self.axes.plot(*self.points[:, k].T, color=color, linewidth=1.0, alpha=0.7)
        finite = self.points[np.isfinite(self.points).all(axis=-1)]
        low, high = finite.min(axis=0), finite.max(axis=0)
        half = max(float((high - low).max()) * 0.55, 0.05)
        for setter, centre in zip(
            (self.axes.set_xlim, self.axes.set_ylim, self.axes.set_zlim), (low + high) / 2, strict=True
        ):
            setter(centre - half, centre + half)
        self.axes.set_box_aspect((1, 1, 1))
        self.axes.view_init(elev=20, azim=-70)
        self.axes.set_xlabel("x right (m)")
        self.axes.set_ylabel("z forward (m)")
        self.axes.set_zlabel("-y up (m)")
        legend = f"{frame_name}\nlarge filled = visible, small grey-rimmed = occluded"
        self.figure.text(0.5, 0.02, legend, ha="center", va="bottom")
        self.markers: list = []

    def render(self, t: int) -> np.ndarray:
        """The panel with frame t's points marked, RGB uint8 [S, S, 3]."""
        for artist in self.markers:
            artist.remove()
        self.markers = []
        occluded = ~self.visibility[t]
        for keep, size, faces, edges, zorder in (  # over the trajectories (lines: zorder 2)
            (occluded, 10, self.greyed[occluded], np.array(OCCLUDED_EDGE) / 255.0, 3),
            (~occluded, 40, self.colors[~occluded], self.colors[~occluded], 4),
        ):
            if keep.any():
                self.markers.append(
                    self.axes.scatter(
                        *self.points[t, keep].T,
                        s=size,
                        facecolors=faces,
                        edgecolors=edges,
                        linewidths=0.8,
                        depthshade=False,
                        zorder=zorder,
                    )
                )
        self.axes.set_title(f"{self.title}\nframe {t + 1} of {len(self.points)}", fontsize=9)
        self.canvas.draw()
        return np.asarray(self.canvas.buffer_rgba())[..., :3].copy()


def compose(frame: np.ndarray, panel: np.ndarray) -> np.ndarray:
    """Frame [H, W, 3] at the top-left, panel [P, Q, 3] to its right, on white; even sides (video codecs)."""
    height = max(frame.shape[0], panel.shape[0])
    width = frame.shape[1] + panel.shape[1]
    canvas = np.empty((height + height % 2, width + width % 2, 3), np.uint8)
    canvas[:] = BACKGROUND
    canvas[: frame.shape[0], : frame.shape[1]] = frame
    canvas[: panel.shape[0], frame.shape[1] : width] = panel
    return canvas


def render_clip(clip: Clip, name: str, frames: list[int], max_tracks: int, tail: int) -> Iterator[np.ndarray]:
    """Yields the composed RGB image [H', W', 3] of each frame index in ``frames``."""
    intrinsics = camera_of(clip)[0]
    tracks = clip.tracks.astype(np.float64)
    chosen = select_tracks(tracks.shape[1], max_tracks)
    tracks = tracks[:, chosen]
    visibility = clip.visibility[:, chosen]
    colors = track_colors(len(chosen))
    images = clip.frames
    height, width = decode_frame(images[0]).shape[:2]
    pixels = project(tracks, intrinsics)
    with np.errstate(invalid="ignore"):
        near = (np.abs(pixels - [width / 2, height / 2]) <= [width, height]).all(axis=-1)
    drawable = (tracks[..., 2] > 0) & near
    if clip.extrinsics is not None:
        w2c0 = clip.extrinsics[0].astype(np.float64)
        world = world_tracks(tracks, clip.extrinsics)
        points = np.einsum("ij,tnj->tni", w2c0[:3, :3], world) + w2c0[:3, 3]
        frame_name = "world coordinates (axes of the frame-0 camera)"
    else:
        points = tracks
        frame_name = "camera coordinates"
    title = f"{name}: {len(chosen)} of {clip.num_tracks} tracks"
    view = TrajectoryView(points, visibility, colors, max(height, PANEL_MIN_PX), title, frame_name)
    for t in frames:
        frame = draw_tracks(decode_frame(images[t]), pixels, drawable, visibility, colors, t, tail)
        yield compose(frame, view.render(t))


def write_clip_figure(
    clip_path: str,
    out: str,
    frame: int | None = None,
    max_tracks: int = 50,
    fps: float = 10.0,
    tail: int = 5,
    limits: ReadLimits = DEFAULT_LIMITS,
) -> int:
    """Writes ``out`` (.png: one frame, default the middle one; .gif/.mp4: every frame).

    Returns the number of frames written.
    """
    kind = os.path.splitext(out)[1].lower()
    if kind not in OUTPUT_KINDS:
        raise ValueError(f"unsupported output {out!r}: use one of {', '.join(OUTPUT_KINDS)}")
    clip = load_clip(clip_path, limits=limits)
    num_frames = clip.num_frames
    name = os.path.splitext(os.path.basename(clip_path))[0]
    if kind == ".png":
        index = num_frames // 2 if frame is None else frame
        if not 0 <= index < num_frames:
            raise ValueError(f"--frame {index} is outside the clip's {num_frames} frames")
        (image,) = render_clip(clip, name, [index], max_tracks, tail)
        Image.fromarray(image).save(out)
        return 1
    images = render_clip(clip, name, list(range(num_frames)), max_tracks, tail)
    if kind == ".gif":
        first = Image.fromarray(next(images))
        rest = (Image.fromarray(image) for image in images)
        first.save(out, save_all=True, append_images=rest, duration=round(1000 / fps), loop=0)
    else:
        first_frame = next(images)
        size = (first_frame.shape[1], first_frame.shape[0])
        writer = cv2.VideoWriter(out, cv2.VideoWriter.fourcc(*"mp4v"), fps, size)
        if not writer.isOpened():
            raise ValueError(f"OpenCV cannot write {out}")
        writer.write(cv2.cvtColor(first_frame, cv2.COLOR_RGB2BGR))
        for image in images:
            writer.write(cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
        writer.release()
    return num_frames
