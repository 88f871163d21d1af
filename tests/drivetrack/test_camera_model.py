"""Waymo's camera model (pipeline/drivetrack/camera_model.py) on the sample world, whose cameras have
lens distortion and rolling shutters on a moving ego vehicle, against an independent projection
(tests/support/waymo_truth.py); and both ways of storing the frames."""

import dataclasses
import os

import cv2
import numpy as np
import pyarrow.parquet as pq
import pytest

from pipeline.drivetrack import columns as C
from pipeline.drivetrack.annotate import unit_camera
from pipeline.drivetrack.camera_model import JPEG_QUALITY, Undistortion, UnitCamera
from pipeline.drivetrack.records import CameraCalibration, CameraFrames
from pipeline.drivetrack.sample.waymo_world import POSE_DELAY_S, SEGMENT, frame_time
from pipeline.export.invariants import check_arrays, quality_findings
from pipeline.export.npz_writer import clip_arrays
from pipeline.settings.fields import with_overrides
from pipeline.settings.run_config import RunConfig
from tests.support.units import drivetrack_clips, drivetrack_input
from tests.support.waymo_truth import inside, pinhole_pixels, seen, sensor_pixels, true_tracks, world_from_cv

FRAMES = (0, 20, 39)


def settings(undistorted: bool) -> RunConfig:
    return with_overrides(RunConfig(), [f"drivetrack.undistort_frames={str(undistorted).lower()}"])


def lidar_points(generated, frame: int) -> np.ndarray:
    points = generated["points"][frame].reshape(-1, 3)
    return points[np.isfinite(points[:, 0])]


def away_from_edges(pixels: np.ndarray, margin: float = 0.01) -> np.ndarray:
    """[N] True for pixels [N, 2] farther than ``margin`` from the frame's edges (or far outside)."""
    return inside(pixels + margin) == inside(pixels - margin)


@pytest.fixture(scope="module")
def at_frames(sample_split, world):
    """(camera models of cameras 1-3, (camera, frame) -> the frame's lidar points and ``seen`` of them
    at FRAMES), which the tests against the truth share."""
    folder, generated = sample_split
    models = {camera: unit_camera(drivetrack_input(folder, SEGMENT, camera)) for camera in (1, 2, 3)}
    points = {frame: lidar_points(generated, frame) for frame in FRAMES}
    views = {(c, t): (points[t], *seen(world, c, t, points[t])) for c in models for t in FRAMES}
    return models, views


def test_lidar_points_appear_where_the_truth_says(at_frames):
    """Each point's camera coordinates as seen, its pinhole pixel and its sensor pixel."""
    models, views = at_frames
    worst_pinhole = worst_sensor = worst_point = 0.0
    for camera in (1, 2, 3):
        model = models[camera]
        for frame in FRAMES:
            points, truth, sensor, _ = views[camera, frame]
            ours = model.project(frame, points)
            front = truth[:, 2] > 0
            pinhole = np.where(front[:, None], pinhole_pixels(truth), -1.0)
            in_view = front & inside(np.nan_to_num(sensor, nan=-1.0)) & inside(pinhole)
            clear = away_from_edges(pinhole) & away_from_edges(np.nan_to_num(sensor, nan=-1.0))
            assert in_view.sum() > 1000
            np.testing.assert_array_equal(ours.in_view[clear], in_view[clear])
            worst_pinhole = max(worst_pinhole, np.abs(ours.pixels[in_view] - pinhole[in_view]).max())
            worst_sensor = max(worst_sensor, np.abs(ours.sensor[in_view] - sensor[in_view]).max())
            worst_point = max(worst_point, np.abs(ours.points[in_view] - truth[in_view]).max())
    print(
        f"worst {worst_pinhole:.5f} px (pinhole), {worst_sensor:.5f} px (sensor), "
        f"{worst_point * 1000:.4f} mm from the truth"
    )
    assert worst_pinhole < 0.01
    assert worst_sensor < 0.01
    assert worst_point < 1e-4


def test_pinhole_at_the_pose_misses_by_pixels(at_frames):
    """What the camera model is for: the pinhole projection from the frame's pose (the pipeline
    before it) lands pixels away from where the points appear; the pinhole projection of the
    points as the camera sees them misses by the lens distortion alone."""
    models, views = at_frames
    old, lens = [], []
    for camera in (1, 2, 3):
        cam_from_world = models[camera].cam_from_world
        for frame in FRAMES:
            points, truth, sensor, _ = views[camera, frame]
            at_pose = points @ cam_from_world[frame, :3, :3].T + cam_from_world[frame, :3, 3]
            shown = (truth[:, 2] > 0) & (at_pose[:, 2] > 0) & inside(np.nan_to_num(sensor, nan=-1.0))
            old.append(np.linalg.norm(pinhole_pixels(at_pose[shown]) - sensor[shown], axis=1))
            lens.append(np.linalg.norm(pinhole_pixels(truth[shown]) - sensor[shown], axis=1))
    for name, miss in (("pinhole at the pose", np.concatenate(old)), ("lens alone", np.concatenate(lens))):
        median, p95, worst = np.median(miss), np.percentile(miss, 95), miss.max()
        print(f"{name}: median {median:.3f} p95 {p95:.3f} max {worst:.3f} px")
    assert np.percentile(np.concatenate(old), 95) > 1.0
    assert np.concatenate(lens).max() > 2.0


def test_without_rolling_shutter_columns_frames_are_seen_from_their_pose(split_copy, world, sample_split):
    path = os.path.join(split_copy, C.CAMERA_IMAGE, f"{SEGMENT}.parquet")
    pq.write_table(pq.read_table(path).drop_columns(list(C.ROLLING_SHUTTER)), path)
    unit = drivetrack_input(split_copy, SEGMENT, 2)
    assert unit.frames.motion is None
    model = unit_camera(unit)
    frame = 20
    points = lidar_points(sample_split[1], frame)
    pose = world_from_cv(world, 2, frame_time(frame) + POSE_DELAY_S)
    local = (points - pose[:3, 3]) @ pose[:3, :3]
    ours = model.project(frame, points)
    assert ours.in_view.sum() > 1000
    np.testing.assert_allclose(ours.points, local, atol=1e-4)
    np.testing.assert_allclose(ours.sensor[ours.in_view], sensor_pixels(2, local[ours.in_view]), atol=1e-3)


def test_frames_projected_together_are_each_as_projected_alone(sample_split):
    """``project_frames`` gives each frame's points the bytes ``project`` gives them, whether the
    frame has a rolling shutter record, none, or a camera that does not turn; a frame may hold
    no point, or appear twice."""
    folder, generated = sample_split
    model = unit_camera(drivetrack_input(folder, SEGMENT, 1))
    model.readouts[5] = None
    model.readouts[7] = dataclasses.replace(model.readouts[7], omega=np.zeros(3))
    frames = [0, 5, 7, 20, 39, 20, 3]
    world = [lidar_points(generated, t)[: 2000 + 100 * i] for i, t in enumerate(frames)]
    world[-1] = np.zeros((0, 3))
    together = model.project_frames(frames, world)
    assert all(projection.in_view.sum() > 400 for projection in together[:-1])
    for t, points, projection in zip(frames, world, together, strict=True):
        alone = model.project(t, points)
        for ours, theirs in zip(
            (projection.points, projection.pixels, projection.sensor, projection.in_view),
            (alone.points, alone.pixels, alone.sensor, alone.in_view),
            strict=True,
        ):
            np.testing.assert_array_equal(ours, theirs, strict=True)


def test_undistortion_maps_read_the_sensor_pixel_of_each_stored_pixel(sample_split):
    calibration = drivetrack_input(sample_split[0], SEGMENT, 3).calibration
    map_x, map_y = Undistortion(calibration).maps
    rows, cols = np.mgrid[0 : calibration.height : 7, 0 : calibration.width : 11]
    fx, fy, cx, cy = calibration.fx_fy_cx_cy
    # the ray of each stored pixel's centre (c + 0.5, r + 0.5), through the sensor's lens
    rays = np.stack([(cols.ravel() + 0.5 - cx) / fx, (rows.ravel() + 0.5 - cy) / fy, np.ones(rows.size)], 1)
    read = (
        np.stack([map_x[rows, cols].ravel(), map_y[rows, cols].ravel()], 1) + 0.5
    )  # OpenCV: centres at integers
    np.testing.assert_allclose(read, sensor_pixels(3, rays), atol=2e-3)


def test_undistorted_frame_has_the_bytes_of_the_three_channel_remap(sample_split):
    """``Undistortion.jpeg`` decodes into a fourth channel and remaps so (OpenCV's fast path), into
    images it keeps from frame to frame: each JPEG is the one OpenCV's plain decode, 3-channel remap
    and encode give, on textured frames with saturated edges, whatever frame came before."""
    calibration = drivetrack_input(sample_split[0], SEGMENT, 2).calibration
    undistortion = Undistortion(calibration)
    rng = np.random.default_rng(5)
    frames = []
    for colour in ((0, 255, 255), (255, 0, 40)):
        image = rng.integers(0, 256, (calibration.height, calibration.width, 3), np.uint8)
        image = cv2.GaussianBlur(image, (0, 0), 1.5)
        image[:, : calibration.width // 8] = colour
        frames.append(cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 90])[1].tobytes())
    for data in frames + frames[::-1]:
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
        plain = cv2.remap(image, *undistortion.maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        expected = cv2.imencode(".jpg", plain, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])[1].tobytes()
        assert undistortion.jpeg(data, "frame") == expected


@pytest.fixture(scope="module")
def lead_clips(sample_split):
    """Camera 1's clips with Waymo's frames kept and with frames undistorted."""
    unit = drivetrack_input(sample_split[0], SEGMENT, 1)
    return {undistorted: drivetrack_clips(unit, settings(undistorted)) for undistorted in (False, True)}


def test_kept_frames_show_a_query_off_its_point_by_the_lens(lead_clips, world):
    """With Waymo's frames kept (the release's rule), queries stay the pinhole projections of their
    tracks (the schema's invariant: the validator finds nothing), while the frames show each point
    where the lens put it: pixels away from its query."""
    shifts = []
    for clip in lead_clips[False]:
        _, sensor, _, _, _ = true_tracks(world, clip, 1, undistorted=False)
        queried = np.flatnonzero(np.isfinite(clip.queries_xyt[:, 2]))
        t_q = clip.queries_xyt[queried, 2].astype(int)
        arrays = clip_arrays(clip.select_tracks(queried))
        assert check_arrays(arrays) == []
        assert quality_findings(arrays)["query_residual_max_px"] < 0.01
        shifts.append(np.linalg.norm(clip.queries_xyt[queried, :2] - sensor[t_q, queried], axis=1).max())
    print(f"kept frames: worst distance of a query to its point in the frame, per clip: {shifts} px")
    assert max(shifts) > 1.0


def test_undistorted_frames_make_the_pinhole_exact(lead_clips):
    """Only the frames differ between the two: tracks, queries and visibility are the same."""
    for kept, clip in zip(lead_clips[False], lead_clips[True], strict=True):
        assert clip.name == kept.name
        assert clip.images_jpeg != kept.images_jpeg
        for field in ("tracks_xyz", "queries_xyt", "visibility"):
            np.testing.assert_array_equal(getattr(clip, field), getattr(kept, field))
        queried = np.flatnonzero(np.isfinite(clip.queries_xyt[:, 2]))
        arrays = clip_arrays(clip.select_tracks(queried))
        assert quality_findings(arrays)["query_residual_max_px"] < 0.01
        assert check_arrays(arrays) == []


@pytest.mark.parametrize("k3", [0.0, -0.02, 0.015])
def test_every_lens_term_is_opencvs(k3):
    """A global-shutter lens with each of Waymo's terms (k1, k2, p1, p2 and k3) set, on points across a
    1920x1280 frame, lands where OpenCV's projectPoints puts them (its pixel centres at integers,
    TAP-Vid's at +0.5)."""
    distortion = np.array([-0.3, 0.09, 0.0007, -0.0005, k3])
    intrinsics = np.array([2055.0, 2056.0, 961.5, 642.0])
    calibration = CameraCalibration(intrinsics, distortion, np.eye(4), 1920, 1280)
    frames = CameraFrames(np.array([0]), [b""], np.eye(4)[None])
    camera = UnitCamera(calibration, frames, np.eye(4)[None], what="lens")
    grid = np.stack(np.meshgrid(np.linspace(-0.45, 0.45, 21), np.linspace(-0.3, 0.3, 15)), -1).reshape(-1, 2)
    points = np.concatenate([grid * 12.0, np.full((len(grid), 1), 12.0)], axis=1)
    fx, fy, cx, cy = intrinsics
    matrix = np.array([[fx, 0, cx - 0.5], [0, fy, cy - 0.5], [0, 0, 1.0]])
    expected = cv2.projectPoints(points.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), matrix, distortion)[0]
    seen = camera.project(0, points)
    assert seen.in_view.all()
    np.testing.assert_allclose(seen.sensor, expected.reshape(-1, 2) + 0.5, atol=1e-6)
