"""benchmarks/sim_carmen.py writes a CARMEN log and relations that slamlab reads back as
written: the same scans, the odometry it drifted, and relations that are the ground truth's."""

from __future__ import annotations

import importlib.util
import warnings
from pathlib import Path

import numpy as np

from slamlab.datasets.carmen import load_carmen
from slamlab.eval.relations import relation_errors

_spec = importlib.util.spec_from_file_location(
    "sim_carmen", Path(__file__).resolve().parents[1] / "benchmarks" / "sim_carmen.py")
sim_carmen = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(sim_carmen)


def test_the_simulated_log_reads_back_as_written_and_its_relations_are_the_truths(tmp_path):
    clf = sim_carmen.write_log(tmp_path, scale=1.0, world_seed=0, seed=0, n_loop=50, yaw_bias_deg_per_m=1.0)
    log = sim_carmen.simulate(1.0, 0, 0, 1.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a clean log: no bad-line or saturation warnings
        seq = load_carmen(clf)
    assert len(seq) == len(log.t)
    t = np.array([f.t for f in seq.scans])
    assert np.allclose(t, log.t, atol=1e-6)
    odom = np.array([f.odom for f in seq.scans])
    assert np.allclose(odom[:, :2], log.odom[:, :2], atol=1e-5)
    k = len(seq) // 2  # a scan's readings: 1 cm steps, "no return" beyond 30 m
    f = seq.scans[k]
    want = log.ranges[k]
    hit = want < sim_carmen.LIDARS["sick"].no_return_m
    assert np.allclose(f.ranges[hit & f.valid], want[hit & f.valid], atol=1e-4) and (f.valid == hit).all()
    drift = np.hypot(*(log.odom[-1, :2] - log.truth[-1, :2]))
    assert drift > 3.0  # the odometry drifts by metres
    # relations: the truth scores zero on them, the odometry does not; the loop ones join revisits
    assert seq.relations is not None and len(seq.relations.t1) > 100
    assert relation_errors(log.t, log.truth, seq.relations)["trans_abs_mean_m"] < 1e-5
    assert relation_errors(log.t, log.odom, seq.relations)["trans_abs_mean_m"] > 0.1
    assert ((seq.relations.t2 - seq.relations.t1) > sim_carmen.LOOP_MIN_DT_S).sum() >= 10


def test_a_lidar_with_its_own_geometry_is_written_as_robotlaser1_and_reads_back(tmp_path):
    # The short-range Hokuyo: 667 beams over 240 degrees, 5.6 m, 0 for no return.
    urg = sim_carmen.LIDARS["urg"]
    clf = sim_carmen.write_log(tmp_path, scale=1.0, world_seed=0, seed=0, n_loop=10, yaw_bias_deg_per_m=1.0, lidar="urg")
    assert clf.name == "loops1x_w0_urg.clf" and "ROBOTLASER1" in clf.read_text()[:2000]
    log = sim_carmen.simulate(1.0, 0, 0, 1.0, urg)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        seq = load_carmen(clf)
    k = len(seq) // 3
    f = seq.scans[k]
    np.testing.assert_allclose(f.angles, urg.angles, atol=1e-6)
    assert np.isclose(f.angles[0], np.deg2rad(-120.0)) and np.isclose(f.angles[-1], np.deg2rad(119.76), atol=1e-6)
    want = log.ranges[k]
    hit = want > 0.0
    assert 0 < hit.sum() < urg.n  # some beams see nothing within 5.6 m
    assert (f.valid == hit).all() and np.allclose(f.ranges[hit], want[hit], atol=1e-4)
    assert want[hit].max() <= urg.max_m


def test_people_walking_the_corridors_cut_some_beams_short_and_leave_the_rest_and_the_truth_as_they_were():
    still = sim_carmen.simulate(1.0, 0, 0, 1.0)
    busy = sim_carmen.simulate(1.0, 0, 0, 1.0, people=6)
    assert np.array_equal(busy.truth, still.truth) and np.array_equal(busy.odom, still.odom)
    walls = still.ranges < sim_carmen.LIDARS["sick"].no_return_m
    changed = np.abs(busy.ranges - still.ranges) > 0.05  # beyond the range noise
    # a person stands in front of a wall: a beam only ever gets shorter, and most stay as they were
    assert (busy.ranges[changed & walls] < still.ranges[changed & walls]).all()
    assert 0.002 < changed.mean() < 0.1 and changed.any(axis=1).mean() > 0.2
    # the log's name says so, and the same people walk again for the same world
    assert sim_carmen.log_stem(2.0, 1, "sick", 6) == "loops2x_w1_p6" and sim_carmen.log_stem(2.0, 1) == "loops2x_w1"
    assert np.array_equal(sim_carmen.simulate(1.0, 0, 0, 1.0, people=6).ranges, busy.ranges)


def test_the_summary_line_names_the_mean_the_worst_run_and_the_failures():
    import pandas as pd

    table = pd.DataFrame({"world_seed": [0, 0, 2, 3], "filter_seed": [0, 1, 1, 0],
                          "rel_mean_m": [0.04, 0.06, 0.24, None]})
    line = sim_carmen.summary(table)
    assert line == "3 runs: smoothed relation error mean 0.113 m, worst 0.240 m (world 2, filter seed 1); 1 failed"
    assert sim_carmen.summary(table.iloc[3:]) == "no run finished (1 failed)"
    assert sim_carmen.summary(pd.DataFrame({"world_seed": [1], "filter_seed": [0], "error": ["x"]})) == "no run finished (1 failed)"


def test_each_defect_does_to_the_log_what_it_says_and_nothing_else():
    from slamlab.geometry import se2_between

    log = sim_carmen.simulate(1.0, 0, 0, 1.0)
    sick = sim_carmen.LIDARS["sick"]
    n, rel = log.t.size, log.t - log.t[0]
    inc = se2_between(log.odom[:-1], log.odom[1:])

    reset = sim_carmen.with_defect(log, "reset", sick)
    j = n // 2
    assert np.allclose(reset.odom[j], 0.0, atol=1e-9) and np.array_equal(reset.odom[:j], log.odom[:j])
    inc_reset = se2_between(reset.odom[:-1], reset.odom[1:])
    assert np.hypot(*inc_reset[j - 1, :2]) > 2.0  # one jump of metres ...
    assert np.allclose(np.delete(inc_reset, j - 1, axis=0), np.delete(inc, j - 1, axis=0), atol=1e-9)  # ... and the motion kept
    assert np.array_equal(reset.ranges, log.ranges) and np.array_equal(reset.truth, log.truth)

    gap = sim_carmen.with_defect(log, "gap", sick)
    assert gap.t.size == n - 100 and np.diff(gap.t).max() > 10.0  # 10 s of 10 Hz records gone
    assert np.diff(gap.odom_t).max() > 10.0

    freeze = sim_carmen.with_defect(log, "freeze", sick)
    held = np.flatnonzero((freeze.odom != log.odom).any(axis=1))
    assert len(held) == 99 and (freeze.odom[held] == log.odom[held[0] - 1]).all()  # held at the window's first scan
    assert np.array_equal(freeze.odom[held[-1] + 1:], log.odom[held[-1] + 1:])  # catching up at once after

    dropout = sim_carmen.with_defect(log, "dropout", sick)
    dark = (dropout.ranges == sick.no_return_m).all(axis=1)
    assert dark.sum() >= 200 and np.ptp(rel[dark & ~(log.ranges == sick.no_return_m).all(axis=1)]) < 20.0

    dup = sim_carmen.with_defect(log, "duplicates", sick)
    assert dup.t.size == n + len(range(49, n, 50)) and np.array_equal(dup.t[49], dup.t[50])

    spikes = sim_carmen.with_defect(log, "spikes", sick)
    changed = spikes.ranges != log.ranges
    assert 0.015 < changed.mean() < 0.025 and spikes.ranges[changed].max() <= 3.0
    assert np.array_equal(sim_carmen.with_defect(log, "spikes", sick).ranges, spikes.ranges)  # seeded
    assert sim_carmen.log_stem(2.0, 1, "sick", 0, "reset") == "loops2x_w1_reset"


def test_the_campus_world_keeps_its_streets_and_sidewalks_clear_and_its_scans_see_open_space():
    from slamlab.datasets.sim.campus import STREET_CLEAR_M, build_campus
    from slamlab.datasets.sim.people import RADIUS_M
    from slamlab.datasets.sim.raycast import cast_scans
    from slamlab.datasets.sim.world import _segment_distance

    world = build_campus(0, scale=2.0)
    assert world.layout == "campus" and np.array_equal(build_campus(0, scale=2.0).boxes, world.boxes)  # seeded
    assert not np.array_equal(build_campus(1, scale=2.0).boxes, world.boxes)
    # the figure-eight from the origin along +x, 856 m at scale 2
    route = world.route
    assert np.allclose(route[0], 0.0) and route[1, 1] == 0.0 and route[1, 0] > 0
    assert np.allclose(route[-1], route[0]) and 800 < np.hypot(*np.diff(route, axis=0).T).sum() < 900
    counts = np.bincount(world.kind, minlength=3)
    assert counts[0] >= 20 and counts[1] >= 50 and counts[2] >= 5  # buildings, trees and lamp posts, cars and hedges
    assert (world.boxes[:, 4] > sim_carmen.LIDAR_Z_M).all()  # the wheeled robot's lidar sees every obstacle
    for scale in (1.5, 2.0, 3.0):
        for seed in range(3):
            w = build_campus(seed, scale)
            legs = [((a[0], a[1]), (b[0], b[1])) for a, b in zip(w.route[:-1], w.route[1:])]
            assert min(_segment_distance(list(b), leg) for b in w.boxes for leg in legs) >= STREET_CLEAR_M - 1e-9
            # people pace 0.65 m to either side of each lane: a person's cylinder clear of every box and of the route
            sides = [((a[0] + dx, a[1] + dy), (b[0] + dx, b[1] + dy)) for a, b in w.lanes
                     for dx, dy in (((0, 0.65), (0, -0.65)) if a[1] == b[1] else ((0.65, 0), (-0.65, 0)))]
            assert min(_segment_distance(list(b), lane) for b in w.boxes for lane in sides) > RADIUS_M
            assert min(_segment_distance([*lane[0], *lane[0]], leg) for lane in sides for leg in legs) > RADIUS_M
            x0, y0, x1, y1 = w.bounds  # every box within the world's bounds
            assert (w.boxes[:, 0] >= x0).all() and (w.boxes[:, 1] >= y0).all() and (w.boxes[:, 2] <= x1).all() and (w.boxes[:, 3] <= y1).all()
    # the SICK along the route: walls and trees, and much of each scan returns nothing within 30 m
    k = np.linspace(0, len(route) - 2, 9).astype(int)
    T = np.tile(np.eye(4), (len(k), 1, 1))
    T[:, :2, 3] = route[k] + 0.5 * (route[k + 1] - route[k])
    heading = np.arctan2(*(route[k + 1] - route[k])[:, ::-1].T)
    T[:, 0, 0], T[:, 0, 1], T[:, 1, 0], T[:, 1, 1] = np.cos(heading), -np.sin(heading), np.sin(heading), np.cos(heading)
    T[:, 2, 3] = sim_carmen.LIDAR_Z_M
    sick = sim_carmen.LIDARS["sick"]
    ranges, ids = cast_scans(T, sick.angles, world.boxes, np.zeros((len(k), 0, 4)), sick.max_m)
    open_share = (ids == -1).mean()
    assert 0.2 < open_share < 0.9 and (ids >= 0).any(axis=1).all()
    assert sim_carmen.log_stem(2.0, 1, "lms291", 0, "", "campus") == "campus2x_w1_lms291"
