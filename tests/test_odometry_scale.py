"""The per-particle odometry scale (`motion.scale_gain_per_m`, slam/odometry_scale.py)."""

import numpy as np
import pytest

from slamlab.assemble import build_components
from slamlab.geometry import se2_compose
from slamlab.slam.engine import run_slam
from slamlab.slam.odometry_scale import SCALE_LIMITS, learn_scales, scaled_start
from test_slam_engine import _cfg, _room_sequence


def test_scaled_start_then_the_increment_moves_s_times_as_far():
    poses = np.array([[1.0, 2.0, 0.3], [-1.0, 0.5, -2.0], [0.0, 0.0, 3.0]])
    scales = np.array([0.9, 1.0, 1.1])
    inc = np.array([0.2, 0.05, 0.4])
    got = se2_compose(scaled_start(poses, scales, inc), inc)
    want = np.array([se2_compose(p, [s * inc[0], s * inc[1], inc[2]]) for p, s in zip(poses, scales)])
    np.testing.assert_allclose(got, want, atol=1e-12)


def test_a_match_that_keeps_the_prediction_leaves_the_scale():
    before = np.array([[0.0, 0.0, 0.7], [3.0, 1.0, -1.2]])
    scales = np.array([0.97, 1.04])
    inc = np.array([0.2, 0.0, 0.05])
    after = np.array([se2_compose(p, [s * inc[0], 0.0, inc[2]]) for p, s in zip(before, scales)])
    np.testing.assert_allclose(learn_scales(scales, before, after, inc, 0.2), scales, atol=1e-12)


def test_the_scale_converges_to_true_over_odometry_distance():
    # odometry over-counts 4 %: every step the particle really moves 0.2 / 1.04 m along a
    # heading that turns, so the along-track direction changes in the world frame
    inc = np.array([0.2, 0.0, 0.01])
    pose = np.zeros((1, 3))
    scales = np.ones(1)
    for _ in range(500):  # 100 m of odometry, five times the averaging distance
        after = se2_compose(pose, [inc[0] / 1.04, 0.0, inc[2]])
        scales = learn_scales(scales, pose, after, inc, 0.05)
        pose = after
    assert abs(scales[0] - 1 / 1.04) < 1e-3


def test_a_turn_on_the_spot_teaches_nothing_and_scales_stay_in_limits():
    s = np.array([1.0])
    p = np.zeros((1, 3))
    assert learn_scales(s, p, np.array([[0.3, 0.0, 0.5]]), np.array([0.0, 0.0, 0.5]), 1.0)[0] == 1.0
    # a matcher that jumped 1 m back on a 0.2 m step: the scale is pinned at the lower limit
    got = learn_scales(s, p, np.array([[-1.0, 0.0, 0.0]]), np.array([0.2, 0.0, 0.0]), 10.0)
    assert got[0] == SCALE_LIMITS[0]


def test_the_filter_learns_the_rooms_odometry_scale():
    # the room's odometry counts x 5 % long (true 1 / 1.05 = 0.952); the run is 1.5 m, so a
    # gain of 2 / m (0.5 m averaging) has room to learn it
    seq = _room_sequence()
    on = run_slam(seq, build_components(_cfg("particles=20", "seed=1", "matcher=likelihood", "filter=rbpf",
                                              "motion.scale_gain_per_m=2.0")))
    scale = on.extras["odometry_scale"]
    assert 0.92 < scale < 0.98, scale
    assert on.steps["odometry_scale"][0] == 1.0 and on.steps["odometry_scale"][-1] == scale
    off = run_slam(seq, build_components(_cfg("particles=20", "seed=1", "matcher=likelihood", "filter=rbpf")))
    assert "odometry_scale" not in off.extras and "odometry_scale" not in off.steps


def test_each_particle_keeps_its_own_scale_through_resampling():
    """The reported scale is the one the final best particle learnt along its own ancestry:
    replaying `learn_scales` along its path (parents from the recorded history) from 1.0 must
    give it. Were scales not resampled with their particles, the final particle would carry
    another lineage's scale. The room run resamples at nearly every step (threshold 1.0)."""
    from slamlab.geometry import se2_between
    from slamlab.slam.engine import ancestral_path

    seq = _room_sequence()
    gain = 2.0
    res = run_slam(seq, build_components(_cfg("particles=20", "seed=3", "matcher=likelihood", "filter=rbpf",
                                               f"motion.scale_gain_per_m={gain}", "resampler.threshold=1.0",
                                               "record.particles=true")))
    h = res.particle_history
    assert res.resample_count > 10
    best = int(np.argmax(h.weights[-1]))
    path = ancestral_path(h.poses, h.parents, best)
    odom = np.array([s.odom for s in seq.scans])[res.extras["step_scans"]]
    scale = np.ones(1)
    for k in range(1, len(path)):
        scale = learn_scales(scale, path[k - 1:k], path[k:k + 1], se2_between(odom[k - 1], odom[k]), gain)
    assert scale[0] == pytest.approx(res.extras["odometry_scale"], abs=1e-12)
    # the particles' scales differ enough that another lineage's would not pass the check
    assert len(set(np.round(res.steps["odometry_scale"], 9))) > 5
