"""DriveTrack annotation on the sample world, compared with the world's analytic truth."""

import numpy as np
import pytest

from pipeline.core.config import RunConfig, with_overrides
from pipeline.drivetrack import annotate as A
from pipeline.drivetrack.evidence import gather_lidar
from pipeline.drivetrack.objects import select_objects
from pipeline.drivetrack.poses import camera_from_world, frame_poses
from pipeline.drivetrack.source import load_unit
from pipeline.filters.select import apply_filters, decide
from pipeline.samples.waymo_world import (
    FIRST_TIMESTAMP_MICROS,
    FX_FY_CX_CY,
    HEIGHT,
    SEGMENT,
    WIDTH,
    frame_time,
    world_from_camera,
)

# OpenCV camera axes from the Waymo camera axes (x forward, y left, z up), written out here
# rather than taken from the pipeline.
OPENCV_FROM_WAYMO = np.array([[0, -1, 0, 0], [0, 0, -1, 0], [1, 0, 0, 0], [0, 0, 0, 1.0]])


@pytest.fixture(scope="module")
def clips(sample_split):
    config = RunConfig()
    return {
        camera: A.annotate_unit(load_unit(sample_split[0], SEGMENT, camera), config) for camera in (1, 2, 3)
    }


def true_tracks(world, clip, camera):
    """Truth for a clip: [T, N, 3] camera-frame positions of each track's surface point, its
    body-frame points [N, 3], and true visibility [T, N] by ray casting from the camera."""
    object_id = clip.name.split(f"_{camera}_", 1)[1]
    actor = world.actors[object_id]
    first = (int(clip.frame_ids[0]) - FIRST_TIMESTAMP_MICROS) // 100_000
    positions, visible = [], []
    for i in range(clip.num_frames):
        t = frame_time(first + i)
        world_from_cv = world_from_camera(world, camera, t) @ np.linalg.inv(OPENCV_FROM_WAYMO)
        if i == 0:
            seen = world_from_cv[:3, :3] @ clip.tracks_xyz[0].T + world_from_cv[:3, 3:4]
            body_from_world = np.linalg.inv(actor.world_from_body(t))
            body = (body_from_world[:3, :3] @ seen + body_from_world[:3, 3:4]).T
        pose = actor.world_from_body(t)
        points_world = body @ pose[:3, :3].T + pose[:3, 3]
        cv_from_world = np.linalg.inv(world_from_cv)
        points = points_world @ cv_from_world[:3, :3].T + cv_from_world[:3, 3]
        fx, fy, cx, cy = FX_FY_CX_CY
        u, v = fx * points[:, 0] / points[:, 2] + cx, fy * points[:, 1] / points[:, 2] + cy
        in_view = (points[:, 2] > 0) & (u >= 0) & (u < WIDTH) & (v >= 0) & (v < HEIGHT)
        positions.append(points)
        visible.append(in_view & world.unobstructed(t, world_from_cv[:3, 3], points_world))
    return np.stack(positions), body, np.stack(visible), object_id


def test_expected_objects_become_clips(clips):
    names = sorted(
        f"{camera}/{clip.name.split(f'_{camera}_', 1)[1].split('_')[0]}"
        for camera, camera_clips in clips.items()
        for clip in camera_clips
    )
    # The pedestrian (type 2), the car beyond 50 m, and the parked car seen on too few
    # contiguous frames yield no clip.
    assert names == ["1/crossing", "1/lead", "1/oncoming", "3/parked"]


def test_tracks_follow_the_true_surface_points_within_1cm(clips, world):
    for camera, camera_clips in clips.items():
        for clip in camera_clips:
            truth, body, _, object_id = true_tracks(world, clip, camera)
            error = np.linalg.norm(truth - clip.tracks_xyz, axis=2).max()
            assert error < 0.01, f"{clip.name}: worst track error {error:.4f} m"
            # and the points are on the object's surface, not merely inside its box
            assert world.body_distance(object_id, body).max() < 0.01


def test_visibility_agrees_with_ray_cast_truth(clips, world):
    written_agree = written_total = candidate_agree = candidate_total = 0
    config = RunConfig()
    for camera, camera_clips in clips.items():
        for clip in camera_clips:
            _, _, visible, _ = true_tracks(world, clip, camera)
            candidate_agree += (visible == clip.visibility).sum()
            candidate_total += visible.size
            selected = apply_filters(clip, config, config.drivetrack.mask_min_agreement)[1].selected
            written_agree += (visible[:, selected] == clip.visibility[:, selected]).sum()
            written_total += visible[:, selected].size
    print(
        f"visibility agreement: written {written_agree / written_total:.4f} "
        f"({written_total} pairs); candidates {candidate_agree / candidate_total:.4f}"
    )
    assert written_agree / written_total >= 0.97
    assert candidate_agree / candidate_total >= 0.95


def test_mask_filter_drops_planted_off_object_tracks(sample_split):
    config = with_overrides(RunConfig(), ["drivetrack.oversample=1000"])
    unit = load_unit(sample_split[0], SEGMENT, 1)
    world_from_frame = frame_poses(unit)
    cam_from_world = camera_from_world(unit.frames, unit.calibration)
    run = next(
        r
        for r in select_objects(unit, cam_from_world, world_from_frame, config)
        if r.object_id.startswith("lead")
    )
    evidence = gather_lidar(unit, [run], cam_from_world, world_from_frame, 0.1, 0.05)
    # Plant ground points 2 m beside the car, as a mislabelled box would capture them.
    planted = np.array([[x, 2.9, -0.86] for x in np.linspace(-2.0, 2.0, 12)])
    frame = run.start + 5
    points = evidence.body_points[run.object_id]
    points[frame] = np.concatenate([points[frame], planted])
    normals = evidence.body_normals[run.object_id]
    normals[frame] = np.concatenate([normals[frame], np.tile([0.0, 0.0, 1.0], (12, 1))])
    clip = A.track_object(unit, run, evidence, cam_from_world, config)
    box_from_cam = np.linalg.inv(cam_from_world[run.start] @ run.world_from_box[0])
    body = clip.tracks_xyz[0] @ box_from_cam[:3, :3].T + box_from_cam[:3, 3]
    is_planted = np.linalg.norm(body[:, None] - planted[None], axis=2).min(axis=1) < 1e-6
    assert is_planted.sum() == 12
    verdicts, _ = decide(clip, config, config.drivetrack.mask_min_agreement)
    visible = clip.visibility[:, is_planted].any(axis=0)
    assert visible.sum() >= 6, "planted points should be visible (ground beside the car)"
    assert not verdicts["mask"][is_planted & clip.visibility.any(axis=0)].any()
    assert verdicts["mask"][~is_planted].mean() > 0.95
