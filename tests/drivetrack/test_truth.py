"""DriveTrack annotation on the sample world, compared with the world's analytic truth."""

import numpy as np
import pytest

from pipeline.core.errors import InputError
from pipeline.drivetrack import annotate as A
from pipeline.drivetrack.camera_model import frame_poses
from pipeline.drivetrack.lidar import BodyPoints, gather_lidar
from pipeline.drivetrack.objects import select_objects
from pipeline.drivetrack.queries import match_given_queries, point_pool
from pipeline.drivetrack.sample.waymo_world import SEGMENT
from pipeline.drivetrack.settings import DriveTrackConfig
from pipeline.drivetrack.tracks import candidate_clip
from pipeline.filters.select import apply_filters, decide
from pipeline.settings.fields import with_overrides
from pipeline.settings.run_config import RunConfig
from pipeline.sources import RunChoices
from tests.support.units import drivetrack_clips, drivetrack_input, drivetrack_segment_clips
from tests.support.waymo_truth import true_tracks, world_points


@pytest.fixture(scope="module")
def clips(sample_split):
    config = RunConfig()
    return {
        camera: drivetrack_clips(drivetrack_input(sample_split[0], SEGMENT, camera), config)
        for camera in (1, 2, 3)
    }


def test_expected_objects_become_clips(clips):
    names = sorted(
        f"{camera}/{clip.name.split(f'_{camera}_', 1)[1].split('_')[0]}"
        for camera, camera_clips in clips.items()
        for clip in camera_clips
    )
    # The pedestrian (type 2), the car beyond 50 m, and the parked car seen on too few
    # contiguous frames yield no clip.
    assert names == ["1/crossing", "1/lead", "1/oncoming", "3/parked"]


def test_tracks_and_queries_follow_the_true_surface_points(clips, world):
    for camera, camera_clips in clips.items():
        for clip in camera_clips:
            truth, pixels, body, _, object_id = true_tracks(world, clip, camera)
            error = np.linalg.norm(truth - clip.tracks_xyz, axis=2).max()
            assert error < 0.01, f"{clip.name}: worst track error {error:.4f} m"
            queried = np.isfinite(clip.queries_xyt[:, 2])
            t_q = clip.queries_xyt[queried, 2].astype(int)
            miss = np.linalg.norm(
                pixels[t_q, np.flatnonzero(queried)] - clip.queries_xyt[queried, :2], axis=1
            )
            assert miss.max() < 0.01, f"{clip.name}: worst query {miss.max():.4f} px from the truth"
            # and the points are on the object's surface, not merely inside its box
            assert world.body_distance(object_id, body).max() < 0.01


def test_visibility_agrees_with_ray_cast_truth(clips, world):
    written_agree = written_total = candidate_agree = candidate_total = 0
    config = RunConfig()
    for camera, camera_clips in clips.items():
        for clip in camera_clips:
            _, _, _, visible, _ = true_tracks(world, clip, camera)
            candidate_agree += (visible == clip.visibility).sum()
            candidate_total += visible.size
            threshold = config.section(DriveTrackConfig).mask_min_agreement
            selected = apply_filters(clip, config, threshold)[1].selected
            written_agree += (visible[:, selected] == clip.visibility[:, selected]).sum()
            written_total += visible[:, selected].size
    print(
        f"visibility agreement: written {written_agree / written_total:.4f} "
        f"({written_total} pairs); candidates {candidate_agree / candidate_total:.4f}"
    )
    assert written_agree / written_total >= 0.97
    assert candidate_agree / candidate_total >= 0.95


DEPTH_TEST = "drivetrack.refined_visibility=false"  # the depth test, which the two parts amend
PARTS = ("drivetrack.facing_test=false", "drivetrack.parallax_cleanup=false")


@pytest.fixture(scope="module")
def depth_test_agreement(sample_split, world):
    """Candidate visibility agreement with the truth over the sample's clips under the depth test,
    with both of its parts of ours (``None``) or with one of them turned off (setting -> agreement)."""

    def agreement(setting: str | None) -> float:
        config = with_overrides(RunConfig(), [DEPTH_TEST] + ([setting] if setting else []))
        agree = total = 0
        made = drivetrack_segment_clips(sample_split[0], SEGMENT, (1, 3), config)
        for camera, camera_clips in made.items():
            for clip in camera_clips:
                visible = true_tracks(world, clip, camera)[3]
                agree, total = agree + (visible == clip.visibility).sum(), total + visible.size
        return agree / total

    return {setting: agreement(setting) for setting in (None, *PARTS)}


@pytest.mark.parametrize("setting", PARTS)
def test_each_depth_test_part_raises_the_agreement(depth_test_agreement, setting):
    """The facing test (far sides of cars beyond the depth margin) and the parallax cleanup (lidar
    points seen over an occluder's edge) are ours, not the generator's: each one, turned off, loses
    over half a point of agreement with the truth."""
    full, without = depth_test_agreement[None], depth_test_agreement[setting]
    print(f"agreement {full:.4f}; with {setting}: {without:.4f}")
    assert full - without > 0.005


def test_given_queries_at_pinhole_or_sensor_pixels_match_the_same_points(sample_split, world, clips):
    """The release's queries may be the points' pinhole pixels (the schema's) or where the lens put
    them (Waymo's frames): the lead car's queries moved to their sensor pixels match the same lidar
    points; moved a pixel further, they are refused."""
    unit = drivetrack_input(sample_split[0], SEGMENT, 1)
    camera, world_from_frame = A.unit_camera(unit), frame_poses(unit)
    runs, _ = select_objects(unit, camera, world_from_frame, DriveTrackConfig())
    (run,) = [r for r in runs if "lead" in r.object_id]
    evidence = gather_lidar(unit, [run], camera, world_from_frame, 0.1, 0.05)
    pool = point_pool(evidence, run, unit.frames.timestamps).points
    clip = next(clip for clip in clips[1] if "lead" in clip.name)
    queried = np.flatnonzero(np.isfinite(clip.queries_xyt[:, 2]))
    queries = clip.queries_xyt[queried]
    at_pinhole = match_given_queries(pool, queries, run, camera, clip.name)
    sensor = true_tracks(world, clip, 1, undistorted=False)[1]
    at_sensor = queries.copy()
    at_sensor[:, :2] = sensor[queries[:, 2].astype(int), queried]
    assert np.abs(at_sensor[:, :2] - queries[:, :2]).max() > 1.0
    np.testing.assert_array_equal(match_given_queries(pool, at_sensor, run, camera, clip.name), at_pinhole)
    at_sensor[:, 0] += 1.0
    with pytest.raises(InputError, match="px from the nearest lidar point of the object"):
        match_given_queries(pool, at_sensor, run, camera, clip.name)


def test_mask_filter_drops_planted_off_object_tracks(sample_split, world):
    config = with_overrides(RunConfig(), ["drivetrack.oversample=1000"])
    unit = drivetrack_input(sample_split[0], SEGMENT, 1)
    world_from_frame = frame_poses(unit)
    camera = A.unit_camera(unit)
    rules = config.section(DriveTrackConfig)
    run = next(
        r for r in select_objects(unit, camera, world_from_frame, rules)[0] if r.object_id.startswith("lead")
    )
    evidence = gather_lidar(unit, [run], camera, world_from_frame, 0.1, 0.05, refined=True)
    # Plant ground points 2 m beside the car, as a mislabelled box would capture them.
    planted = np.array([[x, 2.9, -0.86] for x in np.linspace(-2.0, 2.0, 12)])
    frame = run.start + 5
    bodies = evidence.bodies[run.object_id]
    bodies[frame] = BodyPoints(
        np.concatenate([bodies[frame].points, planted]),
        np.concatenate([bodies[frame].normals, np.tile([0.0, 0.0, 1.0], (12, 1))]),
        np.concatenate([bodies[frame].pixels, -1 - np.arange(12)]),  # names no range-image pixel
    )
    views = evidence.refined.body_views[run.object_id]  # seen from above, as the lidar sees the ground
    views[frame] = np.concatenate([views[frame], np.tile([0.0, 0.0, 1.0], (12, 1))])
    stored = A.stored_frames(unit, list(range(run.start, run.stop)), A.undistorts(unit, True))
    clip = candidate_clip(unit, run, evidence, camera, stored, rules, RunChoices.of(config, "drivetrack"))
    box_from_world = np.linalg.inv(run.world_from_box[0])
    body = (
        world_points(world, 1, run.start, clip.tracks_xyz[0]) @ box_from_world[:3, :3].T
        + box_from_world[:3, 3]
    )
    is_planted = np.linalg.norm(body[:, None] - planted[None], axis=2).min(axis=1) < 1e-6
    assert is_planted.sum() == 12
    verdicts, _ = decide(clip, config, rules.mask_min_agreement)
    visible = clip.visibility[:, is_planted].any(axis=0)
    assert visible.sum() >= 6, "planted points should be visible (ground beside the car)"
    assert not verdicts["mask"][is_planted & clip.visibility.any(axis=0)].any()
    assert verdicts["mask"][~is_planted].mean() > 0.95


def test_a_segments_cameras_share_one_lidar_read_and_make_the_same_clips(clips, sample_split, monkeypatch):
    """The graph's group (``annotate_group``): the TOP lidar is streamed once for the three cameras,
    each frame once, and every clip is the one its camera makes alone."""
    from pipeline.drivetrack.annotate import annotate_group
    from pipeline.drivetrack.reader import SegmentReader
    from pipeline.drivetrack.units import SegmentCamera

    streamed = []
    original = SegmentReader.top_lidar_frames

    def counted(self, timestamps):
        streamed.append(list(timestamps))
        return original(self, timestamps)

    monkeypatch.setattr(SegmentReader, "top_lidar_frames", counted)
    grouped = list(
        annotate_group(
            sample_split[0], [SegmentCamera(SEGMENT, camera) for camera in (1, 2, 3)], RunConfig(), [None] * 3
        )
    )
    assert len(streamed) == 1
    assert len(set(streamed[0])) == len(streamed[0])
    needed = {int(t) for camera_clips in clips.values() for clip in camera_clips for t in clip.frame_ids}
    assert set(streamed[0]) == needed  # the frames of cameras 1 and 3's clips, in one pass
    for camera, alone in zip((1, 2, 3), [made.clips for made in grouped], strict=True):
        assert [clip.name for clip in alone] == [clip.name for clip in clips[camera]]
        for together, single in zip(alone, clips[camera], strict=True):
            for field in ("tracks_xyz", "visibility", "queries_xyt", "extrinsics_w2c", "track_keys"):
                np.testing.assert_array_equal(getattr(together, field), getattr(single, field))
            assert together.images_jpeg == single.images_jpeg
