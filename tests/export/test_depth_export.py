"""``--export-depth``: the depth each visibility test read, written beside the clips, against truth."""

from __future__ import annotations

import numpy as np
import open3d as o3d

from pipeline.drivetrack.sample.waymo_world import FIRST_TIMESTAMP_MICROS, frame_time, world_from_camera
from pipeline.pstudio.sample.studio_world import WIDTH as STUDIO_WIDTH
from pipeline.runner.command import main as run_main
from tests.support.adt_excerpt import SAMPLE as ADT_EXCERPT
from tests.support.adt_excerpt import needs_excerpt

OPENCV_FROM_WAYMO = np.array([[0, -1, 0, 0], [0, 0, -1, 0], [1, 0, 0, 0], [0, 0, 0, 1.0]])


def unproject(uv, z, fx_fy_cx_cy):
    fx, fy, cx, cy = fx_fy_cx_cy
    return np.stack([(uv[:, 0] - cx) / fx * z, (uv[:, 1] - cy) / fy * z, z], axis=1)


def test_pstudio_dense_depth_matches_ray_cast_truth(pstudio_sample, tmp_path):
    root, studio = pstudio_sample
    out = tmp_path / "out"
    camera = studio.cameras[0]
    only = f"pstudio.cameras={camera.camera_id}"  # the camera read below: one unit's dense depth
    command = ["--source", "pstudio", "--input", root, "--output", str(out), "--export-depth", "--set", only]
    assert run_main(command) == 0
    with np.load(out / "depth" / "pstudio" / f"dome_{camera.camera_id}.npz", allow_pickle=False) as depth:
        assert str(depth["kind"]) == "dense"
        assert depth["depth_mm"].dtype == np.uint16
        depth_mm = depth["depth_mm"]
    assert depth_mm.shape == (40, 360, STUDIO_WIDTH)
    errors = []
    for t in (0, 20, 39):
        cast = studio.cast_image(camera, t)
        v, u = np.mgrid[0 : depth_mm.shape[1], 0 : depth_mm.shape[2]] + 0.5  # pixel centres
        fx, fy, cx, cy = camera.fx_fy_cx_cy
        ray_length = np.sqrt(((u - cx) / fx) ** 2 + ((v - cy) / fy) ** 2 + 1)
        true_z = cast["t_hit"] / ray_length
        body = (cast["body"] >= 0) & (cast["body"] < len(studio.bodies) - 1)
        errors.append(np.abs(depth_mm[t][body] / 1000.0 - true_z[body]))
    errors = np.concatenate(errors)
    assert np.median(errors) < 0.01
    assert np.mean(errors < 0.05) > 0.9


def test_drivetrack_sparse_depth_lies_on_visible_surfaces(sample_split, world, tmp_path):
    out = tmp_path / "out"
    assert (
        run_main(
            # camera 1, whose clip is read below
            ["--source", "drivetrack", "--input", sample_split[0], "--output", str(out), "--export-depth"]
            + ["--set", "drivetrack.cameras=1"]
        )
        == 0
    )
    path = sorted((out / "depth" / "drivetrack").glob("*_1_lead_car_*.npz"))[0]
    clip = np.load(out / "drivetrack" / path.name, allow_pickle=False)
    with np.load(path, allow_pickle=False) as depth:
        assert str(depth["kind"]) == "sparse"
        offsets, uv, z, frame_ids = depth["frame_offsets"], depth["uv"], depth["z"], depth["frame_ids"]
    assert len(offsets) == len(frame_ids) + 1 == clip["tracks_XYZ"].shape[0] + 1
    on_surface = unobstructed = total = 0
    for i in range(0, len(frame_ids), 7):
        t = frame_time((int(frame_ids[i]) - FIRST_TIMESTAMP_MICROS) // 100_000)
        world_from_cv = world_from_camera(world, 1, t) @ np.linalg.inv(OPENCV_FROM_WAYMO)
        rows = slice(offsets[i], offsets[i + 1])
        points = unproject(uv[rows].astype(np.float64), z[rows].astype(np.float64), clip["fx_fy_cx_cy"])
        points_world = points @ world_from_cv[:3, :3].T + world_from_cv[:3, 3]
        scene = world.scene(t)[0]
        distance = scene.compute_distance(o3d.core.Tensor(points_world.astype(np.float32))).numpy()
        on_surface += int((distance < 0.1).sum())
        unobstructed += int(world.unobstructed(t, world_from_cv[:3, 3], points_world).sum())
        total += len(points)
    assert total > 1000
    # Lidar points are captured up to a sweep before the camera exposure: moving cars shift.
    assert on_surface / total > 0.9, (on_surface / total, unobstructed / total)
    assert unobstructed / total > 0.9, (on_surface / total, unobstructed / total)


@needs_excerpt
def test_adt_dense_depth_is_the_rendered_depth(tmp_path):
    from tests.adt.test_sample import SETTINGS, Truth

    out = tmp_path / "out"
    assert (
        run_main(
            [
                "--source",
                "adt",
                "--input",
                str(ADT_EXCERPT),
                "--output",
                str(out),
                *SETTINGS,
                "--export-depth",
            ]
        )
        == 0
    )
    with np.load(out / "depth" / "adt" / "aria_digital_twin_test_data_0.npz", allow_pickle=False) as depth:
        depth_mm = depth["depth_mm"]
    truth = Truth()
    for t in range(2):
        expected = truth.depth(t)
        assert np.abs(depth_mm[t] / 1000.0 - expected).max() <= 0.0005 + 1e-9
        assert (depth_mm[t] > 0).mean() > 0.9
