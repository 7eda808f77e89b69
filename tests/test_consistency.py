"""The consistency verdict (slamlab.eval.consistency) needs no ground truth: it must call a
map that agrees with its scans consistent, flag one that contradicts itself where it does,
and judge a map the same whichever filter made it; and its kernels must walk the beams the
map's own ray cast walks. The calibration on real maps, good and broken on purpose, is
benchmarks/bench_consistency.py (README, "Is the map consistent?")."""

import numpy as np
import pytest

from slamlab.assemble import build_components
from slamlab.eval.consistency import (
    BROKEN_SHARE,
    IN_FREE,
    SEE_THROUGH,
    SUPPORT,
    WINDOW,
    classify_beams,
    consistency_metrics,
    correction_candidates,
    register_scans,
)
from slamlab.frames import Sequence
from slamlab.slam.engine import run_slam
from slamlab.slam.mapping import map_from_trajectory
from test_slam_engine import _cfg, _room_sequence


def _verdict(seq: Sequence, poses: np.ndarray, log_odds, *keys: str):
    cons = consistency_metrics(seq, poses, log_odds, build_components(_cfg(*keys)).map)
    assert len(cons.series["hit_fraction"]) == cons.summary["scans_scored"]
    assert len(cons.series["contradiction"]) == len(cons.series["t"])
    return cons


def test_a_map_drawn_from_its_own_scans_is_consistent_and_a_broken_one_is_flagged_where_it_broke():
    seq = _room_sequence(80)
    res = run_slam(seq, build_components(_cfg("mode=odometry")))
    good = _verdict(seq, res.trajectory, res.log_odds, "mode=odometry")
    s = good.summary
    assert s["verdict"] == "consistent" and s["broken_spans"] == [] and good.spans == []
    assert s["contradiction_worst_window"] < 0.05 and s["hit_fraction_mean"] > 0.97
    assert s["verdict_text"].startswith("consistent")
    # the second half of the path 0.4 m and 5 degrees off, and the map drawn from it: its
    # walls twice, the second time beside the first; the verdict names that half and the room
    moved = res.trajectory.copy()
    moved[40:] += np.array([0.4, 0.0, np.radians(5.0)])
    settings = build_components(_cfg("mode=odometry")).map
    broken_map = map_from_trajectory(seq, moved, settings, np.arange(len(moved)))
    bad = _verdict(seq, moved, broken_map, "mode=odometry")
    b = bad.summary
    assert b["verdict"] == "likely broken" and b["contradiction_worst_window"] >= BROKEN_SHARE
    span = bad.spans[0]
    assert -3.0 <= span.x_m <= 3.5 and -2.0 <= span.y_m <= 2.5  # in the room
    t = bad.series["t"] - bad.series["t"][0]
    # the stretch reaches the moment it broke (the pass before it or the one after: they disagree)
    assert span.t1_s <= t[40] + 1.0 and span.t2_s >= t[40] - 1.0
    assert b["verdict_text"].startswith(f"likely broken near ({span.x_m:.1f}, {span.y_m:.1f}) m")
    # where: the overlay holds the contradicting beams and the region's share
    ov = bad.overlay
    assert ov["see_through"].sum() + ov["in_free"].sum() > 100 and np.nanmax(ov["region_share"]) > 0.2
    assert good.overlay["see_through"].sum() + good.overlay["in_free"].sum() < 0.02 * good.overlay["support"].sum()


def test_the_verdict_judges_a_map_the_same_whichever_filter_made_it():
    """Course filter, RBPF, dead reckoning on a drift-free room: each map is consistent with
    its own path, and the verdict reads nothing but the map, the path and the scans."""
    seq = _room_sequence(80)
    for keys in (("filter=course", "particles=10"), ("filter=rbpf", "particles=8", "matcher=likelihood"), ("mode=odometry",)):
        res = run_slam(seq, build_components(_cfg(*keys)))
        cons = _verdict(seq, res.trajectory, res.log_odds, *keys)
        assert cons.summary["verdict"] == "consistent", (keys, cons.summary["verdict_text"])


def test_too_few_scans_is_no_verdict():
    seq = _room_sequence(12)
    res = run_slam(seq, build_components(_cfg("mode=odometry")))
    s = _verdict(seq, res.trajectory, res.log_odds, "mode=odometry").summary
    assert s["verdict"] == "too short to judge" and str(WINDOW) in s["verdict_text"]


@pytest.mark.data
def test_scan_matching_is_consistent_and_dead_reckoning_is_flagged_on_intel(shared_data):
    from slamlab.datasets.carmen import load_carmen

    full = load_carmen(shared_data / "carmen" / "intel.clf.bz2")
    seq = Sequence(name="intel-slice", scans=full.scans[:2500], body_height_m=None, sources=full.sources,
                   max_range_m=full.max_range_m, min_range_m=full.min_range_m)
    keys = ("dataset=carmen", "dataset.path=unused", "particles=10", "filter=course", "matcher=likelihood",
            "steps.min_distance_m=0.2", "steps.min_angle_rad=0.2")
    slam = run_slam(seq, build_components(_cfg(*keys)))
    dead = run_slam(seq, build_components(_cfg(*keys, "mode=odometry")))
    s = _verdict(seq, slam.trajectory, slam.log_odds, *keys).summary
    d = _verdict(seq, dead.trajectory, dead.log_odds, *keys, "mode=odometry").summary
    assert s["verdict"] == "consistent" and s["contradiction_worst_window"] < BROKEN_SHARE
    assert d["verdict"] == "likely broken" and d["contradiction_worst_window"] > s["contradiction_worst_window"] + 0.2
    assert s["hit_fraction_mean"] > d["hit_fraction_mean"] + 0.1


def _classify_in_python(lo, occ, free, s_row, s_col, e_row, e_col, ends, margin):
    """classify_beams' rules written out, along `raycast.bresenham`'s cells."""
    from slamlab.slam.raycast import bresenham

    H, W = lo.shape
    cls, near = [], []
    for j in range(len(s_row)):
        for k in range(ends[j], ends[j + 1]):
            r1, c1 = int(e_row[k]), int(e_col[k])
            block = [(r, c) for r in range(r1 - 1, r1 + 2) for c in range(c1 - 1, c1 + 2)]
            on = [(r, c) for r, c in block if 0 <= r < H and 0 <= c < W]
            is_near = 0 <= r1 < H and 0 <= c1 < W and any(lo[r, c] > occ for r, c in on)
            all_free = len(on) == 9 and all(lo[r, c] < free for r, c in on)
            walk = bresenham(int(s_row[j]), int(s_col[j]), r1, c1)[:-1]  # the cells before the end
            crossed = any(0 <= r < H and 0 <= c < W and lo[r, c] > occ for r, c in walk[: max(0, len(walk) - margin)])
            cls.append(SEE_THROUGH if crossed else SUPPORT if is_near else IN_FREE if all_free else 0)
            near.append(is_near)
    return np.array(cls), np.array(near)


def test_beams_are_classified_along_the_cells_the_maps_ray_cast_walks():
    """Support, see-through (a wall crossed more than `margin` cells before the end) and in
    free space, compared in the map's float32, off-map cells unknown: against a plain Python
    walk of `raycast.bresenham`'s cells."""
    rng = np.random.default_rng(3)
    lo = rng.choice(np.array([0.0, 0.1, 0.2, -1.5], dtype=np.float32), size=(40, 50), p=[0.2, 0.01, 0.01, 0.78])
    s_row, s_col = np.array([20, 5, 33, 0]), np.array([25, 5, 40, 49])
    ends = np.array([0, 60, 60, 110, 140])  # the second scan has no beams
    e_row, e_col = rng.integers(-3, 43, 140), rng.integers(-3, 53, 140)  # some endpoints off the map
    got_cls, ev_r, ev_c, got_near = classify_beams(lo, np.float32(0.1), np.float32(-1.0), s_row, s_col, e_row, e_col, ends, 3)
    want_cls, want_near = _classify_in_python(lo, np.float32(0.1), np.float32(-1.0), s_row, s_col, e_row, e_col, ends, 3)
    assert np.array_equal(got_cls, want_cls) and np.array_equal(got_near, want_near)
    assert {0, SUPPORT, SEE_THROUGH, IN_FREE} <= set(got_cls.tolist())
    # a see-through beam's evidence is the wall it crossed, the others' their endpoint
    thru = got_cls == SEE_THROUGH
    assert np.all(lo[ev_r[thru], ev_c[thru]] > 0.1)
    assert np.array_equal(ev_r[~thru], e_row[~thru]) and np.array_equal(ev_c[~thru], e_col[~thru])


def test_a_scan_a_few_cells_off_its_walls_is_nudged_back_and_a_centred_one_stays():
    lo = np.full((60, 60), -2.0, np.float32)
    lo[10, 5:55] = 3.0  # a wall along a row
    lo[5:55, 50] = 3.0  # and one along a column
    wall = np.concatenate([np.column_stack([np.arange(5, 50) + 0.5, np.full(45, 10.5)]),
                           np.column_stack([np.full(40, 50.5), np.arange(12, 52) + 0.5])])
    angles, n, order, offsets = correction_candidates(0.05)
    assert n == 3 and np.array_equal(offsets[0], [0.0, 0.0, 0.0])  # no nudge first: it wins every tie
    assert len(offsets) == 5 * 7 * 7 and np.allclose(np.degrees(angles), [-1, -0.5, 0, 0.5, 1])
    ends = np.array([0, len(wall), 2 * len(wall)])
    xy = np.concatenate([wall, wall + [-2.0, 3.0]])  # the second scan sits 2 cells left, 3 up
    pivots = np.array([[30.0, 30.0], [30.0, 30.0]])
    best = register_scans(lo, np.float32(0.0), xy, ends, pivots, angles, n, order, 90)
    assert np.array_equal(offsets[best[0]], [0, 0, 0])
    # within the one cell of slack a hit has, the smallest nudge that puts every point on the walls
    assert np.all(np.abs(offsets[best[1], :2] - [2.0, -3.0]) <= 1.0) and offsets[best[1], 2] == 0.0
    assert np.array_equal(offsets[best[1], :2], [1.0, -2.0])
    # the same counts as trying every nudge point by point (a plain loop over the 3 x 3 blocks)
    from slamlab.eval.consistency import _scan_nudge_hits

    hits = _scan_nudge_hits(lo, np.float32(0.0), xy, 0, len(wall), 1, 30.0, 30.0, angles, n)
    for k, dy, dx in order[:60]:
        c, s_ = np.cos(angles[k]), np.sin(angles[k])
        rel = wall - 30.0
        p = np.floor(np.column_stack([30.0 + c * rel[:, 0] - s_ * rel[:, 1], 30.0 + s_ * rel[:, 0] + c * rel[:, 1]])).astype(int)
        p += [dx - n, dy - n]
        want = sum(bool((lo[max(r - 1, 0):r + 2, max(q - 1, 0):q + 2] > 0).any()) for q, r in p)
        assert hits[k, dy, dx] == want
    # a scan turned 1 degree about its robot, whose walls run out from it (no shift can undo a turn there)
    big = np.full((400, 400), -2.0, np.float32)
    big[200, 210:390] = 3.0
    big[210:390, 200] = 3.0
    rays = np.concatenate([np.column_stack([np.arange(210, 390) + 0.5, np.full(180, 200.5)]),
                           np.column_stack([np.full(180, 200.5), np.arange(210, 390) + 0.5])])
    a = np.radians(1.0)
    turned = (rays - 200.0) @ np.array([[np.cos(a), np.sin(a)], [-np.sin(a), np.cos(a)]]) + 200.0
    pick = register_scans(big, np.float32(0.0), turned, np.array([0, len(turned)]), np.array([[200.0, 200.0]]),
                          angles, n, order, 400)
    k, dy, dx = order[pick[0]]
    hits = _scan_nudge_hits(big, np.float32(0.0), turned, 0, len(turned), 1, 200.0, 200.0, angles, n)
    assert hits[k, dy, dx] == len(turned) > hits[angles.tolist().index(0.0)].max()  # no shift alone does it
    assert offsets[pick[0], 2] < 0  # it turns back
