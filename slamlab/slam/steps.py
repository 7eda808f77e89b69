"""Which scans the filter processes, and how the scans in between get a pose.

Selection (config `steps.*`): drop the static start (scans before the odometry first
changes, keeping the last static one so the first map is built at rest), then take every
k-th scan, or, when `min_distance_m` or `min_angle_rad` is > 0, a scan once the odometry
path since the last processed scan is that long (m) or has turned that much (rad).
Filling: a scan between processed steps k and k+1 gets the pose of step k composed with
the motion since step k's scan: the odometry increment, or the scan's matched motion where
the engine has one (`steps.between=match`); scans before the first step take the odometry,
backwards.
"""

from __future__ import annotations

import numpy as np

from slamlab.geometry import FloatArray, se2_between, se2_compose, wrap_angle

STATIC_EPS_M = 1e-4  # odometry changes below these count as standing still
STATIC_EPS_RAD = 1e-4


def first_move(odometry: FloatArray) -> int | None:
    """The index of the first scan whose odometry (N, 3) leaves the first scan's pose by more
    than STATIC_EPS_M or STATIC_EPS_RAD; None when it never does (a log without odometry)."""
    d = se2_between(odometry[0], odometry)
    moved = np.flatnonzero((np.hypot(d[:, 0], d[:, 1]) > STATIC_EPS_M) | (np.abs(d[:, 2]) > STATIC_EPS_RAD))
    return int(moved[0]) if len(moved) else None


def select_steps(
    odometry: FloatArray,
    every: int = 1,
    min_distance_m: float = 0.0,
    min_angle_rad: float = 0.0,
    skip_static_start: bool = True,
) -> np.ndarray:
    """Indices (int64, increasing) of the scans to process, given (N, 3) odometry."""
    n = len(odometry)
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    start = 0
    if skip_static_start:
        moved = first_move(odometry)
        start = max(moved - 1, 0) if moved is not None else n - 1
    if min_distance_m <= 0 and min_angle_rad <= 0:
        return np.arange(start, n, every, dtype=np.int64)
    inc = se2_between(odometry[start:-1], odometry[start + 1 :])
    dist = np.hypot(inc[:, 0], inc[:, 1])
    turn = np.abs(wrap_angle(inc[:, 2]))
    out = [start]
    acc_d = acc_a = 0.0
    # a plain loop: the accumulator resets at each selected scan, so this is not a cumsum
    for i in range(len(inc)):
        acc_d += dist[i]
        acc_a += turn[i]
        if (min_distance_m > 0 and acc_d >= min_distance_m) or (min_angle_rad > 0 and acc_a >= min_angle_rad):
            out.append(start + i + 1)
            acc_d = acc_a = 0.0
    return np.asarray(out, dtype=np.int64)


def fill_between_steps(step_scans: np.ndarray, step_poses: FloatArray, odometry: FloatArray, motion: FloatArray | None = None) -> FloatArray:
    """(N, 3) pose for every scan: the latest processed step's pose (+) the motion since,
    which is `motion[i]` (N, 3; the scan's matched motion from its step) where that row is
    set (not NaN), else the odometry since the step.

    `step_scans` (K,) increasing scan indices, `step_poses` (K, 3) their estimates."""
    n = len(odometry)
    k = np.searchsorted(step_scans, np.arange(n), side="right") - 1
    k = np.clip(k, 0, len(step_scans) - 1)  # scans before the first step use step 0
    anchor = step_scans[k]
    since = se2_between(odometry[anchor], odometry)
    if motion is not None:
        known = ~np.isnan(motion[:, 0])
        since[known] = motion[known]
    return se2_compose(step_poses[k], since)
