"""``compare`` scores as tapnet's ``evaluate_model.py`` does where scoring can go astray: NaN
predictions, missing and unreadable prediction files, prediction-only files, references holding
annotations only (as the release's ADT and Panoptic Studio files), clips of different lengths. Every
expected value is worked out by hand in the comments."""

import io
import json
import pickle

import cv2
import numpy as np
import pytest

from pipeline.audit.compare import Status, compare_dirs, main, read_reference
from pipeline.export.npz_writer import encode_npz
from pipeline.io.clip_reader import DEFAULT_LIMITS

# Frames of 16 x 32 px with f = 0.625 px: the evaluation scale 256 / min(16, 32) = 16 makes f = 10 px,
# so a d-pixel threshold is the 3D radius d * z / 10 m, at z = 2 m: 0.2, 0.4, 0.8, 1.6, 3.2 m.
HEIGHT, WIDTH = 16, 32
K = np.array([0.625, 0.625, 16.0, 8.0], np.float32)
JPEG = cv2.imencode(".jpg", np.zeros((HEIGHT, WIDTH, 3), np.uint8))[1].tobytes()
TAPNET_KEYS = (
    "aj_median",
    "apd_median",
    "aj_per_trajectory",
    "apd_per_trajectory",
    "aj_none",
    "apd_none",
    "oa",
)


def write_ref(root, key, tracks, query_t=0.0, visible=True):
    """A REF clip of tracks [T, N, 3], all visible (or none), every query at frame ``query_t``."""
    num_frames, num_tracks = tracks.shape[:2]
    arrays = {
        "images_jpeg_bytes": np.array([JPEG] * num_frames),
        "queries_xyt": np.tile(np.array([[8.0, 8.0, query_t]], np.float32), (num_tracks, 1)),
        "tracks_XYZ": tracks.astype(np.float32),
        "visibility": np.full((num_frames, num_tracks), visible),
        "fx_fy_cx_cy": K,
    }
    path = root / key
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(encode_npz(arrays))


def write_prediction(root, key, tracks, **extra):
    """A prediction file as tapnet's evaluator expects it: ``tracks_XYZ`` and ``visibility`` only
    (all visible), written by plain ``np.savez``; ``extra`` replaces or adds members."""
    path = root / key
    path.parent.mkdir(parents=True, exist_ok=True)
    members = {"tracks_XYZ": tracks.astype(np.float32), "visibility": np.ones(tracks.shape[:2], bool)}
    np.savez(path, **(members | extra))


def on_z_axis(*depths):
    """One frame of points (0, 0, z): [1, len(depths), 3]."""
    return np.array([[[0.0, 0.0, z] for z in depths]])


def at_2m(frames, tracks):
    """[T, N, 3] points at x = 0, 1, 2, ... m, y = 0, z = 2 m."""
    points = np.zeros((frames, tracks, 3))
    points[..., 0] = np.arange(tracks)
    points[..., 2] = 2.0
    return points


def test_nan_predictions_are_misses_and_leave_only_the_predictions_median(tmp_path):
    # 4 tracks on the z axis at 1, 2, 3, 4 m; track 0 predicted NaN, tracks 1-3 at twice the depth.
    ref, new = tmp_path / "ref", tmp_path / "new"
    write_ref(ref, "adt/a.npz", on_z_axis(1, 2, 3, 4))
    pred = on_z_axis(np.nan, 4, 6, 8)
    pred[0, 0] = np.nan
    write_prediction(new, "adt/a.npz", pred)
    row = compare_dirs(str(ref), str(new)).clips[0]
    assert row.status is Status.SCORED
    # median: nanmedian of the GT norms keeps track 0 (its GT is a number): median(1, 2, 3, 4) = 2.5;
    # the prediction's drops it: median(4, 6, 8) = 6. Scale 2.5 / 6 = 5/12 puts tracks 1-3 at 5z/6,
    # errors z/6 = 0.33, 0.5, 0.67 m against radii d * z / 10 = 0.2, 0.3, 0.4 m at 1 px (all miss)
    # and 0.4, 0.6, 0.8 m at 2 px (all within, so at 4, 8, 16 px too). Track 0 never within.
    # pts_within = 0, 3/4, 3/4, 3/4, 3/4 -> APD 0.6. jaccard: 1 px 0 / (4 + 4 false positives) = 0,
    # then 3 / (4 + 1) = 0.6 -> AJ 0.48. (Dropping track 0 from both medians gives scale 3 / 6,
    # every track 1-3 exact and APD 0.75; a plain median gives a NaN scale and 0.)
    assert row.scores.apd["median"] == pytest.approx(0.6)
    assert row.scores.aj["median"] == pytest.approx(0.48)
    # none: errors z = 2, 3, 4 m within only at 16 px (radius 1.6 z) -> pts_within_16 = 3/4,
    # APD 0.75 / 5 = 0.15; jaccard_16 = 3/5, the others 0 -> AJ 0.12.
    assert row.scores.apd["none"] == pytest.approx(0.15)
    assert row.scores.aj["none"] == pytest.approx(0.12)
    # per_trajectory: track 0's scale is NaN (a miss), tracks 1-3 scale by 1/2 and are exact:
    # pts_within 3/4 at every threshold, jaccard 3 / (4 + 1).
    assert row.scores.apd["per_trajectory"] == pytest.approx(0.75)
    assert row.scores.aj["per_trajectory"] == pytest.approx(0.6)
    assert row.scores.oa == 1.0
    # Unscaled errors inf (NaN), 2, 3, 4 -> median (3 + 4) / 2.
    assert row.scores.median_error_m == 3.5


def test_a_missing_prediction_file_counts_zero_and_is_named(tmp_path, capsys):
    ref, new = tmp_path / "ref", tmp_path / "new"
    for name in ("a", "b"):
        write_ref(ref, f"adt/{name}.npz", at_2m(1, 2))
    write_prediction(new, "adt/a.npz", at_2m(1, 2))
    out = tmp_path / "report"
    assert main([str(ref), str(new), "--out", str(out)]) == 0
    assert "not scored: adt/b.npz: no prediction file (counted as 0)" in capsys.readouterr().err
    report = json.loads(out.with_suffix(".json").read_text())
    assert [row["status"] for row in report["clips"]] == ["scored", "zero"]
    # a scores 1 everywhere, b 0 everywhere: every mean is (1 + 0) / 2.
    adt, overall = report["sources"]
    assert (adt["clips"], adt["zero"]) == (2, 1)
    for key in TAPNET_KEYS:
        assert adt[key] == overall[key] == 0.5, key
    # The median error is over the scored clip a only.
    assert adt["median_error_m"] == 0.0
    assert "| adt | b.npz | zero |" in out.with_suffix(".md").read_text()
    # No prediction at all: nothing scored, exit 1.
    (tmp_path / "empty").mkdir()
    assert main([str(ref), str(tmp_path / "empty"), "--out", str(out)]) == 1


def test_unreadable_predictions_count_zero(tmp_path):
    ref, new = tmp_path / "ref", tmp_path / "new"
    for name in ("a", "b", "c", "d"):
        write_ref(ref, f"adt/{name}.npz", at_2m(1, 2))
    write_prediction(new, "adt/a.npz", at_2m(1, 2))
    buffer = io.BytesIO()
    np.savez(buffer, tracks_XYZ=at_2m(1, 2), visibility=np.ones((1, 2), bool))
    (new / "adt" / "b.npz").write_bytes(buffer.getvalue()[: len(buffer.getvalue()) // 2])  # truncated zip
    np.savez(new / "adt" / "c.npz", tracks_XYZ=at_2m(1, 2))  # no visibility
    (new / "adt" / "d.npz").write_bytes(b"not an npz")
    report = compare_dirs(str(ref), str(new))
    assert [row.status.value for row in report.clips] == ["scored", "zero", "zero", "zero"]
    assert "not an .npz archive" in report.clips[1].error
    assert "missing ['visibility']" in report.clips[2].error
    # (1 + 0 + 0 + 0) / 4 on every tapnet metric.
    for key in TAPNET_KEYS:
        assert report.sources[0].means.tapnet()[key] == 0.25, key


def test_a_pickled_prediction_is_refused_unread_and_counts_zero(tmp_path, monkeypatch):
    # Deliberately unlike tapnet (np.load with allow_pickle=True would run it): never unpickled.
    def refuse(*args, **kwargs):
        raise AssertionError("compare unpickled something")

    ref, new = tmp_path / "ref", tmp_path / "new"
    write_ref(ref, "adt/a.npz", at_2m(1, 2))
    write_prediction(new, "adt/a.npz", at_2m(1, 2), tracks_XYZ=np.array([None, 1.0], dtype=object))
    monkeypatch.setattr(pickle, "load", refuse)
    monkeypatch.setattr(pickle, "loads", refuse)
    row = compare_dirs(str(ref), str(new)).clips[0]
    assert row.status is Status.ZERO
    assert "pickle" in row.error
    assert row.scores.aj["median"] == 0.0


def test_a_prediction_only_file_is_scored(tmp_path):
    # 4 tracks at z = 2 m, predicted off in x by 0, 0.3, 1.0, 5.0 m; radii 0.2, 0.4, 0.8, 1.6, 3.2 m.
    ref, new = tmp_path / "ref", tmp_path / "new"
    gt = at_2m(1, 4)
    write_ref(ref, "pstudio/a.npz", gt)
    pred = gt.copy()
    pred[0, :, 0] += [0.0, 0.3, 1.0, 5.0]
    write_prediction(new, "pstudio/a.npz", pred)
    assert sorted(np.load(new / "pstudio" / "a.npz").files) == ["tracks_XYZ", "visibility"]
    row = compare_dirs(str(ref), str(new)).clips[0]
    assert row.status is Status.SCORED
    # Within per threshold: 1, 2, 2, 3, 3 of 4 -> APD (1 + 2 + 2 + 3 + 3) / 4 / 5 = 0.55.
    # jaccard = c / (4 + (4 - c)) = 1/7, 2/6, 2/6, 3/5, 3/5 -> AJ = (1/7 + 2/3 + 6/5) / 5 = 0.401905.
    assert row.scores.apd["none"] == pytest.approx(0.55)
    assert row.scores.aj["none"] == pytest.approx(0.401905, abs=1e-6)
    assert row.scores.oa == 1.0
    # Median of the errors 0, 0.3, 1.0, 5.0 -> (0.3 + 1.0) / 2.
    assert row.scores.median_error_m == pytest.approx(0.65)


def test_a_reference_of_annotations_only_takes_the_camera_of_the_run_s_clip(tmp_path):
    # REF as the release's ADT files: queries, tracks and visibility, no frames, intrinsics or poses.
    # NEW a run's whole clip of 16 x 32 frames with f = 0.625 px: the radii are those of the module
    # doc. 4 tracks at z = 2 m, NEW's off in x by 0, 0.3, 1.0, 5.0 m.
    ref, new = tmp_path / "ref", tmp_path / "new"
    gt = at_2m(1, 4)
    queries = np.tile(np.array([[8.0, 8.0, 0.0]], np.float32), (4, 1))
    (ref / "adt").mkdir(parents=True)
    annotations = {"queries_xyt": queries, "tracks_XYZ": gt.astype(np.float32), "visibility": np.ones((1, 4))}
    (ref / "adt" / "a.npz").write_bytes(encode_npz(annotations))
    pred = gt.copy()
    pred[0, :, 0] += [0.0, 0.3, 1.0, 5.0]
    write_prediction(
        new, "adt/a.npz", pred, images_jpeg_bytes=np.array([JPEG]), queries_xyt=queries, fx_fy_cx_cy=K
    )
    clip = read_reference(str(ref / "adt" / "a.npz"), DEFAULT_LIMITS)
    assert (clip.name, clip.source, clip.frames, clip.frame_size) == ("a", "adt", (), None)
    assert clip.intrinsics is None and clip.extrinsics is None
    assert clip.visibility.dtype == bool and clip.visibility.all()  # stored as float64 ones
    row = compare_dirs(str(ref), str(new)).clips[0]
    assert row.status is Status.SCORED
    assert row.note == "frame size and intrinsics from the regenerated clip (the reference holds none)"
    # As for the prediction-only file: within 1, 2, 2, 3, 3 of 4 per threshold -> APD 0.55, AJ 0.401905.
    assert row.scores.apd["none"] == pytest.approx(0.55)
    assert row.scores.aj["none"] == pytest.approx(0.401905, abs=1e-6)
    # Agreement: the same query frames and visibility; distances 0, 300, 1000, 5000 mm: median 650,
    # p95 at rank 0.95 x 3 = 2.85, 1000 + 0.85 x 4000 = 4400.
    measured = row.agreement
    assert (measured.query_frames_equal, measured.visibility) == (1.0, 1.0)
    assert measured.median_mm == pytest.approx(650.0)
    assert measured.p95_mm == pytest.approx(4400.0)
    # A prediction of tracks and visibility only gives no camera either: counted 0, saying why.
    write_prediction(new, "adt/a.npz", pred)
    row = compare_dirs(str(ref), str(new)).clips[0]
    assert (row.status, row.error) == (Status.ZERO, "neither clip holds intrinsics (fx_fy_cx_cy)")


def test_prediction_members_are_capped_by_the_ref_clips_size(tmp_path):
    # REF holds 1 frame x 4 tracks: a tracks_XYZ of 50 frames is refused from its header alone.
    ref, new = tmp_path / "ref", tmp_path / "new"
    write_ref(ref, "adt/a.npz", at_2m(1, 4))
    write_prediction(new, "adt/a.npz", at_2m(50, 4))
    row = compare_dirs(str(ref), str(new)).clips[0]
    assert row.status is Status.ZERO
    assert "REF's clip has T = 1 frames and N = 4 tracks" in row.error
    assert "refused" in row.error


def test_clips_of_different_lengths_weigh_one_each_and_sources_one_each(tmp_path):
    ref, new = tmp_path / "ref", tmp_path / "new"
    far = np.array([10.0, 0.0, 0.0])  # beyond the largest radius, 3.2 m at z = 2 m
    # adt/a: 1 frame x 4 tracks, track 0 exact, tracks 1-3 far: pts_within 1/4, jaccard 1 / (4 + 3).
    write_ref(ref, "adt/a.npz", at_2m(1, 4))
    pred = at_2m(1, 4)
    pred[0, 1:] += far
    write_prediction(new, "adt/a.npz", pred)
    # adt/b: 2 frames x 1 track, exact: 1 and 1.
    write_ref(ref, "adt/b.npz", at_2m(2, 1))
    write_prediction(new, "adt/b.npz", at_2m(2, 1))
    # adt/c: REF 3 frames, prediction 2: another shape, counted 0 everywhere (OA too).
    write_ref(ref, "adt/c.npz", at_2m(3, 1))
    write_prediction(new, "adt/c.npz", at_2m(2, 1))
    # pstudio/d: 3 frames x 2 tracks, all far: pts_within 0, jaccard 0 / (6 + 6) = 0, OA 1.
    write_ref(ref, "pstudio/d.npz", at_2m(3, 2))
    write_prediction(new, "pstudio/d.npz", at_2m(3, 2) + far)
    report = compare_dirs(str(ref), str(new))
    assert [row.status.value for row in report.clips] == ["scored", "scored", "zero", "scored"]
    assert "shapes differ" in report.clips[2].error
    adt, pstudio, overall = report.sources
    # adt: each clip weighs 1 whatever its length: APD (1/4 + 1 + 0) / 3 = 5/12, AJ (1/7 + 1 + 0) / 3
    # = 8/21, OA (1 + 1 + 0) / 3 = 2/3. (Pooling adt's points would give APD (1 + 2 + 0) / 9 = 1/3.)
    assert adt.means.apd["none"] == pytest.approx(5 / 12)
    assert adt.means.aj["none"] == pytest.approx(8 / 21)
    assert adt.means.oa == pytest.approx(2 / 3)
    assert pstudio.means.apd["none"] == 0.0
    assert pstudio.means.aj["none"] == 0.0
    assert pstudio.means.oa == 1.0
    # all: the mean of the source means, APD (5/12 + 0) / 2 = 5/24, AJ 4/21, OA (2/3 + 1) / 2 = 5/6
    # (the mean over the 4 clips would give APD 5/16).
    assert overall.means.apd["none"] == pytest.approx(5 / 24)
    assert overall.means.aj["none"] == pytest.approx(4 / 21)
    assert overall.means.oa == pytest.approx(5 / 6)
    assert (overall.clips, overall.zero) == (4, 1)


def test_a_nan_clip_metric_makes_the_mean_nan_as_in_tapnet(tmp_path):
    # adt/a: no REF-visible point, 2 predicted visible: APD 0/0 = NaN, AJ 0 / (0 + 2) = 0, OA 0.
    # adt/b: exact, 1 everywhere. Plain means: APD NaN, AJ (0 + 1) / 2, OA (0 + 1) / 2.
    ref, new = tmp_path / "ref", tmp_path / "new"
    write_ref(ref, "adt/a.npz", at_2m(1, 2), visible=False)
    write_ref(ref, "adt/b.npz", at_2m(1, 2))
    for name in ("a", "b"):
        write_prediction(new, f"adt/{name}.npz", at_2m(1, 2))
    adt = compare_dirs(str(ref), str(new)).sources[0]
    assert np.isnan(adt.means.apd["none"])
    assert adt.means.aj["none"] == 0.5
    assert adt.means.oa == 0.5


def test_query_frames_outside_the_clip_zero_the_per_trajectory_scores_only(tmp_path):
    # REF's queries sit at frame 5 of a 1-frame clip: tapnet's per-trajectory scaling fails (0),
    # the median and unscaled scores of the exact prediction are 1.
    ref, new = tmp_path / "ref", tmp_path / "new"
    write_ref(ref, "adt/a.npz", at_2m(1, 2), query_t=5.0)
    write_prediction(new, "adt/a.npz", at_2m(1, 2))
    row = compare_dirs(str(ref), str(new)).clips[0]
    assert row.scores.aj["per_trajectory"] == row.scores.apd["per_trajectory"] == 0.0
    assert row.scores.aj["median"] == row.scores.apd["none"] == row.scores.oa == 1.0
    assert "per_trajectory counted as 0" in row.note


def test_a_clip_list_picks_the_benchmark_and_a_missing_ref_clip_is_left_out(tmp_path, capsys):
    # As tapnet's use_minival: only the listed REF clips count (b, unpredicted, is not listed).
    ref, new, out = tmp_path / "ref", tmp_path / "new", tmp_path / "report"
    for name in ("a", "b"):
        write_ref(ref, f"adt/{name}.npz", at_2m(1, 2))
    write_prediction(new, "adt/a.npz", at_2m(1, 2))
    listing = tmp_path / "minival.txt"
    listing.write_text("adt/a.npz\n\n")
    assert main([str(ref), str(new), "--clips", str(listing), "--out", str(out)]) == 0
    report = json.loads(out.with_suffix(".json").read_text())
    assert [row["clip"] for row in report["clips"]] == ["a.npz"]
    assert report["sources"][-1]["aj_median"] == 1.0
    # A listed clip REF lacks is named and left out of the means (tapnet would stop); a is scored.
    listing.write_text("adt/a.npz\nadt/zz.npz\n")
    assert main([str(ref), str(new), "--clips", str(listing), "--out", str(out)]) == 0
    assert "not scored: adt/zz.npz: not in REF (REF holds no clip of this name)" in capsys.readouterr().err
    report = json.loads(out.with_suffix(".json").read_text())
    assert report["sources"][-1]["aj_median"] == 1.0
    assert (report["sources"][-1]["not_in_ref"], report["sources"][-1]["ref_errors"]) == (1, 0)
    listing.write_text("adt/zz.npz\n")  # nothing scorable
    assert main([str(ref), str(new), "--clips", str(listing), "--out", str(out)]) == 1
    listing.write_text("a.npz\n")
    assert main([str(ref), str(new), "--clips", str(listing), "--out", str(out)]) == 2
