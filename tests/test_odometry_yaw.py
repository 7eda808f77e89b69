"""The learnt odometry yaw drift of the graph's local SLAM (`filter.yaw_drift_gain_per_m`,
slamlab/slam/odometry_yaw.py): the update's arithmetic, and local SLAM in a room learning the
bias of odometry that turns too little and predicting with it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from slamlab.config.slam import GraphFilterConfig
from slamlab.errors import ConfigError
from slamlab.geometry import se2_between, se2_compose, wrap_angle
from slamlab.slam.graph.local import LocalSlam
from slamlab.slam.graph.submaps import Submaps
from slamlab.slam.grid import MapSettings
from slamlab.slam.matcher import LikelihoodFieldMatcher
from slamlab.slam.odometry_yaw import YAW_DRIFT_LIMIT, learn_yaw_drift
from slamlab.slam.scan import ScanPoints


def test_the_drift_moves_towards_what_the_match_saw_per_metre():
    # 0.25 m steps whose match turns 5 mrad more than the odometry: 0.02 rad/m
    b = 0.0
    for _ in range(2000):  # 500 m at 0.05 / m: the average over 20 m has long converged
        b = learn_yaw_drift(b, 0.005 + 0.001, 0.001, 0.25, 0.05)
    assert b == pytest.approx(0.02, abs=1e-6)
    # one step: the gain weighs what the prediction (b d) missed
    assert learn_yaw_drift(0.01, 0.004, 0.0, 0.2, 0.05) == pytest.approx(0.01 + 0.05 * 0.2 * (0.004 - 0.002) / 0.2)
    # a step longer than 1 / g takes that step's own drift
    assert learn_yaw_drift(0.0, 0.09, 0.0, 30.0, 0.05) == pytest.approx(0.003)
    # the turn seen is wrapped: a match just across +-pi is a small turn, not 2 pi
    assert learn_yaw_drift(0.0, math.pi - 0.001, -math.pi + 0.001, 0.5, 2.0) == pytest.approx(-0.004)


def test_a_turn_on_the_spot_teaches_nothing_and_the_drift_is_bounded():
    assert learn_yaw_drift(0.01, 0.3, 0.1, 0.0, 0.05) == 0.01  # no distance: no per-metre drift to see
    assert learn_yaw_drift(0.01, 0.3, 0.1, 0.5, 0.0) == 0.01  # gain 0: off
    assert learn_yaw_drift(0.0, 0.5, 0.0, 1.0, 1.0) == YAW_DRIFT_LIMIT
    assert learn_yaw_drift(0.0, -0.5, 0.0, 1.0, 1.0) == -YAW_DRIFT_LIMIT


def _room_scan(pose: np.ndarray) -> ScanPoints:
    """The walls of a 12 x 8 m room with a pillar, seen from `pose` (every wall point within
    10 m, 5 cm apart), in the robot's frame."""
    t = np.arange(0.0, 1.0, 0.05 / 12.0)
    walls = [np.c_[12 * t, 0 * t], np.c_[12 * t, 8 + 0 * t], np.c_[0 * t, 8 * t], np.c_[12 + 0 * t, 8 * t]]
    a = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    walls.append(np.c_[7 + 0.3 * np.cos(a), 5 + 0.3 * np.sin(a)])
    world = np.concatenate(walls)
    world = world[np.hypot(*(world - pose[:2]).T) < 10.0]
    c, s = math.cos(pose[2]), math.sin(pose[2])
    d = world - pose[:2]
    return ScanPoints(xy=np.c_[c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], origin=np.zeros(2))


def _drive(gain_per_m: float, bias_rad_per_m: float) -> tuple[LocalSlam, float]:
    """Local SLAM down the room and back in 0.25 m steps, on odometry that turns
    `bias_rad_per_m` too little: the learnt drift and the largest heading error of a step's
    prediction (rad) over the last half."""
    truth = [np.array([2.0, 3.0, 0.0])]
    for k in range(64):  # 8 m east, a U-turn, 8 m west
        truth.append(se2_compose(truth[-1], np.array([0.25, 0.0, 0.1 if 30 <= k < 62 else 0.0])))
    matcher = LikelihoodFieldMatcher()
    ms = MapSettings()
    local = LocalSlam(matcher, ms, Submaps(ms, 10, matcher.field_sigma_m, matcher.field_radius_m), "map", truth[0],
                      yaw_drift_gain_per_m=gain_per_m)
    local.insert(0, _room_scan(truth[0]))
    predicted: list[float] = []  # the yaw each node's match starts from
    match = local._match
    local._match = lambda grid, pose, scan: (predicted.append(float(pose[2])), match(grid, pose, scan))[1]
    worst = 0.0
    for k in range(1, len(truth)):
        inc = se2_between(truth[k - 1], truth[k])
        inc[2] -= bias_rad_per_m * float(np.hypot(inc[0], inc[1]))  # the odometry's turn falls short
        local.step(inc, _room_scan(truth[k]))
        if k > len(truth) // 2:
            worst = max(worst, abs(float(wrap_angle(predicted[-1] - truth[k][2]))))
        local.insert(k, _room_scan(truth[k]))
        local.finish_step()
    return local, worst


def test_local_slam_learns_the_odometrys_yaw_bias_and_predicts_with_it():
    bias = 0.03  # rad per metre, 1.7 degrees: Intel's is 0.057
    learnt, worst_learnt = _drive(0.25, bias)  # averages over 4 m: 16 m driven
    assert learnt.yaw_drift == pytest.approx(bias, abs=0.004)
    off, worst_off = _drive(0.0, bias)
    assert off.yaw_drift == 0.0  # off: nothing learnt
    # the matches pin the yaw in the room either way; what changes is the prediction they start from
    assert worst_off > 0.9 * bias * 0.25  # the odometry's own error each step
    assert worst_learnt < 0.5 * worst_off


def test_yaw_drift_needs_a_local_map_it_can_learn_on():
    with pytest.raises(ConfigError, match="filter.yaw_drift_gain_per_m"):
        GraphFilterConfig(yaw_drift_gain_per_m=-0.1)
    with pytest.raises(ConfigError, match="local_map=particles"):
        GraphFilterConfig(yaw_drift_gain_per_m=0.02, local_map="particles")
    assert GraphFilterConfig(yaw_drift_gain_per_m=0.02, local_map="submap").yaw_drift_gain_per_m == 0.02
