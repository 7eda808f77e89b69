"""The Kuemmerle et al. relation metric on trajectories with known errors."""

from __future__ import annotations

import numpy as np
import pytest

from slamlab.eval.relations import LOOP_MIN_DT_S, SPAN_KEYS, loop_end_offsets, match_times, relation_errors, relation_residuals
from slamlab.frames import Relations
from slamlab.geometry import se2_compose, se2_inverse


def _relations_with_error(poses: np.ndarray, times: np.ndarray, pairs: np.ndarray, c: np.ndarray) -> Relations:
    """Relations such that the estimate `poses` is off by exactly c[k] on relation k:
    rel = inv(P1) (+) P2 (+) inv(c), hence d = inv(rel) (+) inv(P1) (+) P2 = c."""
    p1, p2 = poses[pairs[:, 0]], poses[pairs[:, 1]]
    rel = se2_compose(se2_compose(se2_inverse(p1), p2), se2_inverse(c))
    return Relations(t1=times[pairs[:, 0]], t2=times[pairs[:, 1]], rel=rel)


def test_single_relation_hand_computed_in_a_rotated_frame():
    # The robot at (5, 5) facing +y; the reference says "1 m straight ahead", the estimate
    # went 1 m ahead but drifted 0.1 m left and turned 0.05 rad: error (0, 0.1, 0.05).
    p1 = np.array([5.0, 5.0, np.pi / 2])
    p2 = np.array([5.0 - 0.1, 6.0, np.pi / 2 + 0.05])
    rels = Relations(t1=np.array([10.0]), t2=np.array([11.0]), rel=np.array([[1.0, 0.0, 0.0]]))
    trans, rot = relation_residuals(np.array([10.0, 11.0]), np.stack([p1, p2]), rels)
    assert trans == pytest.approx([0.1], abs=1e-12)
    assert rot == pytest.approx([0.05], abs=1e-12)
    e = relation_errors(np.array([10.0, 11.0]), np.stack([p1, p2]), rels)
    assert e["count"] == 1
    assert e["trans_abs_mean_m"] == pytest.approx(0.1)
    assert e["rot_abs_mean_deg"] == pytest.approx(np.degrees(0.05))
    assert np.isnan(e["trans_abs_std_m"])  # one sample has no sample std


def test_known_per_relation_errors_give_known_statistics():
    rng = np.random.default_rng(3)
    n = 40
    poses = np.column_stack([rng.uniform(-20, 20, n), rng.uniform(-20, 20, n), rng.uniform(-np.pi, np.pi, n)])
    times = 976052857.0 + np.arange(n) * 0.2
    pairs = np.array([[0, 1], [5, 9], [30, 2]])
    # Errors of 0.1, 0.2, 0.3 m in mixed directions and 1, 2, 3 deg (signs mixed).
    c = np.array([[0.1, 0.0, np.radians(1.0)], [0.0, -0.2, np.radians(-2.0)], [0.18, 0.24, np.radians(3.0)]])
    e = relation_errors(times, poses, _relations_with_error(poses, times, pairs, c))
    assert e["count"] == 3
    assert e["trans_abs_mean_m"] == pytest.approx(0.2, abs=1e-9)
    assert e["trans_abs_std_m"] == pytest.approx(0.1, abs=1e-9)
    assert e["trans_sq_mean_m2"] == pytest.approx((0.01 + 0.04 + 0.09) / 3, abs=1e-9)
    assert e["trans_sq_std_m2"] == pytest.approx(np.std([0.01, 0.04, 0.09], ddof=1), abs=1e-9)
    assert e["rot_abs_mean_deg"] == pytest.approx(2.0, abs=1e-6)
    assert e["rot_abs_std_deg"] == pytest.approx(1.0, abs=1e-6)
    assert e["rot_sq_mean_deg2"] == pytest.approx(14.0 / 3, abs=1e-6)
    assert e["rot_sq_std_deg2"] == pytest.approx(np.std([1.0, 4.0, 9.0], ddof=1), abs=1e-6)
    assert all(type(v) in (int, float) for v in e.values())


def test_local_and_loop_relations_are_scored_apart():
    rng = np.random.default_rng(5)
    n = 100
    poses = np.column_stack([rng.uniform(-20, 20, n), rng.uniform(-20, 20, n), rng.uniform(-np.pi, np.pi, n)])
    times = 1000.0 + np.arange(n) * 1.0  # one pose a second
    # local: dt 1 s, 3 s and -1 s (t2 first); loop: 40 s, 60 s, exactly LOOP_MIN_DT_S, and -70 s (t2 first, a revisit)
    pairs = np.array([[0, 1], [2, 5], [21, 20], [0, 40], [10, 70], [50, 50 + int(LOOP_MIN_DT_S)], [90, 20]])
    err = np.array([0.1, 0.3, 0.2, 1.0, 0.5, 0.6, 0.7])
    c = np.column_stack([err, np.zeros(7), np.radians([1.0, 2.0, 3.0, 10.0, 20.0, 30.0, 20.0])])
    rels = _relations_with_error(poses, times, pairs, c)
    split = relation_errors(times, poses, rels, loop_min_dt_s=LOOP_MIN_DT_S)
    assert split["local"]["count"] == 3 and split["loop"]["count"] == 4
    assert tuple(split["local"]) == tuple(split["loop"]) == SPAN_KEYS
    assert split["local"]["trans_abs_mean_m"] == pytest.approx(0.2, abs=1e-9)
    assert split["loop"]["trans_abs_mean_m"] == pytest.approx(0.7, abs=1e-9)
    assert split["local"]["rot_abs_mean_deg"] == pytest.approx(2.0, abs=1e-6)
    assert split["loop"]["rot_abs_mean_deg"] == pytest.approx(20.0, abs=1e-6)
    whole = relation_errors(times, poses, rels)
    assert whole["trans_abs_mean_m"] == pytest.approx((3 * 0.2 + 4 * 0.7) / 7, abs=1e-9)
    # each part is `relation_errors` of its own relations, standard deviations included
    for name, rows in (("local", [0, 1, 2]), ("loop", [3, 4, 5, 6])):
        alone = relation_errors(times, poses, Relations(rels.t1[rows], rels.t2[rows], rels.rel[rows]))
        assert split[name] == pytest.approx({k: alone[k] for k in SPAN_KEYS})
    # a log whose relations are all local: the loop part is empty, not an error
    short = relation_errors(times, poses, rels, loop_min_dt_s=1000.0)
    assert short["local"]["count"] == 7 and short["loop"]["count"] == 0
    assert np.isnan(short["loop"]["trans_abs_mean_m"])


def test_global_frame_change_does_not_change_errors():
    rng = np.random.default_rng(0)
    poses = np.column_stack([rng.normal(size=20), rng.normal(size=20), rng.uniform(-3, 3, 20)])
    times = np.arange(20.0)
    pairs = np.column_stack([np.arange(19), np.arange(1, 20)])
    c = np.column_stack([rng.normal(0, 0.1, 19), rng.normal(0, 0.1, 19), rng.normal(0, 0.05, 19)])
    rels = _relations_with_error(poses, times, pairs, c)
    moved = se2_compose(np.array([100.0, -40.0, 2.0]), poses)  # same trajectory, other map frame
    a = relation_errors(times, poses, rels)
    b = relation_errors(times, moved, rels)
    for key in a:
        assert a[key] == pytest.approx(b[key], rel=1e-9, abs=1e-9)


def test_rotation_error_is_wrapped():
    # 190 deg of yaw error is 170 deg the other way.
    poses = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, np.radians(190.0)]])
    rels = Relations(t1=np.array([0.0]), t2=np.array([1.0]), rel=np.zeros((1, 3)))
    e = relation_errors(np.array([0.0, 1.0]), poses, rels)
    assert e["rot_abs_mean_deg"] == pytest.approx(170.0)


def test_poses_are_found_by_timestamp_not_by_order():
    # A clock that steps back, like Intel's: the file order is not the time order.
    times = np.array([100.0, 100.5, 100.2, 101.0])
    poses = np.array([[0.0, 0, 0], [9.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0]])
    rels = Relations(t1=np.array([100.0, 100.2]), t2=np.array([100.2, 101.0]), rel=np.array([[1.0, 0, 0], [1.0, 0, 0]]))
    e = relation_errors(times, poses, rels)
    assert e["trans_abs_mean_m"] == pytest.approx(0.0, abs=1e-12)
    shuffled = np.array([3, 1, 0, 2])
    e2 = relation_errors(times[shuffled], poses[shuffled], rels)
    assert e2["trans_abs_mean_m"] == pytest.approx(0.0, abs=1e-12)


def test_match_times_tolerance_and_duplicates():
    t = np.array([976052905.167303, 976052896.784509, 976052911.885496, 976052896.784509])
    idx = match_times(t, np.array([976052896.7845093, 976052911.885496]))
    assert idx.tolist() == [1, 2]  # duplicate time: the first in file order
    with pytest.raises(ValueError, match=r"1 relation time\(s\) have no pose.*976052905\.168303"):
        match_times(t, np.array([976052905.168303]))


def test_missing_relation_time_is_a_clear_error():
    rels = Relations(t1=np.array([0.0]), t2=np.array([5.0]), rel=np.zeros((1, 3)))
    with pytest.raises(ValueError, match="no pose"):
        relation_errors(np.array([0.0, 1.0]), np.zeros((2, 3)), rels)


def test_shape_mismatch_is_rejected():
    rels = Relations(t1=np.array([0.0]), t2=np.array([1.0]), rel=np.zeros((1, 3)))
    with pytest.raises(ValueError, match="2 times but 3 poses"):
        relation_errors(np.array([0.0, 1.0]), np.zeros((3, 3)), rels)


def test_loop_end_offsets_say_where_the_online_path_was_off():
    """The online path is 0.3 m off the smoothed one while the loop is open (before 50 s) and
    agrees with it from the return on: the offset sits at the first visits, not the returns.
    Local relations do not count; either order of t1 and t2 is a visit then a return."""
    times = np.arange(0.0, 100.0, 1.0)
    smoothed = np.stack([np.cos(times / 10.0), np.sin(times / 10.0), times / 10.0], axis=1)
    online = smoothed.copy()
    online[times < 50.0, 0] += 0.3
    rels = Relations(np.array([10.0, 90.0, 20.0, 60.0]), np.array([80.0, 15.0, 21.0, 61.0]), np.zeros((4, 3)))
    off = loop_end_offsets(times, online, smoothed, rels, loop_min_dt_s=LOOP_MIN_DT_S)
    assert off["start_m"] == pytest.approx(0.3)
    assert off["end_m"] == pytest.approx(0.0)
    # a lag at the return shows at the end instead
    lag = smoothed.copy()
    lag[times >= 80.0, 1] -= 0.2
    off = loop_end_offsets(times, lag, smoothed, rels, loop_min_dt_s=LOOP_MIN_DT_S)
    assert off["start_m"] == pytest.approx(0.0)
    assert off["end_m"] == pytest.approx(0.2)
    # no loop relation: no figure rather than a zero
    assert np.isnan(loop_end_offsets(times, online, smoothed, rels, loop_min_dt_s=1000.0)["start_m"])
