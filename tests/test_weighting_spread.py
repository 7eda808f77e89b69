"""linear_exp against logsumexp, and the motion model's expected spread (covariance
propagation) against closed forms and samples."""

import warnings

import numpy as np
import pytest

from slamlab.config.slam import LinearExpWeightingConfig
from slamlab.errors import ConfigError
from slamlab.geometry import se2_compose
from slamlab.slam.motion import CourseMotion, Odometry4Motion
from slamlab.slam.spread import ExpectedSpread, cloud_spread
from slamlab.slam.weighting import (
    OVERFLOW_SCORE,
    LinearExpWeighting,
    LogSumExpWeighting,
    WeightUnderflowWarning,
)

# ---------------------------------------------------------------- linear_exp


@pytest.mark.parametrize("temperature", [1.0, 3.0])
def test_linear_exp_equals_logsumexp_without_overflow(temperature):
    rng = np.random.default_rng(1)
    lin, lse = LinearExpWeighting(temperature), LogSumExpWeighting(temperature)
    a = b = np.full(20, -np.log(20))
    for _ in range(30):  # chained updates: the weights drift apart, still finite in linear space
        scores = rng.uniform(0.0, 60.0, 20)
        a, b = lin.update(a, scores), lse.update(b, scores)
        np.testing.assert_allclose(np.exp(a), np.exp(b), rtol=1e-9, atol=1e-300)
    assert lin.overflows == 0 and lin.underflows == 0
    assert np.exp(a).max() > 0.5  # the updates did separate the particles


def test_linear_exp_overflows_on_thor_sized_scores():
    # a THOR scan puts hundreds of its ~1,000 beams on walls: correlations of 600-900
    scores = np.array([812.0, 790.0, 640.0])
    assert scores.max() > OVERFLOW_SCORE
    lin = LinearExpWeighting()
    with pytest.warns(WeightUnderflowWarning, match="overflow.*709.8.*uniform.*logsumexp"):
        lw = lin.update(np.log(np.full(3, 1 / 3)), scores)
    np.testing.assert_allclose(np.exp(lw), 1 / 3)
    assert (lin.overflows, lin.underflows) == (1, 0)
    # the same update in log space is fine: the best particle dominates
    good = np.exp(LogSumExpWeighting().update(np.log(np.full(3, 1 / 3)), scores))
    np.testing.assert_allclose(good, [1.0, np.exp(-22.0), 0.0], atol=1e-12)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # warned once; later occurrences only counted
        lin.update(np.log(np.full(3, 1 / 3)), scores)
    assert lin.overflows == 2


def test_linear_exp_counts_underflow_separately():
    lin = LinearExpWeighting()
    with pytest.warns(WeightUnderflowWarning, match="underflow"):
        lw = lin.update(np.log([1e-300, 1e-300]), np.array([-100.0, -120.0]))
    np.testing.assert_allclose(np.exp(lw), [0.5, 0.5])
    assert (lin.overflows, lin.underflows) == (0, 1)


def test_linear_exp_temperature_is_checked():
    with pytest.raises(ConfigError, match="weighting.temperature"):
        LinearExpWeightingConfig(temperature=0.0)


# ---------------------------------------------------------------- expected spread


def test_course_increment_covariance_is_the_sampled_noise():
    m = CourseMotion(sigma_xy_m=0.02, sigma_theta_rad=0.01, per_distance_m=0.1, per_angle_rad=0.1)
    u = np.array([0.3, 0.0, 0.1])
    k = 0.3 / 0.1 + 0.1 / 0.1
    np.testing.assert_allclose(m.increment_covariance(u), np.diag([0.02 * k, 0.02 * k, 0.01 * k]) ** 2)


def test_odometry4_increment_covariance_matches_samples():
    m = Odometry4Motion(alpha1=0.05, alpha2=0.01, alpha3=0.05, alpha4=0.01)
    u = np.array([0.4, 0.1, 0.3])
    rng = np.random.Generator(np.random.PCG64(3))
    out = m.sample(np.zeros((200_000, 3)), u, rng)
    sample_cov = np.cov(out.T)
    np.testing.assert_allclose(m.increment_covariance(u), sample_cov, atol=2e-4, rtol=0.05)


def _straight_line_variances(n: int, d: float, sxy: float, sth: float) -> tuple[float, float]:
    """Closed form, first order, for n forward steps of d m with per-step noise sxy (x, y)
    and sth (theta): heading error after step i is the sum of i draws, and step i+1 turns it
    into d * heading sideways. Returns (var x + var y, var theta)."""
    var_th = n * sth**2
    var_y = n * sxy**2 + d**2 * sth**2 * sum(i * i for i in range(n))
    var_x = n * sxy**2
    return var_x + var_y, var_th


def test_expected_spread_matches_the_closed_form_on_a_straight_line():
    m = CourseMotion(sigma_xy_m=0.01, sigma_theta_rad=0.02, per_distance_m=0.1, per_angle_rad=0.1)
    u = np.array([0.05, 0.0, 0.0])  # 20 steps = 1 m
    e = ExpectedSpread(m, np.zeros(3))
    for _ in range(20):
        e.advance(u)
    var_xy, var_th = _straight_line_variances(20, 0.05, 0.01 * 0.5, 0.02 * 0.5)
    assert e.spread() == pytest.approx((np.sqrt(var_xy), np.sqrt(var_th)), rel=1e-9)
    np.testing.assert_allclose(e.pose, [1.0, 0.0, 0.0], atol=1e-12)


def test_expected_spread_matches_samples_on_a_curve():
    # a quarter circle with both models: sampled clouds against the first-order prediction
    for m in (CourseMotion(sigma_xy_m=0.02, sigma_theta_rad=0.02, growth="sqrt"), Odometry4Motion(0.02, 0.005, 0.02, 0.005)):
        u = np.array([0.1, 0.0, np.pi / 40])
        rng = np.random.Generator(np.random.PCG64(5))
        poses = np.zeros((20_000, 3))
        e = ExpectedSpread(m, np.zeros(3))
        for _ in range(20):
            poses = m.sample(poses, u, rng)
            e.advance(u)
        xy, th = cloud_spread(poses)
        exy, eth = e.spread()
        assert xy == pytest.approx(exy, rel=0.04) and th == pytest.approx(eth, rel=0.04)
        # the nominal pose followed the noise-free increments: a quarter turn
        nominal = np.zeros(3)
        for _ in range(20):
            nominal = se2_compose(nominal, u)
        np.testing.assert_allclose(e.pose, nominal, atol=1e-12)
        assert nominal[2] == pytest.approx(np.pi / 2)


def test_cloud_spread_handles_headings_across_pi():
    poses = np.array([[0.0, 0.0, np.pi - 0.01], [1.0, 0.0, -np.pi + 0.01]])
    xy, th = cloud_spread(poses)
    assert xy == pytest.approx(0.5) and th == pytest.approx(0.01)
