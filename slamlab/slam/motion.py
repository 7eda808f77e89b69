"""Prediction: move every particle by the odometry increment composed with sampled noise.

The increment is `u = o_t (-) o_t+1` written as a pose in the robot frame at t
(`se2_between(o_t, o_t+1)`); a particle p becomes `p (+) u (+) noise` (or, for the
four-parameter model, the noisy rot1/trans/rot2 decomposition of u). When the robot stands
still (u == 0) neither model adds noise, so a parked robot does not diffuse.

Adding a model: subclass `MotionModel`, implement `sample`, add its schema
(a dataclass in `slamlab.config.slam`, listed in `slamlab.config.SCHEMAS`) and
`conf/motion/NAME.yaml` extending it.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

from slamlab.config.slam import CourseMotionConfig as _Course
from slamlab.config.slam import Odometry4MotionConfig as _Odo4
from slamlab.geometry import FloatArray, se2_compose, wrap_angle


class MotionModel(ABC):
    """Interface: `sample(poses (N,3), increment (3,), rng) -> new poses (N,3)`, and the
    covariance of the noisy increment it samples (for the expected spread, `slam/spread.py`).
    `scale_gain_per_m` > 0: the filter learns a per-particle odometry scale at this gain
    (1/m; `slam/odometry_scale.py`); 0: the odometry's distances are taken as they are."""

    scale_gain_per_m: float = 0.0

    @abstractmethod
    def sample(self, poses: FloatArray, increment: FloatArray, rng: np.random.Generator) -> FloatArray:
        ...

    def increment_covariance(self, increment: FloatArray) -> FloatArray | None:
        """(3, 3) covariance (m^2, m rad, rad^2) of the noisy increment `sample` composes
        onto a particle, in the robot frame at the start of the step, to first order.
        None when a model does not say (the report then shows no expected spread)."""
        return None


class CourseMotion(MotionModel):
    """The course model: Gaussian noise on (x m, y m, theta rad) in the robot frame.

    The standard deviations are the course's per-step values scaled by the size of the
    increment: `sigma * k` with `k = |u.xy| / per_distance_m + |u.theta| / per_angle_rad`
    (`growth: linear`, the course's model). So the noise is zero when the robot stands still
    and grows with how far it moved or turned. With `growth: sqrt` the deviation is
    `sigma * sqrt(k)`: the variance grows linearly with the increment, as a random walk, so
    the spread accumulated over a path does not depend on how often the filter steps (with
    `linear`, halving the step halves the accumulated variance).
    """

    # defaults and checks: `slamlab.config.slam.CourseMotionConfig` (built from it at the edge)
    def __init__(
        self,
        sigma_xy_m: float = _Course.sigma_xy_m,
        sigma_theta_rad: float = _Course.sigma_theta_rad,
        per_distance_m: float = _Course.per_distance_m,
        per_angle_rad: float = _Course.per_angle_rad,
        growth: str = _Course.growth,
        scale_gain_per_m: float = _Course.scale_gain_per_m,
    ) -> None:
        self.scale_gain_per_m = float(scale_gain_per_m)
        self.growth = growth
        self.sigma_xy_m = float(sigma_xy_m)
        self.sigma_theta_rad = float(sigma_theta_rad)
        self.per_distance_m = float(per_distance_m)
        self.per_angle_rad = float(per_angle_rad)

    def sample(self, poses: FloatArray, increment: FloatArray, rng: np.random.Generator) -> FloatArray:
        u = np.asarray(increment, dtype=np.float64)
        n = poses.shape[0]
        # Always draw the same number of variates so the random stream does not depend on
        # whether the robot moved (keeps runs comparable across configs).
        z = rng.standard_normal((n, 3))
        sig = self._sigmas(u)
        noisy = u[None, :] + z * sig[None, :]
        return se2_compose(poses, noisy)

    def _sigmas(self, u: FloatArray) -> FloatArray:
        scale = np.hypot(u[0], u[1]) / self.per_distance_m + abs(u[2]) / self.per_angle_rad
        if self.growth == "sqrt":
            scale = np.sqrt(scale)
        return np.array([self.sigma_xy_m, self.sigma_xy_m, self.sigma_theta_rad]) * scale

    def increment_covariance(self, increment: FloatArray) -> FloatArray:
        # independent Gaussian noise on x, y, theta of the increment: exact, not linearised
        return np.diag(self._sigmas(np.asarray(increment, dtype=np.float64)) ** 2)


class Odometry4Motion(MotionModel):
    """The standard odometry model (Thrun et al., Probabilistic Robotics, table 5.6).

    The increment is split into rot1 (turn towards the new position), trans (straight
    line) and rot2 (final turn); each is perturbed with variance
    `a1 rot1^2 + a2 trans^2`, `a3 trans^2 + a4 (rot1^2 + rot2^2)`, `a1 rot2^2 + a2 trans^2`
    (rad^2, m^2). alpha1: rot from rot, alpha2: rot from trans (rad^2/m^2), alpha3: trans
    from trans, alpha4: trans from rot (m^2/rad^2).
    """

    # defaults and checks: `slamlab.config.slam.Odometry4MotionConfig`
    def __init__(self, alpha1: float = _Odo4.alpha1, alpha2: float = _Odo4.alpha2, alpha3: float = _Odo4.alpha3,
                 alpha4: float = _Odo4.alpha4, scale_gain_per_m: float = _Odo4.scale_gain_per_m) -> None:
        self.scale_gain_per_m = float(scale_gain_per_m)
        self.a1, self.a2, self.a3, self.a4 = float(alpha1), float(alpha2), float(alpha3), float(alpha4)

    def _decompose(self, increment: FloatArray) -> tuple[float, float, float, float, float, float]:
        """(rot1, trans, rot2) of the increment and their noise deviations."""
        u = np.asarray(increment, dtype=np.float64)
        trans = float(np.hypot(u[0], u[1]))
        # Below 1 mm the heading of the translation is meaningless: treat it as a pure turn.
        rot1 = float(np.arctan2(u[1], u[0])) if trans > 1e-3 else 0.0
        rot2 = float(wrap_angle(u[2] - rot1))
        s_rot1 = float(np.sqrt(self.a1 * rot1**2 + self.a2 * trans**2))
        s_trans = float(np.sqrt(self.a3 * trans**2 + self.a4 * (rot1**2 + rot2**2)))
        s_rot2 = float(np.sqrt(self.a1 * rot2**2 + self.a2 * trans**2))
        return rot1, trans, rot2, s_rot1, s_trans, s_rot2

    def increment_covariance(self, increment: FloatArray) -> FloatArray:
        # the sampled increment is (trans cos rot1, trans sin rot1, rot1 + rot2): push the
        # rot1/trans/rot2 variances through its Jacobian (first order)
        rot1, trans, _, s_rot1, s_trans, s_rot2 = self._decompose(increment)
        c, s = np.cos(rot1), np.sin(rot1)
        J = np.array([[-trans * s, c, 0.0], [trans * c, s, 0.0], [1.0, 0.0, 1.0]])
        return J @ np.diag([s_rot1**2, s_trans**2, s_rot2**2]) @ J.T

    def sample(self, poses: FloatArray, increment: FloatArray, rng: np.random.Generator) -> FloatArray:
        rot1, trans, rot2, s_rot1, s_trans, s_rot2 = self._decompose(increment)
        n = poses.shape[0]
        z = rng.standard_normal((n, 3))
        r1 = rot1 + z[:, 0] * s_rot1
        tr = trans + z[:, 1] * s_trans
        r2 = rot2 + z[:, 2] * s_rot2
        th = poses[:, 2]
        out = np.empty_like(poses)
        out[:, 0] = poses[:, 0] + tr * np.cos(th + r1)
        out[:, 1] = poses[:, 1] + tr * np.sin(th + r1)
        out[:, 2] = wrap_angle(th + r1 + r2)
        return out
