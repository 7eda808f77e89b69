"""A run's error over time, read from its files: where a run went wrong, not just how much.

- Simulated data: ATE per pose, the distance (m) between trajectory.tum and groundtruth.tum
  (both written one pose per processed scan, same timestamps).
- Logs with relations (CARMEN + LOG.relations): the translational relation error (m) of
  every relation inside the run, at the time of its later scan. The relations file is found
  as the run found it: `dataset.relations`, else `<log stem>.relations` beside `dataset.path`.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from slamlab.report.rundir import RunDir

ATE = "ate"
RELATIONS = "relations"


@dataclass(frozen=True, slots=True)
class ErrorSeries:
    """`t` (s since the run's first pose, sorted) and `error_m` (m) of one run; `kind` is
    ATE or RELATIONS."""

    kind: str
    t: np.ndarray
    error_m: np.ndarray


def ate_series(run: RunDir) -> ErrorSeries | None:
    """Position error per pose against ground truth; None without both trajectories."""
    est, gt = run.load_trajectory("slam"), run.load_trajectory("groundtruth")
    if est is None or gt is None:
        return None
    n = min(len(est), len(gt))
    err = np.linalg.norm(est.xy[:n] - gt.xy[:n], axis=1)
    return ErrorSeries(ATE, est.t[:n] - est.t[0], err)


@lru_cache(maxsize=8)
def _relations(path: str):
    from slamlab.datasets.carmen import load_relations

    return load_relations(path)


def relations_file(run: RunDir) -> Path | None:
    """The relations file the run was scored with, if it can still be found."""
    ds = run.config.get("dataset")
    if not isinstance(ds, dict):
        return None
    # Relative paths in the config were relative to where the run was started.
    cwd = Path(str(run.manifest.get("cwd") or "."))
    if ds.get("relations"):
        p = cwd / str(ds["relations"])
        return p if p.is_file() else None
    if not ds.get("path"):
        return None
    from slamlab.datasets.carmen import _log_stem

    log = cwd / str(ds["path"])
    guess = log.parent / f"{_log_stem(log)}.relations"
    return guess if guess.is_file() else None


def relation_series(run: RunDir) -> ErrorSeries | None:
    """Translational error of each relation the run covers; None without relations."""
    from slamlab.eval.relations import relation_residuals
    from slamlab.pipeline import relations_within

    path = relations_file(run)
    est = run.load_trajectory("slam")
    if path is None or est is None:
        return None
    rel = relations_within(_relations(str(path.resolve())), est.t)
    if len(rel.t1) == 0:
        return None
    poses = np.column_stack([est.xy, est.yaw])
    trans_m, _rot = relation_residuals(est.t, poses, rel)
    t = np.maximum(rel.t1, rel.t2) - est.t[0]
    order = np.argsort(t, kind="stable")
    return ErrorSeries(RELATIONS, t[order], trans_m[order])


def error_series(run: RunDir) -> ErrorSeries | None:
    """ATE when the run has ground truth, else relation errors, else None."""
    return ate_series(run) or relation_series(run)
