"""TAPVid-3D metrics (Koppula et al., NeurIPS 2024, section 3.5) on NumPy arrays.

Re-implements tapnet's ``tapvid3d/evaluation/metrics.py`` (``compute_tapvid3d_metrics``) for one
clip of [T, N] arrays with the same arithmetic (dtypes, order of operations), so that the scores
agree with tapnet's to the last bit:

- every frame of every track is scored, the query frame included (query points only pick the
  frame used by per-trajectory rescaling);
- a pixel threshold d becomes, at each ground-truth point, the 3D radius ``d * (z_gt / sqrt(fx * fy))``
  with the intrinsics rescaled by ``256 / min(H, W)`` (the official evaluation resizes the frame's
  smaller side to 256); a prediction is within it when its squared distance is strictly smaller;
- the prediction is rescaled before scoring: "median" multiplies it by
  nanmedian(|gt|) / nanmedian(|pred|), each over the points visible in both and not NaN (so a NaN
  prediction leaves the prediction's median only), "per_trajectory" multiplies each track by
  z_gt / z_pred at its query frame (both clamped at 1e-12), "none" multiplies it by 1.0;
- a NaN prediction is never within a threshold: it is a miss, and a false positive where it is
  predicted visible. With no point visible in both, the median scale is NaN and every point misses;
  with no ground-truth-visible point, APD (and AJ when nothing is predicted visible) is NaN.
"""

from __future__ import annotations

import warnings

import numpy as np

PIXEL_THRESHOLDS = (1, 2, 4, 8, 16)
EVAL_RESOLUTION = 256
SCALINGS = ("median", "per_trajectory", "none")
TINY = 1e-12


def eval_intrinsics(fx_fy_cx_cy: np.ndarray, height: int, width: int) -> np.ndarray:
    """Intrinsics [4] of the stored frames rescaled so the smaller image side is 256 px: [4]."""
    return np.asarray(fx_fy_cx_cy) * np.float64(EVAL_RESOLUTION / min(height, width))


def threshold_radii(gt_tracks: np.ndarray, fx_fy_cx_cy: np.ndarray, pixels: float) -> np.ndarray:
    """3D radius of a ``pixels`` threshold at each ground-truth point: [T, N, 3] -> [T, N] metres."""
    return pixels * (gt_tracks[..., 2] / np.sqrt(fx_fy_cx_cy[0] * fx_fy_cx_cy[1]))


def query_frame_indices(query_t: np.ndarray, num_frames: int) -> np.ndarray | None:
    """The frame [N] of each query time [N] as tapnet indexes it: rounded, a negative one counting
    from the end; None when one is no index of T frames (tapnet's scaling then fails)."""
    frames = np.round(np.asarray(query_t, np.float64))
    if not (np.isfinite(frames) & (frames >= -num_frames) & (frames < num_frames)).all():
        return None
    return frames.astype(np.int64) % num_frames


def _median_norm(tracks: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """nanmedian of the norms of ``tracks`` [T, N, 3] where ``keep`` [T, N], in float64 (at least):
    [1, 1]; NaN when no such norm is a number."""
    norms = np.sqrt(np.maximum(np.sum(np.square(tracks), axis=-1), TINY))
    masked = np.where(keep, norms, np.full(norms.shape, np.nan))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all NaN: nothing to take the median of
        return np.nanmedian(masked, axis=(0, 1), keepdims=True)


def rescale(
    gt_tracks: np.ndarray,
    gt_visible: np.ndarray,
    pred_tracks: np.ndarray,
    pred_visible: np.ndarray,
    query_frames: np.ndarray | None,
    scaling: str,
) -> np.ndarray:
    """The prediction [T, N, 3] rescaled to the ground truth [T, N, 3] by ``scaling`` (see module doc).

    Visibilities are [T, N] bool; ``query_frames`` [N] are the tracks' query frame indices (used by
    "per_trajectory" only).
    """
    if scaling == "none":
        return pred_tracks * 1.0
    if scaling == "per_trajectory":
        tracks = np.arange(gt_tracks.shape[1])
        gt_z = np.maximum(gt_tracks[query_frames, tracks, 2], TINY)
        pred_z = np.maximum(pred_tracks[query_frames, tracks, 2], TINY)
        return pred_tracks * (gt_z / pred_z)[:, None]
    if scaling == "median":
        both = gt_visible & pred_visible
        return pred_tracks * (_median_norm(gt_tracks, both) / _median_norm(pred_tracks, both))
    raise ValueError(f"unknown scaling {scaling!r}; expected one of {SCALINGS}")


def tapvid3d_metrics(
    gt_tracks: np.ndarray,
    gt_visible: np.ndarray,
    pred_tracks: np.ndarray,
    pred_visible: np.ndarray,
    eval_fx_fy_cx_cy: np.ndarray,
    query_frames: np.ndarray | None,
    scaling: str = "median",
) -> dict[str, float]:
    """3D-AJ, APD and OA of one clip, with the per-threshold values they average.

    Tracks are [T, N, 3] (camera frame, metres; any float dtype, computed in it as tapnet does),
    visibilities [T, N] bool, ``eval_fx_fy_cx_cy`` [4] the intrinsics at the evaluation scale
    (``eval_intrinsics``), ``query_frames`` [N] int (``query_frame_indices``).
    Over all (t, n): OA = fraction where the visibilities agree; for each threshold,
    pts_within = |within & gt_vis| / |gt_vis| and
    jaccard = |within & gt_vis & pred_vis| / (|gt_vis| + |pred_vis & (~gt_vis | ~within)|).
    ``average_jaccard`` (3D-AJ) and ``average_pts_within`` (APD) average these over 1, 2, 4, 8, 16 px.
    """
    gt_tracks, pred_tracks = np.asarray(gt_tracks), np.asarray(pred_tracks)
    pred = rescale(gt_tracks, gt_visible, pred_tracks, pred_visible, query_frames, scaling)
    squared_error = np.sum(np.square(pred - gt_tracks), axis=-1)
    num_visible = np.count_nonzero(gt_visible)
    metrics = {"occlusion_accuracy": float(np.mean(gt_visible == pred_visible))}
    jaccards, withins = [], []
    for pixels in PIXEL_THRESHOLDS:
        within = squared_error < np.square(threshold_radii(gt_tracks, eval_fx_fy_cx_cy, pixels))
        correct = within & gt_visible
        false_positives = np.count_nonzero(pred_visible & ~correct)
        with np.errstate(divide="ignore", invalid="ignore"):
            pts_within = np.float64(np.count_nonzero(correct)) / num_visible
            jaccard = np.float64(np.count_nonzero(correct & pred_visible)) / (num_visible + false_positives)
        metrics[f"pts_within_{pixels}"] = float(pts_within)
        metrics[f"jaccard_{pixels}"] = float(jaccard)
        withins.append(pts_within)
        jaccards.append(jaccard)
    metrics["average_jaccard"] = float(np.mean(jaccards))
    metrics["average_pts_within"] = float(np.mean(withins))
    return metrics


def median_error(gt_tracks: np.ndarray, gt_visible: np.ndarray, pred_tracks: np.ndarray) -> float:
    """Median 3D distance (metres, no rescaling) over ground-truth-visible points, a NaN prediction
    counting as infinitely far: [T, N, 3] x2, [T, N]. Not a tapnet metric."""
    if not gt_visible.any():
        return float("nan")
    diff = np.asarray(pred_tracks, np.float64)[gt_visible] - np.asarray(gt_tracks, np.float64)[gt_visible]
    distances = np.linalg.norm(diff, axis=-1)
    return float(np.median(np.where(np.isnan(distances), np.inf, distances)))
