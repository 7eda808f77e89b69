"""Odometry that jumps mid-log (a reset of its frame) is taken as no motion (slam/odometry_jumps.py)."""

from __future__ import annotations

import dataclasses
import logging

import numpy as np
import pytest

from slamlab.assemble import build_components
from slamlab.frames import Sequence
from slamlab.geometry import se2_between, se2_compose
from slamlab.pipeline import filter_metrics
from slamlab.slam.engine import run_slam
from slamlab.slam.odometry_jumps import bridge_jumps, find_jumps
from test_slam_engine import _cfg, _room_sequence

RESET = np.array([40.0, -25.0, 1.0])  # the odometry's new frame after the reset


def _path(n: int = 50) -> np.ndarray:
    """An odometry track of 0.1 m steps along a gentle curve (x m, y m, theta rad)."""
    theta = np.linspace(0.0, 1.0, n)
    return np.column_stack([np.cumsum(0.1 * np.cos(theta)), np.cumsum(0.1 * np.sin(theta)), theta])


def _reset(odom: np.ndarray, j: int, frame: np.ndarray = RESET) -> np.ndarray:
    out = odom.copy()
    out[j:] = se2_compose(frame, odom[j:])
    return out


def test_a_reset_of_the_odometrys_frame_is_found_and_bridged_as_no_motion_keeping_every_other_increment():
    odom = _path()
    jumped = _reset(_reset(odom, 20), 35, np.array([0.0, 0.0, 2.5]))  # a second reset: the frame turned about its origin
    jumps = find_jumps(jumped, np.arange(50) * 0.2, max_m=2.0, max_rad=1.57)
    assert [(j.scan, j.t_s) for j in jumps] == [(20, 4.0), (35, 7.0)]
    assert jumps[0].m > 40 and jumps[1].rad > 2.4
    bridged = bridge_jumps(jumped, jumps)
    inc, inc_true = se2_between(bridged[:-1], bridged[1:]), se2_between(odom[:-1], odom[1:])
    np.testing.assert_allclose(inc[[19, 34]], 0.0, atol=1e-12)  # the jumps: no motion
    others = np.setdiff1d(np.arange(49), [19, 34])
    np.testing.assert_allclose(inc[others], inc_true[others], atol=1e-12)
    np.testing.assert_array_equal(bridged[:20], jumped[:20])  # the poses before the first jump as they were


def test_odometry_without_jumps_is_the_same_array_and_zero_thresholds_test_nothing():
    odom = _path()
    times = np.arange(50) * 0.1
    turned = odom.copy()
    turned[30:, 2] += 1.06  # ACES's largest turn between two scans is a real one
    assert find_jumps(turned, times, 2.0, 1.57) == []
    assert bridge_jumps(odom, []) is odom
    jumped = _reset(odom, 20)
    assert find_jumps(jumped, times, 0.0, 0.0) == []
    assert [j.scan for j in find_jumps(jumped, times, 0.0, 0.5)] == [20]  # the turn alone finds it
    assert [j.scan for j in find_jumps(jumped, times, 50.0, 0.0)] == []  # 45 m is under 50


@pytest.mark.parametrize("share", [0.5, 0.1, 0.9])
def test_a_reset_blended_over_the_scan_between_the_frames_is_bridged_on_both_sides(share):
    """A ROS bag's odometry is interpolated at each scan's stamp: the scan that falls between the
    last message of the old frame and the first of the new one gets a pose part-way between
    them, so the jump splits over two increments. A 2.95 m reset halved is two 1.5 m steps,
    each under the 2 m threshold alone; blended unevenly, the small side is the rest of it."""
    odom = _path()
    jumped = _reset(odom, 21, np.array([2.0, -2.0, 0.3]))
    jumped[20] = (1 - share) * jumped[19] + share * jumped[21]  # x, y and theta part-way, as interpolation does
    times = np.arange(50) * 0.1  # 10 Hz: the path's 0.1 m steps are 1 m/s
    jumps = find_jumps(jumped, times, 2.0, 1.57)
    assert [j.scan for j in jumps] == [20, 21]
    bridged = bridge_jumps(jumped, jumps)
    inc, inc_true = se2_between(bridged[:-1], bridged[1:]), se2_between(odom[:-1], odom[1:])
    np.testing.assert_allclose(inc[[19, 20]], 0.0, atol=1e-12)
    np.testing.assert_allclose(np.delete(inc, [19, 20], axis=0), np.delete(inc_true, [19, 20], axis=0), atol=1e-12)


def test_a_gap_in_the_log_is_motion_not_a_jump():
    """10 s without records: the robot drove 3.5 m and turned 80 degrees between two scans, at
    walking pace; the same increment 0.1 s apart is a jump. Stamps that run backwards (Intel's)
    count by their distance in time."""
    odom = np.array([[0.0, 0.0, 0.0], [2.5, 2.5, np.radians(80.5)]])
    assert find_jumps(odom, np.array([0.0, 10.0]), 2.0, 1.57) == []
    assert find_jumps(odom, np.array([10.0, 0.0]), 2.0, 1.57) == []
    assert [j.scan for j in find_jumps(odom, np.array([0.0, 0.1]), 2.0, 1.57)] == [1]


def _rebased(seq: Sequence, j: int) -> Sequence:
    """`seq` with its odometry in another frame from scan j on (a base whose driver restarted)."""
    scans = [s if i < j else dataclasses.replace(s, odom=se2_compose(RESET, s.odom)) for i, s in enumerate(seq.scans)]
    return Sequence(name=seq.name, scans=scans, body_height_m=seq.body_height_m, sources=[])


@pytest.mark.parametrize("overrides", [
    ("particles=20", "seed=7", "matcher=likelihood"),  # the course filter
    ("+experiment=lidar2d", "dataset.path=unused", "filter=rbpf", "particles=20", "steps.min_distance_m=0.1", "steps.min_angle_rad=0.1"),
    ("+experiment=lidar2d", "dataset.path=unused", "steps.min_distance_m=0.1", "steps.min_angle_rad=0.1"),  # the graph
], ids=["course", "rbpf", "graph"])
def test_a_run_over_an_odometry_reset_follows_the_run_without_it(overrides, caplog):
    seq = _room_sequence()
    jumped = _rebased(seq, 30)
    plain = run_slam(seq, build_components(_cfg(*overrides)))
    with caplog.at_level(logging.WARNING):
        bridged = run_slam(jumped, build_components(_cfg(*overrides)))
    assert [j["scan"] for j in bridged.extras["odometry_jumps"]] == [30]
    cfg = _cfg(*overrides)
    assert filter_metrics(jumped, bridged, cfg).to_dict()["odometry_jumps"] == bridged.extras["odometry_jumps"]
    assert "odometry_jumps" not in filter_metrics(seq, plain, cfg).to_dict()  # absent when the odometry never jumped
    assert "room: the odometry jumps 48.09 m and 57.7 deg between scans 29 and 30 (t = 3.000 s)" in caplog.text
    # the robot's own 3 cm across the reset is lost with it, and the matches take it up
    assert np.abs(bridged.trajectory[:, :2] - plain.trajectory[:, :2]).max() < 0.02
    assert np.abs(bridged.trajectory[:, 2] - plain.trajectory[:, 2]).max() < 0.01
    inc, inc_plain = (se2_between(r.odometry[:-1], r.odometry[1:]) for r in (bridged, plain))
    np.testing.assert_allclose(np.delete(inc, 29, axis=0), np.delete(inc_plain, 29, axis=0), atol=1e-9)
    np.testing.assert_allclose(inc[29], 0.0, atol=1e-12)
    # taken as motion (both tests off), the reset throws the run metres off
    taken = run_slam(jumped, build_components(_cfg(*overrides, "steps.odom_jump_m=0", "steps.odom_jump_rad=0")))
    assert taken.extras["odometry_jumps"] == []
    assert np.abs(taken.trajectory[30:, :2] - plain.trajectory[30:, :2]).max() > 5.0


@pytest.mark.parametrize("override", ["steps.odom_jump_m=-1", "steps.odom_jump_rad=nan", "steps.odom_jump_rad=inf"])
def test_a_bad_jump_threshold_is_named(override):
    from slamlab.errors import ConfigError

    with pytest.raises(ConfigError, match=override.split("=")[0].replace(".", r"\.")):
        build_components(_cfg(override))


@pytest.mark.parametrize("extra, listed", [
    ((), [30]),
    (("steps.max_scans=25",), []),  # the run ends before the reset
    (("steps.max_steps=10",), []),  # ... at its tenth step, before the reset
    (("steps.max_steps=40",), [30]),
    (("mode=odometry",), [30]),  # dead reckoning bridges it too
])
def test_only_the_jumps_within_the_run_are_listed_and_named(extra, listed, caplog):
    jumped = _rebased(_room_sequence(), 30)
    with caplog.at_level(logging.WARNING):
        result = run_slam(jumped, build_components(_cfg("particles=5", "seed=7", "matcher=likelihood", *extra)))
    assert [j["scan"] for j in result.extras["odometry_jumps"]] == listed
    assert ("odometry jumps" in caplog.text) == bool(listed)
    if "mode=odometry" in extra:  # the dead-reckoning path has no step of 48 m
        inc = se2_between(result.trajectory[:-1], result.trajectory[1:])
        assert np.hypot(inc[:, 0], inc[:, 1]).max() < 0.1
