"""The relation-based SLAM accuracy metric of Kuemmerle et al. (Autonomous Robots, 2009).

A relation says "the robot pose at time t2, seen from the robot pose at time t1, is `rel`".
For an estimated trajectory P (one SE(2) pose per scan) each relation gives an error

    e = inv(P(t1)) (+) P(t2)        the estimate's relative motion
    d = inv(rel) (+) e              what is left once the reference motion is removed

translational error |d.xy| (m), rotational error |wrap(d.theta)| (deg). The summary is the
mean and sample standard deviation (ddof=1, which reproduces the published raw-odometry
reference values) of the absolute errors and of their squares.

Poses are looked up by timestamp, never by index: some logs (Intel) have clocks that step
back, so the scan order and the time order differ.
"""

from __future__ import annotations

import numpy as np

from slamlab.datasets.stamps import nearest_index
from slamlab.frames import Relations
from slamlab.geometry import FloatArray, se2_between, se2_compose, se2_inverse, wrap_angle

# Relation stamps are snapped to scan times when a log is loaded (slamlab.datasets.relations),
# so matching times are equal; the tolerance only absorbs conversions through other tools.
DEFAULT_TIME_TOL_S = 1e-6
# relations spanning this long or longer (s) are loop relations (`relation_errors`); the
# benchmark logs' relations nearly all span under 10 s or over 60 s (between: Intel 4 of 2,984,
# ACES 13 of 1,279), so the split hardly depends on the value
LOOP_MIN_DT_S = 30.0
SPAN_KEYS = ("count", "trans_abs_mean_m", "trans_abs_std_m", "rot_abs_mean_deg", "rot_abs_std_deg")


def find_times(
    times: np.ndarray, query: np.ndarray, tol_s: float = DEFAULT_TIME_TOL_S
) -> tuple[np.ndarray, np.ndarray]:
    """(index, found): for each `query` time (s), the index into `times` (s, any order) of
    the equal entry, and whether there is one. Unfound entries have index -1.

    Two times match when they differ by at most `tol_s` seconds (widened to a few float64
    ulps for large epoch times). Where several scans share a time the first in file order
    wins; a query exactly halfway between two scan times takes the earlier one.
    """
    times = np.asarray(times, dtype=np.float64).reshape(-1)
    query = np.asarray(query, dtype=np.float64).reshape(-1)
    if times.size == 0:
        return np.full(query.size, -1, dtype=np.intp), np.zeros(query.size, dtype=bool)
    order = np.argsort(times, kind="stable")  # stable: equal times keep file order
    sorted_t = times[order]
    best = nearest_index(sorted_t, query)
    # A run of equal times: step back to its first member so file order decides.
    best = np.searchsorted(sorted_t, sorted_t[best], side="left")
    tol = np.maximum(tol_s, 8.0 * np.spacing(np.abs(query)))
    ok = np.abs(sorted_t[best] - query) <= tol
    return np.where(ok, order[best], -1), ok


def match_times(times: np.ndarray, query: np.ndarray, tol_s: float = DEFAULT_TIME_TOL_S) -> np.ndarray:
    """Index into `times` (s, any order) of the entry equal to each `query` time (s), as in
    `find_times`. Raises ValueError naming the unmatched times when any query has no match.
    """
    query = np.asarray(query, dtype=np.float64).reshape(-1)
    idx, ok = find_times(times, query, tol_s)
    if not np.all(ok):
        missing = query[~ok]
        shown = ", ".join(f"{t:.6f}" for t in missing[:5])
        more = f" (and {missing.size - 5} more)" if missing.size > 5 else ""
        raise ValueError(
            f"{missing.size} relation time(s) have no pose within {tol_s:g} s: {shown}{more}; "
            "every scan of the log needs a pose"
        )
    return idx


def relation_residuals(
    times: np.ndarray, poses: np.ndarray, relations: Relations, time_tol_s: float = DEFAULT_TIME_TOL_S
) -> tuple[FloatArray, FloatArray]:
    """Per-relation errors: (translational m, rotational rad, signed in [-pi, pi)), shape (M,).

    `times` (N,) are the scan times (s) and `poses` (N, 3) the estimated (x m, y m, theta rad)
    at those scans, in any order (typically file order).
    """
    times = np.asarray(times, dtype=np.float64).reshape(-1)
    poses = np.asarray(poses, dtype=np.float64)
    if poses.ndim != 2 or poses.shape[1] != 3:
        raise ValueError(f"poses must have shape (N, 3), got {poses.shape}")
    if poses.shape[0] != times.size:
        raise ValueError(f"{times.size} times but {poses.shape[0]} poses")
    rel = np.asarray(relations.rel, dtype=np.float64).reshape(-1, 3)
    i1 = match_times(times, relations.t1, time_tol_s)
    i2 = match_times(times, relations.t2, time_tol_s)
    est = se2_between(poses[i1], poses[i2])
    d = se2_compose(se2_inverse(rel), est)
    return np.hypot(d[:, 0], d[:, 1]), wrap_angle(d[:, 2])


def relation_errors(
    times: np.ndarray,
    poses: np.ndarray,
    relations: Relations,
    time_tol_s: float = DEFAULT_TIME_TOL_S,
    loop_min_dt_s: float | None = None,
) -> dict:
    """Kuemmerle et al. relation errors of a trajectory, as plain Python numbers.

    Keys: count (int, relations used); trans_abs_mean_m, trans_abs_std_m, trans_sq_mean_m2, trans_sq_std_m2
    (metres); rot_abs_mean_deg, rot_abs_std_deg, rot_sq_mean_deg2, rot_sq_std_deg2
    (degrees). Standard deviations are sample (ddof=1; NaN for a single relation). With no
    relations the statistics are NaN. Raises ValueError if a relation time has no pose in `times`.

    With `loop_min_dt_s` (s, e.g. `LOOP_MIN_DT_S`) also "local" and "loop": the count, means
    and standard deviations (`SPAN_KEYS`) of the relations spanning under it (|t2 - t1|) and
    of the rest. Why: the two answer different questions. A local relation spans a few scans
    (tracking); a loop relation compares a revisit with the first visit minutes earlier, so
    it is only small when the loop closed. A mean over both hides which one failed (Intel:
    1,211 loop relations of 2,984; ACES: 90 of 1,279, which carry the online estimate's gap to
    the smoothed one).
    """
    trans_m, rot_rad = relation_residuals(times, poses, relations, time_tol_s)
    out: dict = _summary(trans_m, rot_rad)
    if loop_min_dt_s is not None:
        loop = _loop_mask(relations, loop_min_dt_s)
        for name, keep in (("local", ~loop), ("loop", loop)):  # the squares' statistics stay with the whole
            out[name] = {k: v for k, v in _summary(trans_m[keep], rot_rad[keep]).items() if k in SPAN_KEYS}
    return out


def loop_end_offsets(
    times: np.ndarray,
    online: np.ndarray,
    smoothed: np.ndarray,
    relations: Relations,
    loop_min_dt_s: float = LOOP_MIN_DT_S,
    time_tol_s: float = DEFAULT_TIME_TOL_S,
) -> dict[str, float]:
    """Where an online estimate's loop-relation error sits: the mean distance (m) between the
    online and the smoothed positions at the earlier pose of each loop relation (`start_m`)
    and at the later one (`end_m`); NaN without loop relations.

    Both paths come from one filter and start at the same pose, so they share a frame. A
    large `start_m` with a small `end_m` says the online path was elsewhere than the
    surviving hypothesis *before* the loop closed (uncertainty that only the return resolves,
    which no causal estimate can undo); a large `end_m` says the online path lags at the
    return itself."""
    loop = _loop_mask(relations, loop_min_dt_s)
    if not loop.any():
        return {"start_m": float("nan"), "end_m": float("nan")}
    t1 = np.asarray(relations.t1, dtype=np.float64)[loop]
    t2 = np.asarray(relations.t2, dtype=np.float64)[loop]
    times = np.asarray(times, dtype=np.float64).reshape(-1)
    d_xy = np.asarray(online, dtype=np.float64)[:, :2] - np.asarray(smoothed, dtype=np.float64)[:, :2]

    def gap(at: np.ndarray) -> float:
        d = d_xy[match_times(times, at, time_tol_s)]
        return float(np.mean(np.hypot(d[:, 0], d[:, 1])))

    # either order of t1 and t2: the earlier time is the first visit, the later the return
    return {"start_m": gap(np.minimum(t1, t2)), "end_m": gap(np.maximum(t1, t2))}


def _loop_mask(relations: Relations, loop_min_dt_s: float) -> np.ndarray:
    """Which relations are loop relations: spanning `loop_min_dt_s` or more, in either order (a revisit)."""
    return np.abs(np.asarray(relations.t2, dtype=np.float64) - np.asarray(relations.t1, dtype=np.float64)) >= loop_min_dt_s


def _summary(trans_m: FloatArray, rot_rad: FloatArray) -> dict[str, float]:
    """`relation_errors`' statistics of per-relation errors (m, rad)."""
    rot_deg = np.degrees(np.abs(rot_rad))

    def stats(values: np.ndarray) -> tuple[float, float]:
        if values.size == 0:
            return float("nan"), float("nan")
        std = float(np.std(values, ddof=1)) if values.size > 1 else float("nan")
        return float(np.mean(values)), std

    t_mean, t_std = stats(trans_m)
    t2_mean, t2_std = stats(trans_m**2)
    r_mean, r_std = stats(rot_deg)
    r2_mean, r2_std = stats(rot_deg**2)
    return {
        "count": int(trans_m.size),
        "trans_abs_mean_m": t_mean,
        "trans_abs_std_m": t_std,
        "trans_sq_mean_m2": t2_mean,
        "trans_sq_std_m2": t2_std,
        "rot_abs_mean_deg": r_mean,
        "rot_abs_std_deg": r_std,
        "rot_sq_mean_deg2": r2_mean,
        "rot_sq_std_deg2": r2_std,
    }
