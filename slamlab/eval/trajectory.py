"""Trajectory error against ground truth and map agreement against a true occupancy grid.

No alignment is applied to the main figures: the estimate and the truth share the odometry
frame at the start, so a drifted estimate is charged for its drift (that is what a user sees
on the map). `aligned_rmse_m` is the same RMSE after the best rigid 2-D alignment (rotation
and translation, as the TUM benchmark's ATE; `evo_ape -a` aligns in 3-D and refuses these
planar paths as degenerate): what is left is the shape of the path, without an offset the
filter picked up early (along a featureless corridor at the start, say) and kept.
"""

from __future__ import annotations

import numpy as np

from slamlab.frames import GridImage
from slamlab.geometry import FloatArray, se2_compose, se2_fit, wrap_angle


def trajectory_errors(estimate: FloatArray, truth: FloatArray) -> dict[str, float]:
    """Per-pose errors of (N, 3) estimated vs true poses (x m, y m, theta rad).

    Keys: rmse_m, mean_m, max_m, aligned_rmse_m (translation, m); rot_rmse_deg, rot_mean_deg,
    rot_max_deg."""
    est = np.asarray(estimate, dtype=np.float64).reshape(-1, 3)
    gt = np.asarray(truth, dtype=np.float64).reshape(-1, 3)
    if est.shape != gt.shape:
        raise ValueError(f"estimate has {len(est)} poses but truth has {len(gt)}")
    if len(est) == 0:
        nan = float("nan")
        return dict(rmse_m=nan, mean_m=nan, max_m=nan, aligned_rmse_m=nan, rot_rmse_deg=nan, rot_mean_deg=nan, rot_max_deg=nan)
    d = np.hypot(est[:, 0] - gt[:, 0], est[:, 1] - gt[:, 1])
    r = np.degrees(np.abs(wrap_angle(est[:, 2] - gt[:, 2])))
    return {
        "rmse_m": float(np.sqrt(np.mean(d**2))),
        "mean_m": float(np.mean(d)),
        "max_m": float(np.max(d)),
        "aligned_rmse_m": aligned_rmse(est[:, :2], gt[:, :2]),
        "rot_rmse_deg": float(np.sqrt(np.mean(r**2))),
        "rot_mean_deg": float(np.mean(r)),
        "rot_max_deg": float(np.max(r)),
    }


def aligned_rmse(estimate_xy: FloatArray, truth_xy: FloatArray) -> float:
    """RMSE (m) of (N, 2) positions after the rigid 2-D motion that best maps the estimate
    onto the truth (least squares, rotation and translation only: `geometry.se2_fit`)."""
    e = np.asarray(estimate_xy, dtype=np.float64).reshape(-1, 2)
    g = np.asarray(truth_xy, dtype=np.float64).reshape(-1, 2)
    moved = se2_compose(se2_fit(e, g), np.column_stack([e, np.zeros(len(e))]))[:, :2]
    return float(np.sqrt(np.mean(np.sum((moved - g) ** 2, axis=1))))


def sample_onto(src: GridImage, dst: GridImage) -> np.ndarray:
    """Values of `src` at the centres of `dst`'s cells (nearest cell), NaN outside `src`."""
    H, W = dst.data.shape[:2]
    xs = dst.origin_xy[0] + (np.arange(W) + 0.5) * dst.resolution_m
    ys = dst.origin_xy[1] + (np.arange(H) + 0.5) * dst.resolution_m
    c = np.floor((xs - src.origin_xy[0]) / src.resolution_m).astype(np.int64)
    r = np.floor((ys - src.origin_xy[1]) / src.resolution_m).astype(np.int64)
    out = np.full((H, W), np.nan)
    ok_r = (r >= 0) & (r < src.data.shape[0])
    ok_c = (c >= 0) & (c < src.data.shape[1])
    out[np.ix_(ok_r, ok_c)] = src.data[np.ix_(r[ok_r], c[ok_c])]
    return out


def map_agreement(
    log_odds: GridImage,
    truth: GridImage,
    occupied_threshold: float = 0.0,
    tolerance_cells: int = 1,
) -> dict[str, float]:
    """Compare an estimated log-odds map with a true occupancy grid (bool, True = wall).

    The estimate is sampled at the truth's cell centres. Only observed cells (log-odds != 0)
    count. Keys: `agreement` = fraction of observed cells whose occupied/free state matches
    the truth; `occupied_precision` = fraction of estimated walls within `tolerance_cells`
    of a true wall; `occupied_recall` = fraction of true walls that were observed and lie
    within `tolerance_cells` of an estimated wall; `observed_cells`.
    No alignment: a map built along a drifted path scores lower, as it should."""
    est = sample_onto(log_odds, truth)
    gt = np.asarray(truth.data).astype(bool)
    observed = np.isfinite(est) & (est != 0)
    est_occ = observed & (est > occupied_threshold)
    n_obs = int(observed.sum())
    if n_obs == 0:
        return {"agreement": float("nan"), "occupied_precision": float("nan"), "occupied_recall": float("nan"), "observed_cells": 0}
    from scipy.ndimage import binary_dilation  # here: only runs with a true map need it (~0.15 s to import)

    st = np.ones((3, 3), dtype=bool)
    it = max(int(tolerance_cells), 0)
    gt_near = binary_dilation(gt, st, iterations=it) if it else gt
    est_near = binary_dilation(est_occ, st, iterations=it) if it else est_occ
    agree = float(np.mean(est_occ[observed] == gt[observed]))
    prec = float(np.mean(gt_near[est_occ])) if est_occ.any() else float("nan")
    # recall over true walls the robot could have seen (near an observed cell)
    seen = binary_dilation(observed, st, iterations=max(it, 1)) & gt
    rec = float(np.mean(est_near[seen])) if seen.any() else float("nan")
    return {"agreement": agree, "occupied_precision": prec, "occupied_recall": rec, "observed_cells": n_obs}
