"""Flicker and mask statistics, and the filter stage's verdicts, counts and sampling."""

import numpy as np

from pipeline.core.clip import ClipRecord, TrackStats
from pipeline.drivetrack.masks import adaptive_closing_px, silhouette_mask
from pipeline.drivetrack.settings import DriveTrackConfig
from pipeline.filters.flicker import passes_flicker, visibility_flips
from pipeline.filters.mask import agreement, on_mask
from pipeline.filters.select import apply_filters
from pipeline.settings.fields import with_overrides
from pipeline.settings.run_config import RunConfig


def test_flips_hand_counted():
    visibility = np.array([[1, 1, 0], [0, 1, 0], [1, 1, 1], [1, 0, 1]], bool)
    # track 0: 1,0,1,1 -> 2 flips; track 1: 1,1,1,0 -> 1; track 2: 0,0,1,1 -> 1.
    assert visibility_flips(visibility).tolist() == [2, 1, 1]
    # 10% of 20 frames = 2 flips allowed.
    assert passes_flicker(np.array([2, 3]), 20, 0.1).tolist() == [True, False]


def test_mask_agreement_counts_only_visible_frames_with_masks():
    on_object = np.array([[1, 0], [0, 0], [1, 1]], bool)
    visible = np.array([[1, 1], [1, 0], [1, 1]], bool)
    has_mask = np.array([True, True, False])
    # track 0: visible with mask on frames 0, 1; on the mask on frame 0 -> 0.5.
    # track 1: visible with mask on frame 0 only, off the mask -> 0.
    np.testing.assert_allclose(agreement(on_object, visible, has_mask), [0.5, 0.0])
    assert np.isnan(agreement(on_object, np.zeros_like(visible), has_mask)).all()


def test_silhouette_closes_scan_line_gaps():
    # Scan lines every 4 rows over a 40 x 20 px object: the closed mask covers the rows
    # between them, and stays away from pixels far outside the object.
    cols, rows = np.meshgrid(np.arange(30.0, 70.0, 1.0), np.arange(40.0, 61.0, 4.0))
    points = np.stack([cols.ravel(), rows.ravel()], 1)
    mask = silhouette_mask(points, 100, 100, closing_px=0)
    assert mask[42:59, 32:68].all()
    assert not mask[:30].any()
    assert not mask[:, 85:].any()
    assert on_mask(mask, np.array([[50.5, 50.5], [5.0, 5.0], [-3.0, 50.0]])).tolist() == [True, False, False]


def test_silhouette_equals_closing_the_whole_image():
    # Scan-line clusters at image corners and edges, and in the middle; the mask is computed on
    # the points' bounding box only, and must equal closing and growing the whole image.
    import cv2

    rng = np.random.default_rng(3)
    width, height = 320, 200
    for centre, closing in (((5, 5), 9), ((315, 100), 0), ((160, 195), 7), ((100, 80), 0)):
        cols, rows = np.meshgrid(np.arange(-20.0, 21.0, 1.0), np.arange(-12.0, 13.0, 3.0))
        points = np.stack([cols.ravel() + centre[0], rows.ravel() + centre[1]], 1)
        points += rng.uniform(-0.4, 0.4, points.shape)
        mask = silhouette_mask(points, width, height, closing_px=closing)
        whole = np.zeros((height, width), np.uint8)
        pixels = np.floor(points).astype(int)
        pixels = pixels[
            (pixels[:, 0] >= 0) & (pixels[:, 0] < width) & (pixels[:, 1] >= 0) & (pixels[:, 1] < height)
        ]
        whole[pixels[:, 1], pixels[:, 0]] = 1
        size = closing or mask_kernel_size(points, width, height)
        closed = cv2.morphologyEx(
            whole, cv2.MORPH_CLOSE, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
        )
        grow = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size // 2 | 1, size // 2 | 1))
        np.testing.assert_array_equal(mask, cv2.dilate(closed, grow).astype(bool))
        assert mask.sum() > len(pixels)


def mask_kernel_size(points, width, height):
    inside = (points[:, 0] >= 0) & (points[:, 0] < width) & (points[:, 1] >= 0) & (points[:, 1] < height)
    return adaptive_closing_px(points[inside])


def _clip(visibility, mask_agreement, target):
    num_frames, num_tracks = visibility.shape
    return ClipRecord(
        source="drivetrack",
        name="clip",
        unit="unit",
        images_jpeg=[b""] * num_frames,
        fx_fy_cx_cy=np.array([1.0, 1.0, 0.0, 0.0]),
        image_size=(10, 10),
        extrinsics_w2c=None,
        tracks_xyz=np.ones((num_frames, num_tracks, 3)),
        visibility=visibility,
        queries_xyt=np.zeros((num_tracks, 3)),
        frame_ids=np.arange(num_frames),
        track_stats=TrackStats(mask_agreement),
        target_tracks=target,
    )


def test_filter_stage_counts_each_track_once_in_order():
    visibility = np.ones((20, 6), bool)
    visibility[:, 0] = False  # never visible
    visibility[::2, 1] = False  # flickers 19 times
    visibility[::2, 2] = False  # flickers and off-mask: counted against flicker
    mask_agreement = np.array([1.0, 1.0, 0.1, 0.3, 0.9, np.nan])  # default keeps >= 0.5
    kept, outcome = apply_filters(
        _clip(visibility, mask_agreement, target=10), RunConfig(), DriveTrackConfig().mask_min_agreement
    )
    assert outcome.dropped_by() == {"never_visible": 1, "flicker": 2, "mask": 1}
    assert outcome.selected.tolist() == [4, 5]  # NaN agreement: no evidence, kept
    assert kept.num_tracks == 2


def test_subsample_is_seeded_by_clip_name():
    visibility = np.ones((10, 50), bool)
    clip = _clip(visibility, np.ones(50), target=7)
    first = apply_filters(clip, RunConfig(), DriveTrackConfig().mask_min_agreement)[1].selected
    assert (
        first.tolist()
        == apply_filters(clip, RunConfig(), DriveTrackConfig().mask_min_agreement)[1].selected.tolist()
    )
    assert len(first) == 7
    other_seed = apply_filters(
        clip, with_overrides(RunConfig(), ["seed=1"]), DriveTrackConfig().mask_min_agreement
    )[1].selected
    assert other_seed.tolist() != first.tolist()
