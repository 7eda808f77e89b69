"""ATE against ground truth: raw (the estimate keeps its offset) and after a rigid alignment."""

from __future__ import annotations

import numpy as np
import pytest

from slamlab.eval.trajectory import aligned_rmse, trajectory_errors


def _path(n: int = 400) -> np.ndarray:
    s = np.linspace(0.0, 2.0 * np.pi, n)
    return np.stack([10.0 * np.cos(s) + 3.0 * np.sin(3 * s), 6.0 * np.sin(s), s], axis=1)


def test_a_rigidly_moved_path_has_an_error_only_before_alignment():
    truth = _path()
    a, t = np.radians(7.0), np.array([0.4, -0.3])
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    est = truth.copy()
    est[:, :2] = truth[:, :2] @ rot.T + t
    e = trajectory_errors(est, truth)
    assert e["rmse_m"] > 0.5
    assert e["aligned_rmse_m"] == pytest.approx(0.0, abs=1e-9)


def test_alignment_never_adds_error_and_never_mirrors():
    rng = np.random.default_rng(0)
    truth = _path()
    est = truth + np.c_[rng.normal(0.0, 0.05, (len(truth), 2)), np.zeros(len(truth))]
    e = trajectory_errors(est, truth)
    assert e["aligned_rmse_m"] <= e["rmse_m"]
    assert e["aligned_rmse_m"] == pytest.approx(0.05 * np.sqrt(2), rel=0.15)
    mirrored = truth[:, :2] * np.array([1.0, -1.0])  # a reflection is no rigid motion
    assert aligned_rmse(mirrored, truth[:, :2]) > 1.0
