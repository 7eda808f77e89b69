"""Loop closures scored against the ground truth (slamlab.eval.closures): a closure is wrong
when it is off in a direction it pins, and a corridor match is not wrong for being off along
the corridor it cannot place."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from slamlab.eval.closures import WRONG_DEG, WRONG_M, closure_truth, pinned_error_m
from slamlab.geometry import se2_between, se2_compose
from slamlab.pipeline import accuracy_metrics
from slamlab.slam.graph.loops import LoopCandidate

TIGHT = np.diag([0.01**2, 0.01**2, 0.005**2])
CORRIDOR_X = np.diag([3.0**2, 0.01**2, 0.005**2])  # pins nothing along x (the node frame's forward)


def _truth() -> np.ndarray:
    """One scan every 0.1 m along x, then every 0.1 m up y (turned 90 degrees)."""
    along_x = np.column_stack([np.arange(100) * 0.1, np.zeros(100), np.zeros(100)])
    up_y = np.column_stack([np.full(100, 9.9), np.arange(1, 101) * 0.1, np.full(100, math.pi / 2)])
    return np.vstack([along_x, up_y])


def _closure(node: int, anchor: int, scans: np.ndarray, truth: np.ndarray, error=(0.0, 0.0, 0.0), cov=TIGHT,
             status: str = "accepted") -> LoopCandidate:
    rel = se2_compose(se2_between(truth[scans[anchor]], truth[scans[node]]), np.asarray(error, dtype=float))
    return LoopCandidate(node=node, submap=0, anchor=anchor, relative=rel, score=0.9, refined=0.9, second=0.0, window_m=5.0,
                         node_pose=truth[scans[node]], match_pose=truth[scans[node]], status=status, covariance=cov)


def test_only_closures_off_where_they_pin_or_in_yaw_count_as_wrong():
    truth = _truth()
    scans = np.arange(0, 200, 5)  # node k is scan 5k
    cands = [
        _closure(30, 2, scans, truth),  # right
        _closure(31, 3, scans, truth, error=(0.0, 0.5, 0.0)),  # half a metre across: wrong
        _closure(8, 1, scans, truth, error=(1.5, 0.0, 0.0), cov=CORRIDOR_X),  # 1.5 m along a corridor it cannot place: not wrong
        _closure(9, 1, scans, truth, error=(0.0, 0.0, math.radians(10))),  # 10 degrees: wrong
        _closure(32, 4, scans, truth, error=(0.0, 2.0, 0.0), status="inconsistent"),  # rejected: not counted
    ]
    out = closure_truth(cands, scans, truth)
    assert out["accepted"] == 4 and out["wrong"] == 2
    assert isinstance(out["worst_m"], float) and abs(out["worst_m"] - 0.5) < 1e-9  # a plain float: metrics.json
    assert abs(out["worst_deg"] - 10.0) < 1e-9
    assert (out["wrong_m"], out["wrong_deg"]) == (WRONG_M, WRONG_DEG)


def test_the_error_is_taken_in_the_nodes_frame_where_its_covariance_is():
    # node 30 stands on the y leg (facing +y): a corridor along its forward axis is world y. An error
    # of 1.5 m along its x (forward) is free; the same error across it is not
    truth = _truth()
    scans = np.arange(0, 200, 5)
    free = closure_truth([_closure(30, 25, scans, truth, error=(1.5, 0.0, 0.0), cov=CORRIDOR_X)], scans, truth)
    across = closure_truth([_closure(30, 25, scans, truth, error=(0.0, 1.5, 0.0), cov=CORRIDOR_X)], scans, truth)
    assert free["wrong"] == 0 and free["worst_m"] < 1e-9
    assert across["wrong"] == 1 and abs(across["worst_m"] - 1.5) < 1e-9


def test_pinned_error_ignores_only_the_free_direction():
    assert pinned_error_m(np.array([3.0, 4.0]), np.diag([0.01, 0.01])) == 5.0
    assert abs(pinned_error_m(np.array([3.0, 4.0]), np.diag([9.0, 0.01])) - 4.0) < 1e-12
    assert pinned_error_m(np.array([3.0, 4.0]), np.diag([9.0, 9.0])) == 0.0


def test_accuracy_metrics_scores_a_graph_runs_closures_on_simulated_data():
    truth = _truth()
    scans = np.arange(0, 200, 5)
    cands = [_closure(31, 3, scans, truth, error=(0.0, 0.5, 0.0)), _closure(30, 2, scans, truth)]
    seq = SimpleNamespace(ground_truth=SimpleNamespace(poses=truth, occupancy=None), relations=None)
    result = SimpleNamespace(times=np.arange(200) * 0.1, trajectory=truth, causal=truth, odometry=truth,
                             extras={"processed_steps": len(scans), "step_scans": scans, "loop_candidates": cands})
    out = accuracy_metrics(seq, result)
    assert out["loop_truth"]["accepted"] == 2 and out["loop_truth"]["wrong"] == 1
    result.extras.pop("loop_candidates")  # the particle filters find no closures: no section
    assert "loop_truth" not in accuracy_metrics(seq, result)
