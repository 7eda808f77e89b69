"""How far a particle cloud spreads under the motion model alone (`mode: predict`).

Two numbers per step, each measured on the particles and expected from the configured noise:
- position spread (m): sqrt(var x + var y), the RMS distance of the particles from their
  mean position;
- heading spread (rad): the standard deviation of the particles' headings.

The expected values come from propagating the covariance of the pose to first order along
the noise-free odometry (the textbook EKF prediction):
    Sigma' = F Sigma F^T + G Q G^T,
F = d(p (+) u)/dp, G = d(p (+) u)/du, Q the covariance of the noisy increment
(`MotionModel.increment_covariance`). Heading noise turns into sideways spread through F, so
the position spread grows faster than the per-step noise alone would say. For the small
per-step noise of the motion presets the first-order error is well below the sampling error
of 100 particles (about 1 / sqrt(2 N) = 7 % of a standard deviation).
"""

from __future__ import annotations

import numpy as np

from slamlab.geometry import FloatArray, se2_between, se2_compose, wrap_angle
from slamlab.slam.motion import MotionModel


def cloud_spread(poses: FloatArray) -> tuple[float, float]:
    """(position spread m, heading spread rad) of a particle set (N, 3); see module doc."""
    p = np.asarray(poses, dtype=np.float64)
    xy = float(np.sqrt(np.var(p[:, 0]) + np.var(p[:, 1])))
    mean_th = float(np.arctan2(np.mean(np.sin(p[:, 2])), np.mean(np.cos(p[:, 2]))))
    th = float(np.std(wrap_angle(p[:, 2] - mean_th)))
    return xy, th


def propagate_covariance(cov: FloatArray, pose: FloatArray, increment: FloatArray, increment_cov: FloatArray) -> FloatArray:
    """The (3, 3) covariance of `pose (+) noisy increment` given `cov` of `pose` (first order)."""
    th = float(pose[2])
    c, s = np.cos(th), np.sin(th)
    ux, uy = float(increment[0]), float(increment[1])
    F = np.array([[1.0, 0.0, -s * ux - c * uy], [0.0, 1.0, c * ux - s * uy], [0.0, 0.0, 1.0]])
    G = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return F @ cov @ F.T + G @ increment_cov @ G.T


class ExpectedSpread:
    """The expected spread of a cloud that starts as one point at `start` and follows the
    motion model: call `advance(increment)` once per predict step."""

    def __init__(self, motion: MotionModel, start: FloatArray) -> None:
        self.motion = motion
        self.pose = np.asarray(start, dtype=np.float64).copy()
        self.cov: FloatArray | None = np.zeros((3, 3))

    def advance(self, increment: FloatArray) -> None:
        q = self.motion.increment_covariance(increment)
        if q is None or self.cov is None:
            self.cov = None  # the model cannot say: no expectation from here on
        else:
            self.cov = propagate_covariance(self.cov, self.pose, increment, q)
        self.pose = se2_compose(self.pose, increment)

    def spread(self) -> tuple[float, float]:
        """(position spread m, heading spread rad) expected now; NaN when unknown."""
        if self.cov is None:
            return float("nan"), float("nan")
        return float(np.sqrt(self.cov[0, 0] + self.cov[1, 1])), float(np.sqrt(self.cov[2, 2]))


def spread_columns(step_poses: FloatArray, step_odometry: FloatArray, motion: MotionModel) -> dict[str, FloatArray]:
    """The steps-table columns of a prediction-only run: for each step k (particles
    `step_poses[k]` (N, 3), odometry `step_odometry[k]` (3,)), `distance_m` (odometry path
    length since the first step), `spread_xy_m` / `spread_theta_rad` (measured) and
    `expected_spread_xy_m` / `expected_spread_theta_rad` (from the configured noise)."""
    k_steps = step_poses.shape[0]
    out = {name: np.empty(k_steps) for name in
           ("distance_m", "spread_xy_m", "spread_theta_rad", "expected_spread_xy_m", "expected_spread_theta_rad")}
    expected = ExpectedSpread(motion, step_odometry[0])
    dist = 0.0
    for k in range(k_steps):
        if k > 0:
            inc = se2_between(step_odometry[k - 1], step_odometry[k])  # the increment the engine sampled
            expected.advance(inc)
            dist += float(np.hypot(inc[0], inc[1]))
        out["distance_m"][k] = dist
        out["spread_xy_m"][k], out["spread_theta_rad"][k] = cloud_spread(step_poses[k])
        out["expected_spread_xy_m"][k], out["expected_spread_theta_rad"][k] = expected.spread()
    return out
