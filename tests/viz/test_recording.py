"""pipeline.viz's Rerun recordings, read back with Rerun's own dataframe API and compared with
positions, pixels and poses computed here from the clip's arrays; their blueprint read back with
Rerun's own ``rerun rrd print``."""

from __future__ import annotations

import os
import re
import subprocess
import sys

import cv2
import numpy as np
import pytest
import rerun.blueprint as rrb
import rerun.dataframe as rd

from pipeline.viz.__main__ import main
from pipeline.viz.clip_figure import track_colors

WIDTH, HEIGHT = 160, 120
INTRINSICS = np.array([100.0, 110.0, 80.0, 60.0], np.float32)
FRAMES = 5
QUERY_FRAMES = [0, 0, 3, 0]
ENTITIES = {
    "/world/camera",
    "/world/camera/image",
    "/world/camera/image/tracks",
    "/world/tracks",
    "/world/tracks/trails",
    "/world/queries",
}


def frame_jpegs() -> list[bytes]:
    """One JPEG per frame, each of its own grey level, so that frames cannot be mixed up."""
    frames = []
    for t in range(FRAMES):
        ok, data = cv2.imencode(".jpg", np.full((HEIGHT, WIDTH, 3), 40 + 40 * t, np.uint8))
        assert ok
        frames.append(data.tobytes())
    return frames


def rotation_y(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def moving_camera() -> np.ndarray:
    """world-to-camera [T, 4, 4] of a camera turning 0.1 rad and moving 0.2 m along x per frame."""
    w2c = np.tile(np.eye(4), (FRAMES, 1, 1))
    for t in range(FRAMES):
        c2w = np.eye(4)
        c2w[:3, :3] = rotation_y(0.1 * t)
        c2w[:3, 3] = [0.2 * t, 0.05 * t, 0.0]
        w2c[t] = np.linalg.inv(c2w)
    return w2c


def world_points() -> np.ndarray:
    """World tracks [T, 4, 3]: three ahead of the camera (one moving), the fourth behind it."""
    steps = np.arange(FRAMES)[:, None, None]
    start = np.array([[0.0, 0.0, 3.0], [0.5, -0.3, 4.0], [-0.6, 0.4, 5.0], [0.0, 0.0, -2.0]])
    return start[None] + steps * np.array([[0.1, 0.0, 0.0], [0.0] * 3, [0.0] * 3, [0.0] * 3])


def visibility() -> np.ndarray:
    visible = np.ones((FRAMES, 4), bool)
    visible[1:3, 0] = False
    visible[:, 3] = False
    return visible


def write_clip(path, tracks: np.ndarray, w2c: np.ndarray | None) -> dict[str, np.ndarray]:
    """A clip .npz with the release's dtypes (the first tracks.shape[1] of ``visibility`` and
    ``QUERY_FRAMES``); returns the arrays as stored."""
    count = tracks.shape[1]
    arrays = {
        "images_jpeg_bytes": np.array(frame_jpegs()),  # |S, as the release
        "queries_xyt": np.array([[0.0, 0.0, t] for t in QUERY_FRAMES[:count]], np.float32),
        "tracks_XYZ": tracks.astype(np.float32),
        "visibility": visibility()[:, :count],
        "fx_fy_cx_cy": INTRINSICS.astype(np.float64),
    }
    if w2c is not None:
        arrays["extrinsics_w2c"] = w2c.astype(np.float32)
    np.savez(path, **arrays)
    return arrays


@pytest.fixture
def world_clip(tmp_path):
    """(path, stored arrays) of a clip with extrinsics, tracks derived from ``world_points``."""
    w2c = moving_camera()
    world = world_points()
    tracks = np.einsum("tij,tnj->tni", w2c[:, :3, :3], world) + w2c[:, None, :3, 3]
    path = tmp_path / "clip.npz"
    return str(path), write_clip(path, tracks, w2c)


def read_back(path: str):
    """(entity paths, table with one row per frame) of a recording, by Rerun's dataframe API."""
    recording = rd.load_recording(path)
    entities = {column.entity_path for column in recording.schema().component_columns()}
    return entities, recording.view(index="frame", contents="/**").select().read_all()


def column(table, name: str) -> list:
    return table.column(name).to_pylist()


def rgb(packed: list[int]) -> np.ndarray:
    """Rerun's 0xRRGGBBAA colours [K] to RGB [K, 3]."""
    packed = np.array(packed, np.int64)
    return np.stack([(packed >> 24) & 255, (packed >> 16) & 255, (packed >> 8) & 255], axis=-1)


def test_recording_holds_frames_camera_and_world_tracks(world_clip, tmp_path):
    path, clip = world_clip
    out = str(tmp_path / "clip.rrd")
    assert main([path, "--out", out, "--tail", "2"]) == 0
    entities, table = read_back(out)
    assert ENTITIES <= entities
    assert column(table, "frame") == list(range(FRAMES))

    c2w = np.linalg.inv(clip["extrinsics_w2c"].astype(np.float64))
    homogeneous = np.concatenate([clip["tracks_XYZ"], np.ones((FRAMES, 4, 1))], axis=-1)
    world = np.einsum("tij,tnj->tni", c2w, homogeneous)[..., :3]
    assert np.allclose(world, world_points(), atol=1e-5)  # the clip is the designed scene
    positions = column(table, "/world/tracks:Position3D")
    for t in (0, 2, 4):
        assert np.allclose(positions[t], world[t], atol=1e-5)
    translations = column(table, "/world/camera:Translation3D")
    matrices = column(table, "/world/camera:TransformMat3x3")
    for t in (1, 4):
        assert np.allclose(translations[t][0], c2w[t, :3, 3], atol=1e-6)
        assert np.allclose(np.reshape(matrices[t][0], (3, 3), order="F"), c2w[t, :3, :3], atol=1e-6)
    trails = column(table, "/world/tracks/trails:LineStrip3D")
    assert trails[0] is None  # nothing behind the first frame
    assert np.allclose(trails[3], world[1:4].transpose(1, 0, 2), atol=1e-5)

    fx, fy, cx, cy = INTRINSICS
    assert np.allclose(
        np.reshape(column(table, "/world/camera/image:PinholeProjection")[0][0], (3, 3), order="F"),
        [[fx, 0, cx], [0, fy, cy], [0, 0, 1]],
    )
    assert column(table, "/world/camera/image:Resolution")[0] == [[WIDTH, HEIGHT]]
    blobs = column(table, "/world/camera/image:Blob")
    assert [bytes(blob[0]) for blob in blobs] == list(clip["images_jpeg_bytes"])
    assert column(table, "/world/camera/image:MediaType")[2] == ["image/jpeg"]
    assert main([path, "--out", str(tmp_path / "absent" / "clip.rrd")]) == 2


def test_recording_pixels_and_point_styles(world_clip, tmp_path):
    path, clip = world_clip
    out = str(tmp_path / "clip.rrd")
    assert main([path, "--out", out]) == 0
    _, table = read_back(out)
    tracks = clip["tracks_XYZ"].astype(np.float64)
    fx, fy, cx, cy = INTRINSICS
    colors = track_colors(4).astype(int)
    for t in (0, 1, 4):
        ahead = tracks[t, :3]  # the fourth track is behind the camera: no pixel
        expected = np.stack([fx * ahead[:, 0] / ahead[:, 2] + cx, fy * ahead[:, 1] / ahead[:, 2] + cy], -1)
        assert np.allclose(column(table, "/world/camera/image/tracks:Position2D")[t], expected, atol=1e-4)

    visible = visibility()
    for t in (1, 4):
        radii = np.array(column(table, "/world/tracks:Radius")[t])
        shown = rgb(column(table, "/world/tracks:Color")[t])
        assert (radii[visible[t]] == -4.0).all()  # UI points
        assert (radii[~visible[t]] == -2.0).all()  # occluded: half the size
        assert (shown[visible[t]] == colors[visible[t]]).all()
        assert (shown[~visible[t]] == (colors[~visible[t]] + 128) // 2).all()  # halfway to grey
        assert np.array_equal(column(table, "/world/camera/image/tracks:Radius")[t], radii[:3])

    queries = column(table, "/world/queries:Position3D")
    world = column(table, "/world/tracks:Position3D")
    assert np.allclose(queries[0], np.array(world[0])[[0, 1, 3]])
    assert np.allclose(queries[3], np.array(world[3])[[2]])
    assert queries[1] == queries[2] == queries[4] == []
    assert column(table, "/world/queries:Radius")[3] == [-8.0]


def test_recording_without_extrinsics_stays_in_camera_coordinates(tmp_path):
    tracks = world_points()  # read as camera-frame tracks this time
    clip = write_clip(tmp_path / "camera.npz", tracks, None)
    out = str(tmp_path / "camera.rrd")
    assert main([str(tmp_path / "camera.npz"), "--out", out, "--max-tracks", "2"]) == 0
    entities, table = read_back(out)
    assert ENTITIES | {"/world"} <= entities
    positions = column(table, "/world/tracks:Position3D")
    for t in (0, 3):
        assert np.allclose(positions[t], clip["tracks_XYZ"][t, [0, 3]], atol=1e-6)  # 2 of 4, evenly spaced
    assert column(table, "/world/camera:Translation3D")[4] == [[0.0, 0.0, 0.0]]
    assert np.allclose(column(table, "/world/camera:TransformMat3x3")[4][0], np.eye(3).ravel())


def test_folder_of_clips_gives_one_recording_each(tmp_path):
    folder = tmp_path / "clips"
    folder.mkdir()
    write_clip(folder / "a.npz", world_points(), moving_camera())
    write_clip(folder / "b.npz", world_points()[:, :3], None)
    out = tmp_path / "recordings"
    assert main([str(folder), "--out", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["a.rrd", "b.rrd"]
    for name, count in (("a.rrd", 4), ("b.rrd", 3)):
        _, table = read_back(str(out / name))
        assert column(table, "frame") == list(range(FRAMES))
        assert len(column(table, "/world/tracks:Position3D")[0]) == count
    with pytest.raises(SystemExit):
        main([str(folder), "--out", str(tmp_path / "recordings.rrd")])
    assert main([str(tmp_path / "recordings"), "--out", str(tmp_path / "none")]) == 2  # no clips in it


def test_projected_points_are_drawn_only_inside_the_image(tmp_path):
    """Camera-frame tracks: one in the image, one right of it, one above it, one behind the camera."""
    fx, fy, cx, cy = INTRINSICS
    inside, right, above = (
        [0.1, 0.1, 3.0],
        [(WIDTH + 5 - cx) * 3.0 / fx, 0.0, 3.0],
        [0.0, -(cy + 5) * 3.0 / fy, 3.0],
    )
    tracks = np.tile(np.array([inside, right, above, [0.0, 0.0, -2.0]]), (FRAMES, 1, 1))
    write_clip(tmp_path / "edges.npz", tracks, None)
    out = str(tmp_path / "edges.rrd")
    assert main([str(tmp_path / "edges.npz"), "--out", out]) == 0
    _, table = read_back(out)
    expected = [fx * inside[0] / inside[2] + cx, fy * inside[1] / inside[2] + cy]
    for t in range(FRAMES):
        assert np.allclose(column(table, "/world/camera/image/tracks:Position2D")[t], [expected], atol=1e-4)
    assert len(column(table, "/world/tracks:Position3D")[0]) == 4  # all four stay in 3D


def blueprint_rows(path: str) -> dict[str, dict[str, str]]:
    """Entity path -> {column: value} of each one-row chunk of the recording's blueprint store, as
    ``rerun rrd print -vvv`` prints it (the SDK's own reader; values as printed, e.g. ``[3D]``)."""
    rerun = os.path.join(os.path.dirname(sys.executable), "rerun")
    printed = subprocess.run(
        [rerun, "rrd", "print", "-vvv", path], capture_output=True, text=True, timeout=60
    )
    assert printed.returncode == 0, printed.stderr
    rows: dict[str, dict[str, str]] = {}
    for chunk in re.split(r"^Chunk\(", printed.stdout, flags=re.M)[1:]:
        entity = re.match(r"[0-9A-F]+\) with 1 rows .*? - (\S+) - ", chunk)
        lines = [line.strip("│ ").split("┆") for line in chunk.splitlines() if "┆" in line]
        if entity is None or not lines:
            continue
        header, data = lines[0], lines[-1]
        cells = {name.strip(): value.strip() for name, value in zip(header, data, strict=True)}
        rows.setdefault(entity[1], {}).update(cells)
    return rows


def test_the_recording_opens_on_its_own_views(world_clip, tmp_path):
    """A 3D view of the world and a 2D view of the frame with its tracks, side by side; the time
    panel open; the viewer adds no view of its own (no extra panel of dots on black)."""
    out = str(tmp_path / "clip.rrd")
    assert main([world_clip[0], "--out", out]) == 0
    rows = blueprint_rows(out)
    views = {
        (row["ViewClass"], row["ViewOrigin"])
        for path, row in rows.items()
        if re.fullmatch(r"/view/[^/]+", path)
    }
    assert views == {("[3D]", "[world]"), ("[2D]", "[world/camera/image]")}
    assert (rows["/viewport"]["AutoViews"], rows["/viewport"]["AutoLayout"]) == ("[false]", "[false]")
    (container,) = [row for path, row in rows.items() if path.startswith("/container/")]
    assert container["ContainerKind"] == f"[{rrb.components.ContainerKind.Horizontal.value}]"
    assert rows["/time_panel"]["PanelState"] == f"[{rrb.components.PanelState.Expanded.value}]"
