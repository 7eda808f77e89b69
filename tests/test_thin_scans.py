"""Scans with too few returns to match are found, named in a warning and listed in metrics.json (slam/thin_scans.py)."""

from __future__ import annotations

import dataclasses
import logging

import numpy as np
import pytest

from slamlab.assemble import build_components
from slamlab.frames import Sequence
from slamlab.pipeline import filter_metrics
from slamlab.slam.engine import run_slam
from slamlab.slam.scan import scan_to_points
from slamlab.slam.thin_scans import THIN_RETURNS, WARN_M, WARN_SHARE, thin_stretches, usable_returns
from test_slam_engine import _cfg, _room_sequence


def _straight(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Odometry 1 m a scan along x, and the scans' times (s, a log's epoch clock)."""
    return np.column_stack([np.arange(n, dtype=float), np.zeros(n), np.zeros(n)]), 1e9 + 0.5 * np.arange(n)


def test_the_longest_stretch_runs_between_the_steps_with_enough_returns_around_it():
    odom, times = _straight(200)
    steps = np.arange(0, 200, 2)  # a step every 2 m
    returns = np.full(len(steps), 150)
    returns[[10, 11, 12]] = [0, 19, 5]  # steps at 20-24 m: the path from 18 to 26 m rests on odometry
    returns[[40, 60]] = 3  # two lone thin steps: 4 m each
    returns[70] = THIN_RETURNS  # enough
    thin = thin_stretches(returns, steps, odom, times)
    assert (thin.steps, thin.share, thin.longest_m) == (5, 0.05, 8.0)
    assert (thin.from_s, thin.to_s) == (9.0, 13.0)  # the same stretch (steps at 18 m and 26 m), s since the first scan
    assert thin.worth_a_warning  # 5 % of the steps
    assert thin.as_dict() == {"steps": 5, "share": 0.05, "min_returns": THIN_RETURNS, "longest_m": 8.0, "from_s": 9.0, "to_s": 13.0}
    returns[[40, 60]] = 150
    few = thin_stretches(returns, steps, odom, times)
    assert few.share < WARN_SHARE and few.longest_m < WARN_M and not few.worth_a_warning
    returns[13:20] = 0  # now 20 m between steps with enough returns (18 m -> 40 m: 22 m)
    assert thin_stretches(returns, steps, odom, times).longest_m == 22.0 and thin_stretches(returns, steps, odom, times).worth_a_warning
    assert thin_stretches(np.full(len(steps), 150), steps, odom, times) is None
    # a thin first or last step: the stretch is measured from / to the run's end
    ends = np.full(len(steps), 150)
    ends[[0, 1, 99]] = 0
    first = thin_stretches(ends, steps, odom, times)
    assert (first.longest_m, first.from_s, first.to_s) == (4.0, 0.0, 2.0)
    ends[:2] = 150
    last = thin_stretches(ends, steps, odom, times)
    assert (last.longest_m, last.from_s, last.to_s) == (2.0, 98.0, 99.0)
    sparse = thin_stretches(np.array([150, 0, 150]), np.array([0, 6, 12]), odom, times)  # steps 6 m apart: one thin step is 12 m
    assert sparse.longest_m == 12.0 and sparse.worth_a_warning


def test_usable_returns_are_the_points_the_matcher_gets():
    seq = _room_sequence(8)
    f = seq.scans[3]
    ranges = f.ranges.copy()
    ranges[:10] = 0.05  # too close
    ranges[10:20] = 40.0  # too far
    valid = f.valid.copy()
    valid[20:30] = False
    scans = list(seq.scans)
    scans[3] = dataclasses.replace(f, ranges=ranges, valid=valid)
    n = usable_returns(scans, np.array([2, 3]), None, 0.1, 30.0, 0.1)
    assert n[0] == int(f.valid.sum()) and n[1] == n[0] - 30
    # a head-mounted lidar pitched down: the beams that hit the floor are no use to the matcher
    pitched = dataclasses.replace(f, pitch=0.5)
    on_floor = usable_returns([pitched], np.array([0]), 1.2, 0.1, 30.0, 0.1)[0]
    want = len(scan_to_points(pitched, 1.2, 0.1, 30.0, 0.1).xy)
    assert on_floor == want < int(f.valid.sum())


def _blind(seq: Sequence, first: int) -> Sequence:
    """The sequence with every scan from `first` on seeing only five beams."""
    scans = list(seq.scans)
    for i in range(first, len(scans)):
        valid = np.zeros_like(scans[i].valid)
        valid[:5] = scans[i].valid[:5]
        scans[i] = dataclasses.replace(scans[i], valid=valid)
    return dataclasses.replace(seq, scans=scans)


@pytest.mark.parametrize("overrides", [
    ("particles=10", "seed=7", "matcher=likelihood"),  # the course filter
    ("+experiment=lidar2d", "dataset.path=unused", "steps.min_distance_m=0.1", "steps.min_angle_rad=0.1"),  # the graph
], ids=["course", "graph"])
def test_a_run_whose_scans_go_blind_says_so_and_a_clean_run_says_nothing(overrides, caplog):
    seq = _room_sequence()
    cfg = _cfg(*overrides)
    with caplog.at_level(logging.WARNING):
        clean = run_slam(seq, build_components(cfg))
    assert clean.extras["thin_scans"] is None and "thin_scans" not in filter_metrics(seq, clean, cfg).to_dict()
    assert "too few to match" not in caplog.text
    blind = _blind(seq, 40)
    with caplog.at_level(logging.WARNING):
        result = run_slam(blind, build_components(cfg))
    thin = result.extras["thin_scans"]
    n_steps = int(result.extras["processed_steps"])
    steps = np.asarray(result.extras["step_scans"])
    assert thin.steps == int((steps >= 40).sum()) and thin.share == pytest.approx(thin.steps / n_steps)
    before = int(steps[steps < 40][-1])  # the stretch runs from the last step with enough returns to the end
    assert thin.from_s == pytest.approx(seq.scans[before].t - seq.scans[0].t)
    assert thin.to_s == pytest.approx(seq.scans[int(steps[-1])].t - seq.scans[0].t)
    path = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(result.odometry[:, :2], axis=0).T))])
    assert thin.longest_m == pytest.approx(path[int(steps[-1])] - path[before])
    listed = filter_metrics(blind, result, cfg).to_dict()["thin_scans"]
    assert listed == thin.as_dict()
    assert f"room: {thin.steps} of the {n_steps} processed scans" in caplog.text and "too few to match" in caplog.text
    # a run that ends before the scans go blind has nothing to say
    early = run_slam(blind, build_components(_cfg(*overrides, "steps.max_scans=38")))
    assert early.extras["thin_scans"] is None
    # dead reckoning matches nothing: nothing to say of its scans
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        dead = run_slam(blind, build_components(_cfg(*overrides, "mode=odometry")))
    assert dead.extras["thin_scans"] is None and "too few to match" not in caplog.text


def test_a_log_whose_odometry_never_moves_says_so_and_a_moving_one_says_nothing(caplog):
    seq = _room_sequence()
    scans = [dataclasses.replace(f, odom=np.zeros(3)) for f in seq.scans]  # a log without odometry: its fields all zero
    still = dataclasses.replace(seq, scans=scans)
    cfg = _cfg("+experiment=lidar2d", "dataset.path=unused", "steps.min_distance_m=0.1", "steps.min_angle_rad=0.1")
    with caplog.at_level(logging.WARNING):
        result = run_slam(still, build_components(cfg))
    assert int(result.extras["processed_steps"]) == 1
    assert f"room: the odometry never moves (all {len(scans)} scans at x=0.000 m, y=0.000 m, theta=0.000 rad): 1 of them processed" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        run_slam(seq, build_components(cfg))  # the room's robot stands still for its first 5 scans, then drives
    assert "never moves" not in caplog.text
