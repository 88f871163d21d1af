"""Dataset statistics over ``<DIR>/<source>/*.npz``: per-source histograms and a printed table.

A track is static when it is never farther from its median position than 1% of its median distance
to the camera: its motion spans under 0.01 rad (0.6 degrees) seen from the camera, under
fx / 100 pixels in the image. A fixed length would not do, as positions carry errors that grow
with the scene: DriveTrack's rolling-shutter camera model sees each point at the instant its row
is read while the frame's extrinsics hold one instant, so a parked car seen from a camera driving
8 m/s spreads over up to 8 cm in the world (0.6% of its 12-15 m), where a 1 cm bound called it
moving; an object 1 m away keeps a 1 cm bound.
"""

from __future__ import annotations

import glob
import os

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from pipeline.clips import Clip
from pipeline.io.clip_reader import DEFAULT_LIMITS, ReadLimits
from pipeline.viz.clip_figure import load_clip, world_tracks

STATIC_MAX_SPREAD = 0.01  # of the track's median distance to the camera
STATIC_CRITERION = (
    f"static = never farther from its median position than {STATIC_MAX_SPREAD:.0%} "
    "of its median distance to the camera"
)


def track_motion(clip: Clip) -> tuple[np.ndarray, np.ndarray, str]:
    """Per track whether it is static [N] (bool, ``STATIC_CRITERION``) and its mean step length [N]
    (metres per frame).

    World coordinates when the clip has ``extrinsics_w2c``, else camera coordinates (named
    in the third value). The step length is NaN for a one-frame clip.
    """
    tracks = clip.tracks.astype(np.float64)
    if clip.extrinsics is not None:
        points, frame = world_tracks(tracks, clip.extrinsics), "world"
    else:
        points, frame = tracks, "camera"
    spread = np.linalg.norm(points - np.median(points, axis=0), axis=-1).max(axis=0)
    distance = np.median(np.linalg.norm(tracks, axis=-1), axis=0)
    steps = np.linalg.norm(np.diff(points, axis=0), axis=-1)
    speed = steps.mean(axis=0) if len(steps) else np.full(points.shape[1], np.nan)
    return spread < STATIC_MAX_SPREAD * distance, speed, frame


def dataset_stats(directory: str, limits: ReadLimits = DEFAULT_LIMITS) -> dict[str, dict]:
    """Statistics per source folder of ``directory`` holding clips, sources and clips in name order.

    Each value: ``clips`` (names), ``frames`` [C] and ``tracks`` [C] (int), ``static_share`` [C]
    (share of static tracks, ``STATIC_CRITERION``), ``mean_speed`` [total tracks] (metres per frame)
    and ``coordinates`` ("world", "camera" or "mixed": where the motion was measured).
    """
    stats: dict[str, dict] = {}
    for source in sorted(os.listdir(directory)):
        paths = sorted(glob.glob(os.path.join(directory, source, "*.npz")))
        if not paths:
            continue
        frames, tracks, static_share, speeds, coordinates = [], [], [], [], set()
        for path in paths:
            clip = load_clip(path, limits=limits)
            static, speed, frame = track_motion(clip)
            frames.append(clip.num_frames)
            tracks.append(clip.num_tracks)
            static_share.append(float(np.mean(static)))
            speeds.append(speed)
            coordinates.add(frame)
        stats[source] = {
            "clips": [os.path.splitext(os.path.basename(path))[0] for path in paths],
            "frames": np.array(frames),
            "tracks": np.array(tracks),
            "static_share": np.array(static_share),
            "mean_speed": np.concatenate(speeds),
            "coordinates": coordinates.pop() if len(coordinates) == 1 else "mixed",
        }
    if not stats:
        raise ValueError(f"no clips found in {directory}/<source>/*.npz")
    return stats


def format_table(stats: dict[str, dict]) -> str:
    """The statistics as a fixed-width text table, one row per source, then the static criterion."""
    header = (
        f"{'source':<12}{'clips':>6}{'frames min/med/max':>20}{'tracks min/med/max':>20}"
        f"{'static share':>14}{'speed med (m/frame)':>21}  coordinates"
    )
    rows = [header, "-" * len(header)]
    for source, entry in stats.items():
        frames, tracks, speed = entry["frames"], entry["tracks"], entry["mean_speed"]
        speed_text = f"{np.nanmedian(speed):.4f}" if np.isfinite(speed).any() else "n/a"
        rows.append(
            f"{source:<12}{len(frames):>6}"
            f"{f'{frames.min()}/{np.median(frames):g}/{frames.max()}':>20}"
            f"{f'{tracks.min()}/{np.median(tracks):g}/{tracks.max()}':>20}"
            f"{entry['static_share'].mean():>14.3f}{speed_text:>21}  {entry['coordinates']}"
        )
    rows.append(STATIC_CRITERION)
    return "\n".join(rows)


def write_stats_figure(stats: dict[str, dict], out: str) -> None:
    """A PNG with one row per source: histograms of frames/clip, tracks/clip, static share, mean speed."""
    figure = Figure(figsize=(16, 3.2 * len(stats)), dpi=100, layout="constrained")
    FigureCanvasAgg(figure)
    axes = figure.subplots(len(stats), 4, squeeze=False)
    for row, (source, entry) in zip(axes, stats.items(), strict=True):
        speed = entry["mean_speed"][np.isfinite(entry["mean_speed"])]
        panels = (
            (entry["frames"], "auto", "frames per clip", "clips"),
            (entry["tracks"], "auto", "tracks per clip", "clips"),
            (
                entry["static_share"],
                np.linspace(0, 1, 21),
                f"share of static tracks ({entry['coordinates']} coords)",
                "clips",
            ),
            (speed, 30, "mean speed per track (metres per frame)", "tracks"),
        )
        for ax, (values, bins, label, unit) in zip(row, panels, strict=True):
            if len(values):
                ax.hist(values, bins=bins, color="tab:blue", edgecolor="white")
            ax.set_xlabel(label)
            ax.set_ylabel(unit)
        row[0].set_title(f"{source}: {len(entry['frames'])} clips", loc="left", fontweight="bold")
    figure.suptitle(
        f"{STATIC_CRITERION}, in world coordinates for clips with extrinsics_w2c, else camera coordinates"
    )
    figure.savefig(out)
