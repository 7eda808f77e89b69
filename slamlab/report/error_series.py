"""A run's error over time, read from its files: where a run went wrong, not just how much.

- Simulated data: ATE per pose, the distance (m) between trajectory.tum and groundtruth.tum
  (both written one pose per processed scan, same timestamps).
- Logs with relations (CARMEN + LOG.relations): the translational relation error (m) of
  every relation inside the run, at the time of its later scan, from the run's relations.csv.
"""

from __future__ import annotations

from dataclasses import dataclass
import numpy as np

from slamlab.geometry import wrap_angle
from slamlab.io.rundir import RunFile
from slamlab.report.rundir import RunDir, Trajectory

ATE = "ate"
RELATIONS = "relations"


@dataclass(frozen=True, slots=True)
class ErrorSeries:
    """`t` (s since the run's first pose, sorted) and `error_m` (m) of one run; `kind` is
    ATE or RELATIONS."""

    kind: str
    t: np.ndarray
    error_m: np.ndarray


def pose_errors(estimate: Trajectory, truth: Trajectory) -> tuple[np.ndarray, np.ndarray]:
    """Per-pose translation (m) and absolute heading (deg) error of `estimate` against
    `truth`, pose by pose (both files hold one pose per scan, same order)."""
    n = min(len(estimate), len(truth))
    d = np.hypot(*(estimate.xy[:n] - truth.xy[:n]).T)
    r = np.degrees(np.abs(wrap_angle(estimate.yaw[:n] - truth.yaw[:n])))
    return d, r


def ate_series(run: RunDir) -> ErrorSeries | None:
    """Position error per pose against ground truth; None without both trajectories."""
    est, gt = run.load_trajectory("slam"), run.load_trajectory("groundtruth")
    if est is None or gt is None:
        return None
    err, _ = pose_errors(est, gt)
    return ErrorSeries(ATE, est.t[: len(err)] - est.t[0], err)


def relation_series(run: RunDir) -> ErrorSeries | None:
    """Translational error of each relation the run covers, at the time of its later scan,
    from the run's relations.csv; None without one."""
    est = run.load_trajectory("slam")
    table = run.files.read_columns(RunFile.RELATIONS) if est is not None else None
    if table is None or not len(table):
        return None
    t = np.maximum(np.asarray(table["t1"], float), np.asarray(table["t2"], float)) - est.t[0]
    order = np.argsort(t, kind="stable")
    return ErrorSeries(RELATIONS, t[order], np.asarray(table["slam_trans_m"], float)[order])


def error_series(run: RunDir) -> ErrorSeries | None:
    """ATE when the run has ground truth, else relation errors, else None."""
    return ate_series(run) or relation_series(run)
