"""`slam.mapping.map_from_trajectory`: a trajectory's map, as the filters draw it."""

import numpy as np
import pytest

from slamlab.assemble import build_components
from slamlab.slam.engine import run_slam
from slamlab.slam.mapping import map_from_trajectory
from test_slam_engine import _cfg, _room_sequence


def test_the_course_filters_map_is_its_online_poses_mapped_at_its_steps():
    """The course filter inserts each processed scan at the best particle's pose, which is
    its online (causal) pose: mapping those poses at those scans gives its map to the bit."""
    seq = _room_sequence()
    cfg = _cfg("particles=15", "seed=3", "filter=course", "steps.every=2")
    res = run_slam(seq, build_components(cfg))
    steps = np.asarray(res.extras["step_scans"])
    grid = map_from_trajectory(seq, res.causal, build_components(cfg).map, steps)
    assert grid.data.dtype == np.float32
    assert grid.origin_xy == res.log_odds.origin_xy and grid.resolution_m == res.log_odds.resolution_m
    assert np.array_equal(grid.data, res.log_odds.data)


def test_the_rbpfs_map_is_its_smoothed_path_mapped_at_its_steps():
    """The RBPF's final map is the best particle's, drawn along its ancestry: its smoothed
    path. The tiles hold log-odds as one-byte codes of 0.05 where the grid adds float32s, so
    the two agree to rounding, and on every wall."""
    seq = _room_sequence()
    cfg = _cfg("particles=8", "seed=1", "filter=rbpf", "matcher=likelihood")
    res = run_slam(seq, build_components(cfg))
    steps = np.asarray(res.extras["step_scans"])
    grid = map_from_trajectory(seq, res.trajectory, build_components(cfg).map, steps)
    a, b = _common(grid, res.log_odds)
    assert np.abs(a - b).max() < 1e-4
    assert np.array_equal(a > 0, b > 0)


def test_a_rotation_injected_from_mid_run_changes_the_later_scans_walls_only():
    seq = _room_sequence()
    settings = build_components(_cfg("mode=odometry")).map
    res = run_slam(seq, build_components(_cfg("mode=odometry")))
    first = map_from_trajectory(seq, res.trajectory, settings, np.arange(30))
    assert np.count_nonzero(first.data) > 0
    moved = res.trajectory.copy()
    moved[30:, 2] += np.radians(5.0)
    # the first 30 scans alone: unchanged by what happens to the others
    again = map_from_trajectory(seq, moved, settings, np.arange(30))
    assert np.array_equal(first.data, again.data)
    whole, broken = map_from_trajectory(seq, res.trajectory, settings), map_from_trajectory(seq, moved, settings)
    a, b = _common(whole, broken)
    assert np.count_nonzero((a > 0) != (b > 0)) > 50  # walls drawn twice, 5 degrees apart


def test_bad_arguments_are_refused():
    seq = _room_sequence(20)
    settings = build_components(_cfg()).map
    with pytest.raises(ValueError, match="poses must be"):
        map_from_trajectory(seq, np.zeros((20, 2)), settings)
    with pytest.raises(ValueError, match="21 poses"):
        map_from_trajectory(seq, np.zeros((21, 3)), settings)
    with pytest.raises(ValueError, match="scan_indices"):
        map_from_trajectory(seq, np.zeros((20, 3)), settings, np.array([0, 20]))


def _common(a, b):
    """Two grids of the same resolution cut to the area both cover (cell-aligned)."""
    res = a.resolution_m
    off = np.round((np.array(b.origin_xy) - np.array(a.origin_xy)) / res).astype(int)  # b's origin in a's cells (x, y)
    r0, c0 = max(0, off[1]), max(0, off[0])
    r1 = min(a.data.shape[0], b.data.shape[0] + off[1])
    c1 = min(a.data.shape[1], b.data.shape[1] + off[0])
    return a.data[r0:r1, c0:c1], b.data[r0 - off[1] : r1 - off[1], c0 - off[0] : c1 - off[0]]


def test_the_map_sized_once_is_the_one_grown_scan_by_scan():
    """`map_from_trajectory` sizes the grid once, from the growth the scans would cause one by
    one: the same log-odds and origin, bit for bit, as inserting them one by one into a grid
    that grows (here a path wandering up to 30 m away in every direction, in random order: a
    dozen growths, left, right, up and down)."""
    from dataclasses import replace

    from slamlab.slam.grid import OccupancyGrid
    from slamlab.slam.scan import points_to_world, range_limits, scans_to_points

    seq = _room_sequence(60)
    settings = replace(build_components(_cfg()).map, growth_margin_m=0.0)
    t = np.linspace(0.0, 4.0 * np.pi, 60)
    poses = np.stack([30.0 * np.cos(t) * np.sin(t / 3), -25.0 * np.sin(1.5 * t), t], axis=1)
    order = np.random.default_rng(3).permutation(60)
    grid = map_from_trajectory(seq, poses, settings, order)

    min_r, max_r = range_limits(settings, seq)
    ref = OccupancyGrid(settings, (float(poses[order[0], 0]), float(poses[order[0], 1])))
    points = scans_to_points([seq.scans[int(i)] for i in order], seq.body_height_m, min_r, max_r, settings.ground_threshold_m)
    for i, pts in zip(order, points):
        if len(pts.xy):
            ref.insert(points_to_world(pts.origin.reshape(1, 2), poses[i])[0], points_to_world(pts.xy, poses[i]))
    assert ref.grow_count >= 10
    assert grid.origin_xy == (float(ref.origin[0]), float(ref.origin[1]))
    assert grid.data.shape == ref.log_odds.shape and np.array_equal(grid.data.view(np.uint32), ref.log_odds.view(np.uint32))
