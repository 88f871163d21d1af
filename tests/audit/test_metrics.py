"""TAPVid-3D metrics on hand-worked cases, and ``compare`` on synthetic output folders."""

import json
import pickle

import cv2
import numpy as np
import pytest
from scipy import stats

from pipeline.audit.compare import Status, compare_dirs, main, read_reference
from pipeline.audit.metrics import (
    PIXEL_THRESHOLDS,
    eval_intrinsics,
    median_error,
    query_frame_indices,
    tapvid3d_metrics,
)
from pipeline.export.npz_writer import encode_npz
from pipeline.io.clip_reader import DEFAULT_LIMITS

# Evaluation-scale intrinsics with f = 100 px: at z = 2 m a d-pixel threshold is a 3D radius of
# d * 2 / 100 m, i.e. 0.02, 0.04, 0.08, 0.16, 0.32 m for d = 1, 2, 4, 8, 16.
EVAL_K = np.array([100.0, 100.0, 50.0, 50.0])


def points_at_2m(frames, tracks):
    """[T, N, 3] points spread in x, y at depth z = 2 m."""
    xy = np.stack(np.meshgrid(np.arange(tracks) * 0.1, np.arange(frames) * 0.05), -1)
    return np.concatenate([xy, np.full((frames, tracks, 1), 2.0)], -1)


def score(gt, gt_vis, pred, pred_vis, scaling):
    return tapvid3d_metrics(gt, gt_vis, pred, pred_vis, EVAL_K, np.zeros(gt.shape[1], int), scaling)


@pytest.mark.parametrize("scaling", ["median", "per_trajectory", "none"])
def test_perfect_prediction_scores_one(scaling):
    gt = points_at_2m(3, 5)
    vis = np.ones((3, 5), bool)
    vis[1, 2] = False
    result = score(gt, vis, gt.copy(), vis.copy(), scaling)
    assert result["average_jaccard"] == result["average_pts_within"] == result["occlusion_accuracy"] == 1.0


def test_known_offsets_fall_within_some_thresholds():
    # 4 tracks, 1 frame, all visible in both; x offsets 0, 0.03, 0.1, 0.5 m against the radii
    # 0.02/0.04/0.08/0.16/0.32 m. Points within per threshold (1, 2, 4, 8, 16 px): 1, 2, 2, 3, 3 of 4.
    # pts_within = 1/4, 2/4, 2/4, 3/4, 3/4 -> APD = 2.75 / 5 = 0.55.
    # jaccard = within / (4 visible + (4 - within) false positives) = 1/7, 2/6, 2/6, 3/5, 3/5
    # -> AJ = (1/7 + 1/3 + 1/3 + 3/5 + 3/5) / 5 = 0.401905 (to 6 places).
    gt = points_at_2m(1, 4)
    pred = gt.copy()
    pred[0, :, 0] += [0.0, 0.03, 0.1, 0.5]
    vis = np.ones((1, 4), bool)
    result = score(gt, vis, pred, vis, "none")
    assert [result[f"pts_within_{d}"] for d in PIXEL_THRESHOLDS] == [0.25, 0.5, 0.5, 0.75, 0.75]
    assert result["average_pts_within"] == pytest.approx(0.55)
    assert result["jaccard_1"] == pytest.approx(1 / 7)
    assert result["jaccard_8"] == pytest.approx(3 / 5)
    assert result["average_jaccard"] == pytest.approx(0.401905, abs=1e-6)
    assert result["occlusion_accuracy"] == 1.0
    # Median of the unscaled errors 0, 0.03, 0.1, 0.5 -> (0.03 + 0.1) / 2.
    assert median_error(gt, vis, pred) == pytest.approx(0.065)


def test_wrong_visibility_on_k_of_n_pairs():
    # 2 frames x 4 tracks = 8 pairs, exact positions. GT hides (0, 3); the prediction hides (0, 0)
    # and (1, 1) and shows (0, 3): 3 of 8 pairs wrong -> OA = 5/8.
    # 7 GT-visible pairs, 5 of them predicted visible (true positives); 1 false positive (0, 3)
    # -> jaccard = 5 / (7 + 1) = 5/8 at every threshold; APD ignores predicted visibility -> 7/7.
    gt = points_at_2m(2, 4)
    gt_vis = np.ones((2, 4), bool)
    gt_vis[0, 3] = False
    pred_vis = gt_vis.copy()
    pred_vis[0, 0] = pred_vis[1, 1] = False
    pred_vis[0, 3] = True
    result = score(gt, gt_vis, gt.copy(), pred_vis, "none")
    assert result["occlusion_accuracy"] == 5 / 8
    assert result["average_jaccard"] == pytest.approx(5 / 8)
    assert result["average_pts_within"] == 1.0


def test_median_rescaling_undoes_a_uniform_scale():
    gt = points_at_2m(3, 4)
    vis = np.ones((3, 4), bool)
    pred = 2 * gt
    assert score(gt, vis, pred, vis, "median")["average_jaccard"] == pytest.approx(1.0)
    assert score(gt, vis, pred, vis, "median")["average_pts_within"] == pytest.approx(1.0)
    # Unscaled, every point is about 2 m off, beyond the largest radius 0.32 m.
    assert score(gt, vis, pred, vis, "none")["average_pts_within"] == 0.0


def test_per_trajectory_rescaling_undoes_a_scale_per_track():
    # Track 0 predicted 3x too far, track 1 0.5x: z_gt / z_pred at the query frame fixes each track,
    # one global median factor cannot fix both.
    gt = points_at_2m(3, 2)
    vis = np.ones((3, 2), bool)
    pred = gt * np.array([3.0, 0.5])[None, :, None]
    assert score(gt, vis, pred, vis, "per_trajectory")["average_pts_within"] == pytest.approx(1.0)
    assert score(gt, vis, pred, vis, "median")["average_pts_within"] < 0.5


def test_query_frames_are_rounded_and_negative_ones_count_from_the_end():
    # T = 3: round(0.4) = 0, round(1.6) = 2, -1 -> 2, round(0.5) = 0 and round(2.5) = 2 (half to even),
    # -3.2 -> -3 -> 0.
    frames = query_frame_indices(np.array([0.4, 1.6, -1.0, 0.5, 2.5, -3.2]), 3)
    assert frames.tolist() == [0, 2, 2, 0, 2, 0]
    # round(2.6) = 3 and round(-3.6) = -4 are no index of 3 frames, nor is NaN.
    for bad in (2.6, -3.6, np.nan):
        assert query_frame_indices(np.array([0.0, bad]), 3) is None


def test_evaluation_intrinsics_put_the_smaller_side_at_256_px():
    np.testing.assert_allclose(eval_intrinsics([280, 280, 256, 256], 512, 512), [140, 140, 128, 128])
    # 640x360 (Panoptic Studio): factor 256 / 360.
    expected = [360 * 256 / 360, 720 * 256 / 360, 320 * 256 / 360, 180 * 256 / 360]
    np.testing.assert_allclose(eval_intrinsics([360, 720, 320, 180], 360, 640), expected)


# ---- compare on output folders ---------------------------------------------------------------

HEIGHT, WIDTH = 48, 64
K = np.array([50.0, 50.0, 32.0, 24.0], np.float32)
F_EVAL = 50.0 * 256 / min(HEIGHT, WIDTH)
SCORE_KEYS = ("aj_median", "apd_median", "aj_per_trajectory", "apd_per_trajectory", "aj_none", "apd_none")


def synthetic_clip(seed, frames=10, tracks=200, source="adt"):
    """A clip in the released schema: points at 1.5-2.5 m inside the 64x48 view, all visible."""
    rng = np.random.default_rng(seed)
    z = rng.uniform(1.5, 2.5, (frames, tracks))
    u, v = rng.uniform(2, WIDTH - 2, (frames, tracks)), rng.uniform(2, HEIGHT - 2, (frames, tracks))
    xyz = np.stack([(u - K[2]) / K[0] * z, (v - K[3]) / K[1] * z, z], -1).astype(np.float32)
    t_q = np.arange(tracks) % frames
    jpeg = cv2.imencode(".jpg", np.full((HEIGHT, WIDTH, 3), 128, np.uint8))[1].tobytes()
    arrays = {
        "images_jpeg_bytes": np.array([jpeg] * frames),
        "queries_xyt": np.concatenate([np.stack([u, v], -1)[t_q, np.arange(tracks)], t_q[:, None]], 1),
        "tracks_XYZ": xyz,
        "visibility": np.ones((frames, tracks), bool),
        "fx_fy_cx_cy": K,
    }
    arrays["queries_xyt"] = arrays["queries_xyt"].astype(np.float32)
    if source != "pstudio":
        arrays["extrinsics_w2c"] = np.tile(np.eye(4, dtype=np.float32), (frames, 1, 1))
    return arrays


def write_clip(root, source, name, arrays):
    folder = root / source
    folder.mkdir(parents=True, exist_ok=True)
    (folder / name).write_bytes(encode_npz(arrays))


@pytest.fixture
def ref_dir(tmp_path):
    root = tmp_path / "ref"
    write_clip(root, "adt", "a_0.npz", synthetic_clip(0))
    write_clip(root, "adt", "a_1.npz", synthetic_clip(1))
    write_clip(root, "pstudio", "tennis_1.npz", synthetic_clip(2, source="pstudio"))
    return root


def test_frame_size_comes_from_the_first_jpeg_header(ref_dir):
    assert read_reference(str(ref_dir / "adt" / "a_0.npz"), DEFAULT_LIMITS).frame_size == (HEIGHT, WIDTH)


def test_compare_a_folder_with_itself_scores_one_and_never_unpickles(ref_dir, tmp_path, monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("compare unpickled something")

    monkeypatch.setattr(pickle, "load", refuse)
    monkeypatch.setattr(pickle, "loads", refuse)
    out = tmp_path / "report" / "self"
    assert main([str(ref_dir), str(ref_dir), "--out", str(out)]) == 0
    report = json.loads(out.with_suffix(".json").read_text())
    sources = [(row["source"], row["clips"]) for row in report["sources"]]
    assert sources == [("adt", 2), ("pstudio", 1), ("all", 3)]
    for row in report["clips"] + report["sources"]:
        for key in SCORE_KEYS:
            assert row[key] == 1.0, (row, key)
        assert row["oa"] == 1.0
        assert row["median_error_m"] == 0.0
    table = out.with_suffix(".md").read_text()
    assert f"| adt | a_0.npz | scored | {report['compared_at']} | 10 | 200 |  | 1.0000" in table
    assert all(row["agrees"] for row in report["clips"])


def test_mismatched_and_missing_predictions_count_zero_and_unmatched_clips_are_listed(ref_dir, tmp_path):
    new = tmp_path / "new"
    write_clip(new, "adt", "a_0.npz", synthetic_clip(0, tracks=150))
    write_clip(new, "adt", "a_1.npz", synthetic_clip(1))
    write_clip(new, "drivetrack", "extra.npz", synthetic_clip(3))
    report = compare_dirs(str(ref_dir), str(new))
    first, second, third = report.clips
    assert first.status is Status.ZERO
    assert "shapes differ" in first.error
    assert first.scores.aj["median"] == 0.0
    assert second.status is Status.SCORED
    assert second.scores.aj["median"] == 1.0
    assert third.status is Status.ZERO
    assert third.error == "no prediction file"
    assert report.only_in_new == ["drivetrack/extra.npz"]
    # adt: (0 + 1) / 2; pstudio: 0; all: the mean of the two source means.
    adt, pstudio, overall = report.sources
    assert (adt.clips, adt.zero, adt.means.aj["median"]) == (2, 1, 0.5)
    assert (pstudio.clips, pstudio.zero, pstudio.means.aj["median"]) == (1, 1, 0.0)
    assert overall.means.aj["median"] == 0.25
    assert overall.means.median_error_m == 0.0
    assert main([str(ref_dir), str(tmp_path / "absent")]) == 2
    (tmp_path / "empty").mkdir()
    assert main([str(ref_dir), str(tmp_path / "empty")]) == 1


def expected_apd(gt_z, sigma):
    """APD under isotropic Gaussian noise: the error norm is sigma x chi(3 dof); mean of its CDF at
    each point's radius d * z / f_eval, averaged over the thresholds."""
    return np.mean([stats.chi.cdf(d * gt_z / F_EVAL / sigma, df=3).mean() for d in PIXEL_THRESHOLDS])


def test_metrics_fall_with_noise_and_apd_matches_the_chi_distribution(ref_dir, tmp_path):
    gt = synthetic_clip(0)
    results = []
    for sigma in (0.001, 0.003, 0.01, 0.05):
        noisy = dict(gt)
        rng = np.random.default_rng(7)
        noise = rng.normal(0, sigma, gt["tracks_XYZ"].shape)
        noisy["tracks_XYZ"] = (gt["tracks_XYZ"] + noise).astype(np.float32)
        new = tmp_path / f"noisy_{sigma}"
        write_clip(new, "adt", "a_0.npz", noisy)
        row = compare_dirs(str(ref_dir), str(new)).clips[0]
        assert row.scores.oa == 1.0
        expected = expected_apd(gt["tracks_XYZ"][..., 2].astype(np.float64), sigma)
        apd = row.scores.apd["none"]
        assert apd == pytest.approx(expected, abs=0.01), (sigma, apd, expected)
        results.append(row)
    for key in SCORE_KEYS:
        values = [row.scores.tapnet()[key] for row in results]
        assert values[0] > values[1] > values[2] > values[3], (key, values)
