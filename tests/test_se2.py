"""SE(2) algebra with known answers."""

import numpy as np

from slamlab.geometry import se2_between, se2_compose, se2_fit, se2_inverse, wrap_angle


def test_compose_known_answer():
    a = np.array([1.0, 2.0, np.pi / 2])
    b = np.array([1.0, 0.0, 0.0])
    np.testing.assert_allclose(se2_compose(a, b), [1.0, 3.0, np.pi / 2], atol=1e-12)


def test_inverse_and_between_round_trip():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(50, 3))
    b = rng.normal(size=(50, 3))
    np.testing.assert_allclose(se2_compose(a, se2_inverse(a)), 0.0, atol=1e-12)
    # b == a (+) (a (-) b): the odometry increment re-applied gives the end pose
    back = se2_compose(a, se2_between(a, b))
    np.testing.assert_allclose(back[:, :2], b[:, :2], atol=1e-12)
    np.testing.assert_allclose(wrap_angle(back[:, 2] - b[:, 2]), 0.0, atol=1e-12)


def test_wrap_angle_range():
    w = wrap_angle(np.array([np.pi, -np.pi, 3 * np.pi, 7.0]))
    assert np.all(w >= -np.pi) and np.all(w < np.pi)
    np.testing.assert_allclose(w[2], -np.pi)


def test_weighted_mean_pose_averages_position_and_yaw_across_the_wrap():
    from slamlab.geometry import weighted_mean_pose

    poses = np.array([[1.0, 2.0, np.pi - 0.1], [3.0, 4.0, -np.pi + 0.1]])
    m = weighted_mean_pose(poses, [1.0, 1.0])  # weights need not sum to 1
    np.testing.assert_allclose(m[:2], [2.0, 3.0])
    # the two yaws are 0.2 rad apart across +-pi: their mean is pi, not 0
    assert abs(abs(m[2]) - np.pi) < 1e-12
    m = weighted_mean_pose(poses, [3.0, 1.0])
    np.testing.assert_allclose(m[:2], [1.5, 2.5])
    assert abs(wrap_angle(m[2] - (np.pi - 0.05))) < 1e-3
    # one particle with all the weight is that particle
    np.testing.assert_allclose(weighted_mean_pose(poses, [0.0, 1.0]), poses[1])


def test_se2_fit_recovers_a_rigid_motion_and_fits_noisy_points_in_the_least_squares_sense():
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(40, 3)) * [10.0, 10.0, 1.0]
    motion = np.array([1.5, -2.0, 0.4])
    moved = se2_compose(motion, pts)
    np.testing.assert_allclose(se2_fit(pts[:, :2], moved[:, :2]), motion, atol=1e-12)
    # with noise on the targets, no small change of the fitted motion lowers the squared distances
    noisy = moved[:, :2] + rng.normal(scale=0.05, size=(40, 2))
    fit = se2_fit(pts[:, :2], noisy)

    def cost(m):
        return float(np.sum((se2_compose(m, pts)[:, :2] - noisy) ** 2))

    for dim in range(3):
        for h in (-1e-4, 1e-4):
            assert cost(fit + np.eye(3)[dim] * h) > cost(fit)
    # one point: the translation that carries it there
    np.testing.assert_allclose(se2_fit(pts[:1, :2], moved[:1, :2]), [*(moved[0, :2] - pts[0, :2]), 0.0], atol=1e-12)
