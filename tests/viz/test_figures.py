"""pipeline.viz on synthetic clips whose projections and motions are known."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from PIL import Image

from pipeline.drivetrack.sample.driving_world import ACTORS
from pipeline.viz.__main__ import main
from pipeline.viz.clip_figure import (
    TrajectoryView,
    load_clip,
    marker_radius,
    select_tracks,
    track_colors,
    wrap_title,
)
from pipeline.viz.stats_figure import dataset_stats, track_motion

GREY = 128
WIDTH, HEIGHT = 160, 120
INTRINSICS = np.array([100.0, 100.0, 80.0, 60.0], np.float32)
DEPTH = 2.0
FRAMES = 4
# Pixel centres (x + 0.5 lands in the middle of column x) at the middle frame (index 2).
VISIBLE_PIXEL = (40, 30)  # (col, row) of track 0, which moves 10 px right per frame
OCCLUDED_PIXEL = (100, 80)  # track 1, static and occluded
STATIC_PIXEL = (130, 40)  # track 2, static and visible


def grey_jpeg() -> bytes:
    ok, data = cv2.imencode(".jpg", np.full((HEIGHT, WIDTH, 3), GREY, np.uint8))
    assert ok
    return data.tobytes()


def unproject(col: float, row: float) -> list[float]:
    """Camera point at DEPTH whose projection is the centre of pixel (row, col)."""
    fx, fy, cx, cy = INTRINSICS
    return [(col + 0.5 - cx) / fx * DEPTH, (row + 0.5 - cy) / fy * DEPTH, DEPTH]


def write_clip(path, tracks, visibility, extrinsics=None) -> None:
    """A clip .npz in the release schema: grey frames, tracks [T, N, 3], visibility [T, N]."""
    arrays = {
        "images_jpeg_bytes": [grey_jpeg()] * len(tracks),  # np.savez makes it a |S array, as the release
        "queries_xyt": np.zeros((tracks.shape[1], 3), np.float32),
        "tracks_XYZ": tracks.astype(np.float32),
        "visibility": visibility,
        "fx_fy_cx_cy": INTRINSICS,
    }
    if extrinsics is not None:
        arrays["extrinsics_w2c"] = extrinsics.astype(np.float32)
    np.savez(path, **arrays)


@pytest.fixture
def clip_path(tmp_path):
    """Camera-frame clip: T = 4 frames, 3 tracks (moving visible, static occluded, static visible)."""
    col, row = VISIBLE_PIXEL
    tracks = np.array(
        [
            [unproject(col + 10 * (t - 2), row), unproject(*OCCLUDED_PIXEL), unproject(*STATIC_PIXEL)]
            for t in range(FRAMES)
        ]
    )
    visibility = np.ones((FRAMES, 3), bool)
    visibility[:, 1] = False
    path = tmp_path / "clip.npz"
    write_clip(path, tracks, visibility)
    return str(path)


def test_png_marks_visible_large_and_occluded_small_and_grey(clip_path, tmp_path):
    out = str(tmp_path / "frame.png")
    assert main([clip_path, "--out", out]) == 0
    image = np.asarray(Image.open(out).convert("RGB")).astype(int)
    colors = track_colors(3).astype(int)
    assert image.shape[1] > WIDTH
    assert image.shape[0] >= HEIGHT  # frame plus the 3D panel
    assert (image[:, WIDTH:] != 255).any()
    radius = marker_radius(HEIGHT, WIDTH)
    col, row = VISIBLE_PIXEL
    assert np.abs(image[row, col] - colors[0]).max() <= 8
    assert np.abs(image[row, col + radius - 1] - colors[0]).max() <= 8  # a full-radius disc
    col, row = OCCLUDED_PIXEL
    assert np.abs(image[row, col] - (colors[1] + GREY) // 2).max() <= 8  # its colour halfway to grey
    assert np.abs(image[row, col + radius // 2] - 64).max() <= 12  # a dark grey rim
    for d_row, d_col in ((0, radius), (0, -radius), (radius, 0), (-radius, 0)):
        assert np.abs(image[row + d_row, col + d_col] - GREY).max() <= 3  # smaller than a visible one
    col, row = STATIC_PIXEL
    assert np.abs(image[row, col] - colors[2]).max() <= 8
    assert np.abs(image[5, 5] - GREY).max() <= 3  # untouched background


def test_visible_points_are_drawn_over_occluded_ones(tmp_path):
    """Two pixels each under a visible and an occluded point, the occluded one first by index at
    one, last at the other: the visible colour shows at both."""
    first, second = unproject(*VISIBLE_PIXEL), unproject(*STATIC_PIXEL)
    tracks = np.array([[first, first, second, second]] * FRAMES)
    visibility = np.tile([False, True, True, False], (FRAMES, 1))
    path, out = tmp_path / "stacked.npz", str(tmp_path / "stacked.png")
    write_clip(path, tracks, visibility)
    assert main([str(path), "--out", out]) == 0
    image = np.asarray(Image.open(out).convert("RGB")).astype(int)
    colors = track_colors(4).astype(int)
    for (col, row), k in ((VISIBLE_PIXEL, 1), (STATIC_PIXEL, 2)):
        assert np.abs(image[row, col] - colors[k]).max() <= 8


def test_title_wraps_after_underscores():
    title = "tapvid3d_sample0000000000000001_0_000_4_000_1_obj-3: 5 of 9 tracks"
    assert wrap_title(title, 24) == "tapvid3d_\nsample0000000000000001_\n0_000_4_000_1_obj-3: 5\nof 9 tracks"
    assert wrap_title(title, 60) == "tapvid3d_sample0000000000000001_0_000_4_000_1_obj-3: 5 of 9\ntracks"
    assert wrap_title("a_bb_ccccccccc", 3) == "a_\nbb_\nccccccccc"  # an unbroken piece keeps its length


def test_panel_counts_frames_from_one():
    points = np.array([[[0.0, 0.0, 1.0]], [[0.1, 0.0, 1.0]]])
    view = TrajectoryView(points, np.ones((2, 1), bool), track_colors(1), 200, "clip", "camera coordinates")
    view.render(0)
    assert view.axes.get_title().endswith("\nframe 1 of 2")
    view.render(1)
    assert view.axes.get_title().endswith("\nframe 2 of 2")


def test_png_other_frame_and_determinism(clip_path, tmp_path):
    first, second = str(tmp_path / "a.png"), str(tmp_path / "b.png")
    assert main([clip_path, "--out", first, "--frame", "0", "--tail", "0"]) == 0
    assert main([clip_path, "--out", second, "--frame", "0", "--tail", "0"]) == 0
    with open(first, "rb") as a, open(second, "rb") as b:
        assert a.read() == b.read()
    image = np.asarray(Image.open(first).convert("RGB")).astype(int)
    col, row = VISIBLE_PIXEL
    assert np.abs(image[row, col - 20] - track_colors(3)[0]).max() <= 8  # frame 0: 20 px further left
    assert np.abs(image[row, col] - GREY).max() <= 3


def test_gif_has_every_frame(clip_path, tmp_path):
    out = str(tmp_path / "clip.gif")
    assert main([clip_path, "--out", out, "--fps", "5"]) == 0
    with Image.open(out) as gif:
        assert gif.n_frames == FRAMES
        assert gif.info["duration"] == 200


def test_mp4_has_every_frame(clip_path, tmp_path):
    out = str(tmp_path / "clip.mp4")
    assert main([clip_path, "--out", out]) == 0
    capture = cv2.VideoCapture(out)
    assert capture.isOpened()
    count = 0
    while capture.read()[0]:
        count += 1
    capture.release()
    assert count == FRAMES


def test_bad_output_and_frame_are_refused(clip_path, tmp_path):
    with pytest.raises(SystemExit):
        main([clip_path, "--out", str(tmp_path / "clip.jpg")])
    assert main([clip_path, "--out", str(tmp_path / "clip.png"), "--frame", str(FRAMES)]) == 2


def test_nothing_is_unpickled(clip_path, tmp_path):
    assert all(frame[:2] == b"\xff\xd8" for frame in load_clip(clip_path).frames)
    with np.load(clip_path) as archive:
        arrays = dict(archive)
    arrays["images_jpeg_bytes"] = np.array(list(arrays["images_jpeg_bytes"]), dtype=object)
    path = tmp_path / "pickled.npz"
    np.savez(path, **arrays)
    with pytest.raises(ValueError, match="'images_jpeg_bytes' is an object array: loading it would need"):
        load_clip(str(path))


def test_select_tracks_is_even_and_distinct():
    chosen = select_tracks(1024, 50)
    assert len(chosen) == len(np.unique(chosen)) == 50
    assert chosen[0] == 0
    assert chosen[-1] == 1023
    assert list(select_tracks(7, 50)) == list(range(7))


def moving_camera_clip(path, speeds: list[float], frames: int) -> None:
    """World tracks moving along x at ``speeds`` m/frame (0 = static), seen by a camera moving 0.1 m/frame."""
    steps = np.arange(frames)[:, None, None]
    world = np.array([[i * 0.3, 0.0, 3.0] for i in range(len(speeds))])[None] + steps * np.array(
        [[s, 0.0, 0.0] for s in speeds]
    )
    w2c = np.tile(np.eye(4), (frames, 1, 1))
    w2c[:, 0, 3] = -0.1 * np.arange(frames)  # camera at x = 0.1 t
    tracks = world + w2c[:, None, :3, 3]
    write_clip(path, tracks, np.ones((frames, len(speeds)), bool), w2c)


def test_stats_counts_frames_static_tracks_and_speed(tmp_path, capsys):
    source = tmp_path / "adt"
    source.mkdir()
    moving_camera_clip(source / "a.npz", [0.1, 0.05, 0.0], frames=4)
    moving_camera_clip(source / "b.npz", [0.02, 0.02], frames=6)
    stats = dataset_stats(str(tmp_path))
    entry = stats["adt"]
    assert entry["clips"] == ["a", "b"]
    assert entry["frames"].tolist() == [4, 6]
    assert entry["tracks"].tolist() == [3, 2]
    assert entry["static_share"] == pytest.approx([1 / 3, 0.0])
    assert entry["mean_speed"] == pytest.approx([0.1, 0.05, 0.0, 0.02, 0.02], abs=1e-6)
    assert entry["coordinates"] == "world"

    assert main(["stats", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    row = next(line for line in printed.splitlines() if line.startswith("adt"))
    assert row.split() == ["adt", "2", "4/5/6", "2/2.5/3", "0.167", "0.0200", "world"]
    assert (tmp_path / "stats.png").stat().st_size > 0


def test_static_bound_is_one_percent_of_the_distance(tmp_path):
    """Tracks wobbling along x about their median position (0, +a, 0, -a, 0) at 10 m and 1 m from a
    camera moving 0.1 m/frame: static below 1% of the distance (10 cm, about 1.02 cm), moving above."""
    wobble = np.array([0.0, 1.0, 0.0, -1.0, 0.0])[:, None] * [0.08, 0.12, 0.008, 0.012]
    world = np.zeros((5, 4, 3))
    world[..., 0] = wobble
    world[..., 2] = [10.0, 10.0, 1.0, 1.0]
    w2c = np.tile(np.eye(4), (5, 1, 1))
    w2c[:, 0, 3] = -0.1 * np.arange(5)  # camera at x = 0.1 t
    path = tmp_path / "clip.npz"
    write_clip(path, world + w2c[:, None, :3, 3], np.ones((5, 4), bool), w2c)
    static, _, frame = track_motion(load_clip(str(path)))
    assert static.tolist() == [True, False, True, False]
    assert frame == "world"


def test_stats_parked_car_is_static_and_moving_cars_are_not(reference_run):
    """The DriveTrack sample: the parked car's clip (static in the world, seen through the rolling
    shutter from a moving camera) counts as static, the moving cars' clips as moving."""
    entry = dataset_stats(reference_run("drivetrack"))["drivetrack"]
    speeds = {actor.object_id: actor.speed for actor in ACTORS}
    parked = moving = 0
    for name, share in zip(entry["clips"], entry["static_share"], strict=True):
        speed = next(speed for object_id, speed in speeds.items() if name.endswith(object_id))
        if speed == 0:
            parked += 1
            assert share >= 0.95, name
        else:
            moving += 1
            assert share <= 0.05, name
    assert parked >= 1
    assert moving >= 1


def test_stats_without_extrinsics_uses_camera_coordinates(clip_path, tmp_path):
    folder = tmp_path / "out" / "pstudio"
    folder.mkdir(parents=True)
    with np.load(clip_path) as archive:
        np.savez(folder / "clip.npz", **dict(archive))
    entry = dataset_stats(str(tmp_path / "out"))["pstudio"]
    assert entry["coordinates"] == "camera"
    assert entry["static_share"] == pytest.approx([2 / 3])
    assert entry["mean_speed"][0] == pytest.approx(10 / 100 * DEPTH, rel=1e-5)  # 10 px/frame at 2 m
