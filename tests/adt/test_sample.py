"""ADT on the real excerpt through the CLI: a valid clip, depth at the queries, dynamic objects'
motion against their recorded poses, tracks on their objects (bad input: test_bad_input_adt.py).

Truth comes from outside the pipeline: the CSV files (object and device poses), projectaria-tools'
own re-rendering of depth and ids (built here), and the clip's own frames.
"""

import csv
import json
import os

import cv2
import numpy as np
import pytest

from pipeline.io.clip_reader import read_clip_bytes
from pipeline.runner.command import main as run_main
from pipeline.validate import main as validate_main
from tests.support.adt_excerpt import SAMPLE, SETTINGS, needs_excerpt

S, F = 512, 280.0
# The stored frames' camera, pixel centres at +0.5: the generator's principal point (256, 256) in
# projectaria-tools' integer-centre pixels is (256.5, 256.5), (255.5, 256.5) after the turn.
CX, CY = 255.5, 256.5
# Stored camera from the unrotated pinhole camera: X' = -Y, Y' = X (90 degrees clockwise).
ROTATION = np.array([[0.0, -1, 0, 0], [1, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])

pytestmark = needs_excerpt


def quaternion_pose(qw, qx, qy, qz, tx, ty, tz):
    q = np.array([qw, qx, qy, qz], float)
    w, x, y, z = q / np.linalg.norm(q)
    rotation = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = rotation, [tx, ty, tz]
    return out


def object_poses_csv(timestamp_ns):
    """world_from_object per id from scene_objects.csv: static rows (-1) and the dynamic row
    nearest in time."""
    best = {}
    with open(SAMPLE / "scene_objects.csv") as handle:
        for row in csv.DictReader(handle):
            stamp = int(row["timestamp[ns]"])
            gap = 0 if stamp == -1 else abs(stamp - timestamp_ns)
            key = int(row["object_uid"])
            if key not in best or gap < best[key][0]:
                pose = quaternion_pose(
                    *(float(row[k]) for k in ("q_wo_w", "q_wo_x", "q_wo_y", "q_wo_z")),
                    *(float(row[k]) for k in ("t_wo_x[m]", "t_wo_y[m]", "t_wo_z[m]")),
                )
                best[key] = (gap, pose)
    return {key: pose for key, (_, pose) in best.items()}


def device_pose_csv(timestamp_ns):
    with open(SAMPLE / "aria_trajectory.csv") as handle:
        rows = list(csv.DictReader(handle))
    row = min(rows, key=lambda r: abs(int(r["tracking_timestamp_us"]) * 1000 - timestamp_ns))
    return quaternion_pose(
        *(
            float(row[k])
            for k in ("qw_world_device", "qx_world_device", "qy_world_device", "qz_world_device")
        ),
        *(float(row[k]) for k in ("tx_world_device", "ty_world_device", "tz_world_device")),
    )


class Truth:
    """projectaria-tools opened here, with the stored camera built here: depth and ids per frame."""

    def __init__(self):
        from projectaria_tools.core import calibration
        from projectaria_tools.core.stream_id import StreamId
        from projectaria_tools.projects import adt

        paths = adt.AriaDigitalTwinDataPathsProvider(str(SAMPLE)).get_datapaths_by_device_num(0, True)
        self.provider = adt.AriaDigitalTwinDataProvider(paths)
        self.stream = StreamId("214-1")
        self.calibration = calibration
        self.source = self.provider.get_aria_camera_calibration(self.stream)
        # The release's generator's camera: principal point (W/2, H/2), integer pixel centres.
        self.target = calibration.CameraCalibration(
            "pinhole",
            calibration.CameraModelType.LINEAR,
            np.array([F, F, S / 2, S / 2]),
            self.source.get_transform_device_camera(),
            S,
            S,
            None,
            np.pi,
            "pinhole",
        )
        stamps = np.array(self.provider.get_aria_device_capture_timestamps_ns(self.stream))
        start, end = self.provider.get_start_time_ns(), self.provider.get_end_time_ns()
        self.stamps = stamps[(stamps > start) & (stamps < end)]
        self.human = {
            i
            for i in self.provider.get_instance_ids()
            if "HUMAN" in str(self.provider.get_instance_info_by_id(i).instance_type).upper()
        }

    def depth(self, t):
        raw = (
            self.provider.get_depth_image_by_timestamp_ns(int(self.stamps[t]), self.stream)
            .data()
            .to_numpy_array()
        )
        depth = self.calibration.distort_depth_by_calibration(
            raw.astype(np.float32), self.target, self.source
        )
        return np.rot90(depth, -1).astype(np.float64) / 1000.0

    def ids(self, t):
        raw = (
            self.provider.get_segmentation_image_by_timestamp_ns(int(self.stamps[t]), self.stream)
            .data()
            .to_numpy_array()
        )
        return np.rot90(self.calibration.distort_label_by_calibration(raw, self.target, self.source), -1)


@pytest.fixture(scope="module")
def truth():
    return Truth()


@pytest.fixture(scope="module")
def sample_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("adt_out")
    code = run_main(["--source", "adt", "--input", str(SAMPLE), "--output", str(out), *SETTINGS])
    assert code == 0
    clip = read_clip_bytes((out / "adt" / "aria_digital_twin_test_data_0.npz").read_bytes(), "adt clip")
    return out, clip


def project(points):
    return np.stack([F * points[..., 0] / points[..., 2] + CX, F * points[..., 1] / points[..., 2] + CY], -1)


def test_clip_is_valid_and_named_after_the_v1_sequence(sample_run):
    out, clip = sample_run
    assert validate_main([str(out)]) == 0
    assert sorted(os.listdir(out / "adt")) == ["aria_digital_twin_test_data_0.npz"]
    assert clip["tracks_XYZ"].shape == (2, 1024, 3)
    np.testing.assert_array_equal(clip["fx_fy_cx_cy"], [280, 280, 255.5, 256.5])
    record = json.loads((out / "run_adt.json").read_text())
    assert record["config"]["adt"]["depth_delta_m"] == 0.02
    assert record["summary"]["failures"] == 0


def test_extrinsics_match_the_trajectory_csv(sample_run, truth):
    _, clip = sample_run
    device_from_camera = truth.source.get_transform_device_camera().to_matrix()
    for t in range(2):
        expected = ROTATION @ np.linalg.inv(device_pose_csv(int(truth.stamps[t])) @ device_from_camera)
        np.testing.assert_allclose(clip["extrinsics_w2c"][t], expected, atol=1e-5)


def test_query_depth_matches_the_undistorted_depth(sample_run, truth):
    _, clip = sample_run
    queries, tracks = clip["queries_xyt"], clip["tracks_XYZ"]
    t_q = queries[:, 2].astype(int)
    errors = np.zeros(len(t_q))
    for t in range(2):
        depth = truth.depth(t)
        mine = t_q == t
        rows, cols = np.floor(queries[mine, 1]).astype(int), np.floor(queries[mine, 0]).astype(int)
        errors[mine] = np.abs(tracks[t, mine, 2] - depth[rows, cols])
    assert errors.max() < 1e-5, errors.max()  # float32 metres in the file


def dynamic_tracks(clip, truth):
    """Track indices on dynamic objects and their object ids, from the truth segmentation at
    each track's query pixel."""
    queries = clip["queries_xyt"]
    t_q = queries[:, 2].astype(int)
    object_ids = np.zeros(len(t_q), np.uint64)
    for t in range(2):
        ids = truth.ids(t)
        mine = t_q == t
        object_ids[mine] = ids[np.floor(queries[mine, 1]).astype(int), np.floor(queries[mine, 0]).astype(int)]
    assert object_ids.all()
    assert not set(object_ids.tolist()) & truth.human
    dynamic = np.array(
        [
            "DYNAMIC" in str(truth.provider.get_instance_info_by_id(int(i)).motion_type).upper()
            for i in object_ids
        ]
    )
    return np.nonzero(dynamic)[0], object_ids


def test_dynamic_tracks_move_with_their_object_poses(sample_run, truth):
    _, clip = sample_run
    index, object_ids = dynamic_tracks(clip, truth)
    assert len(index) > 100
    poses = [object_poses_csv(int(truth.stamps[t])) for t in range(2)]
    world_from_cam = [np.linalg.inv(clip["extrinsics_w2c"][t].astype(np.float64)) for t in range(2)]
    tracks = clip["tracks_XYZ"].astype(np.float64)
    errors, motions = [], []
    for i in index:
        p0 = world_from_cam[0] @ np.append(tracks[0, i], 1)
        p1 = world_from_cam[1] @ np.append(tracks[1, i], 1)
        key = int(object_ids[i])
        expected = poses[1][key] @ np.linalg.inv(poses[0][key]) @ p0
        errors.append(np.linalg.norm(expected[:3] - p1[:3]))
        motions.append(np.linalg.norm(p1[:3] - p0[:3]))
    errors, motions = np.array(errors), np.array(motions)
    assert errors.max() < 1e-3, errors.max()
    assert (motions > 0.01).sum() >= 5  # some tracks sit on the fork that moves ~2 cm


def test_tracks_sit_on_their_objects_and_overlay(sample_run, truth, tmp_path):
    _, clip = sample_run
    _, object_ids = dynamic_tracks(clip, truth)
    for t in range(2):
        ids = truth.ids(t)
        visible = clip["visibility"][t]
        uv = project(clip["tracks_XYZ"][t, visible].astype(np.float64))
        landed = ids[np.floor(uv[:, 1]).astype(int), np.floor(uv[:, 0]).astype(int)]
        assert (landed == object_ids[visible]).mean() > 0.98
        assert not set(landed.tolist()) & truth.human
        image = cv2.imdecode(np.frombuffer(clip["images_jpeg_bytes"][t], np.uint8), cv2.IMREAD_COLOR)
        assert image.shape == (S, S, 3)
        for x, y in uv:
            cv2.circle(image, (int(x), int(y)), 2, (0, 255, 255), -1)
        cv2.imwrite(str(tmp_path / f"overlay_{t}.png"), image)
    # The stored frame is the generator's upright re-rendering, JPEG-encoded: the mean difference
    # is JPEG's alone (2.07 on this frame; 3.6 with the principal point half a pixel off).
    raw = (
        truth.provider.get_aria_image_by_timestamp_ns(int(truth.stamps[0]), truth.stream)
        .data()
        .to_numpy_array()
    )
    upright = np.rot90(truth.calibration.distort_by_calibration(raw, truth.target, truth.source), -1)
    stored = cv2.imdecode(np.frombuffer(clip["images_jpeg_bytes"][0], np.uint8), cv2.IMREAD_COLOR)[..., ::-1]
    assert np.abs(stored.astype(int) - upright.astype(int)).mean() < 2.3


def test_without_input_explains_how_to_get_adt(tmp_path, capsys):
    assert run_main(["--source", "adt", "--output", str(tmp_path)]) == 2
    message = capsys.readouterr().err
    assert "no embedded ADT sample" in message
    assert "aria_dataset_downloader" in message
    assert "adt.chunk_frames=2" in message
