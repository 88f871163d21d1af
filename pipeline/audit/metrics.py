"""TAPVid-3D metrics (Koppula et al., NeurIPS 2024, section 3.5) on NumPy arrays.

Definitions follow tapnet's ``tapvid3d/evaluation/metrics.py`` (``compute_tapvid3d_metrics``) and
``evaluate_model.py`` (``evaluate_data_source``), re-implemented here for [T, N] arrays:

- every frame of every track is scored, the query frame included (the official function masks
  nothing; query points only pick the frame used by per-trajectory rescaling);
- a pixel threshold d becomes, at each ground-truth point, the 3D radius ``d * z_gt / sqrt(fx * fy)``
  with the intrinsics rescaled by ``256 / min(H, W)`` (the official evaluation resizes the frame's
  smaller side to 256); a prediction is within it when its squared distance is strictly smaller;
- the prediction is rescaled before scoring: "median" multiplies it by median(|gt|) / median(|pred|)
  over the points visible in both, "per_trajectory" multiplies each track by z_gt / z_pred at its
  query frame, "none" leaves it as is.
"""

from __future__ import annotations

import numpy as np

PIXEL_THRESHOLDS = (1, 2, 4, 8, 16)
EVAL_RESOLUTION = 256
SCALINGS = ("median", "per_trajectory", "none")
TINY = 1e-12


def eval_intrinsics(fx_fy_cx_cy: np.ndarray, height: int, width: int) -> np.ndarray:
    """Intrinsics [4] of the stored frames rescaled so the smaller image side is 256 px: [4] float64."""
    return np.asarray(fx_fy_cx_cy, np.float64) * (EVAL_RESOLUTION / min(height, width))


def threshold_radii(gt_tracks: np.ndarray, fx_fy_cx_cy: np.ndarray, pixels: float) -> np.ndarray:
    """3D radius of a ``pixels`` threshold at each ground-truth point: [T, N, 3] -> [T, N] metres."""
    return pixels * gt_tracks[..., 2] / np.sqrt(fx_fy_cx_cy[0] * fx_fy_cx_cy[1])


def rescale(
    gt_tracks: np.ndarray,
    gt_visible: np.ndarray,
    pred_tracks: np.ndarray,
    pred_visible: np.ndarray,
    query_frames: np.ndarray,
    scaling: str,
) -> np.ndarray:
    """The prediction [T, N, 3] rescaled to the ground truth [T, N, 3] by ``scaling`` (see module doc).

    Visibilities are [T, N] bool; ``query_frames`` [N] are the tracks' query frame indices.
    A clip with no point visible in both gets a NaN median scale (every point then misses).
    """
    if scaling == "none":
        return pred_tracks
    if scaling == "per_trajectory":
        tracks = np.arange(gt_tracks.shape[1])
        gt_z = np.maximum(gt_tracks[query_frames, tracks, 2], TINY)
        pred_z = np.maximum(pred_tracks[query_frames, tracks, 2], TINY)
        return pred_tracks * (gt_z / pred_z)[None, :, None]
    if scaling == "median":
        both = gt_visible & pred_visible
        if not both.any():
            return np.full_like(pred_tracks, np.nan)
        gt_norms = np.sqrt(np.maximum(np.sum(np.square(gt_tracks[both]), axis=-1), TINY))
        pred_norms = np.sqrt(np.maximum(np.sum(np.square(pred_tracks[both]), axis=-1), TINY))
        return pred_tracks * (np.median(gt_norms) / np.median(pred_norms))
    raise ValueError(f"unknown scaling {scaling!r}; expected one of {SCALINGS}")


def tapvid3d_metrics(
    gt_tracks: np.ndarray,
    gt_visible: np.ndarray,
    pred_tracks: np.ndarray,
    pred_visible: np.ndarray,
    eval_fx_fy_cx_cy: np.ndarray,
    query_frames: np.ndarray,
    scaling: str = "median",
) -> dict[str, float]:
    """3D-AJ, APD and OA of one clip, with the per-threshold values they average.

    Tracks are [T, N, 3] (camera frame, metres), visibilities [T, N] bool, ``eval_fx_fy_cx_cy`` [4]
    the intrinsics at the evaluation scale (``eval_intrinsics``), ``query_frames`` [N] int.
    Over all (t, n): OA = fraction where the visibilities agree; for each threshold,
    pts_within = |within & gt_vis| / |gt_vis| and
    jaccard = |within & gt_vis & pred_vis| / (|gt_vis| + |pred_vis & (~gt_vis | ~within)|).
    ``average_jaccard`` (3D-AJ) and ``average_pts_within`` (APD) average these over 1, 2, 4, 8, 16 px.
    A clip with no visible ground-truth point gets NaN for everything but OA.
    """
    gt_tracks = np.asarray(gt_tracks, np.float64)
    pred = rescale(
        gt_tracks, gt_visible, np.asarray(pred_tracks, np.float64), pred_visible, query_frames, scaling
    )
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
    """Median 3D distance (metres, no rescaling) over ground-truth-visible points: [T, N, 3] x2, [T, N]."""
    if not gt_visible.any():
        return float("nan")
    diff = np.asarray(pred_tracks, np.float64)[gt_visible] - np.asarray(gt_tracks, np.float64)[gt_visible]
    return float(np.median(np.linalg.norm(diff, axis=-1)))
