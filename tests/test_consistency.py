"""The consistency score (slamlab.eval.consistency) needs no ground truth: it must rate a
map that agrees with its scans above one that does not, on a synthetic room and on real data."""

import numpy as np
import pytest

from slamlab.eval.consistency import consistency_metrics
from slamlab.frames import Sequence
from slamlab.assemble import build_components
from slamlab.slam.engine import run_slam
from test_slam_engine import _cfg, _room_sequence


def _score(seq: Sequence, poses: np.ndarray, log_odds, *keys: str) -> dict:
    summary, series = consistency_metrics(seq, poses, log_odds, build_components(_cfg(*keys)).map)
    assert len(series["hit_fraction"]) == summary["scans_scored"]
    return summary


def test_scans_replayed_where_the_map_was_built_land_on_its_walls():
    seq = _room_sequence()
    res = run_slam(seq, build_components(_cfg("mode=odometry")))
    good = _score(seq, res.trajectory, res.log_odds, "mode=odometry")
    assert good["scans_scored"] == len(seq)
    # the map was made from exactly these scans at exactly these poses
    assert good["hit_fraction_mean"] > 0.97
    assert good["conflict_fraction"] < 0.05
    # the same scans replayed 0.4 m and 5 deg off for the second half: they miss the walls
    # and their beams cross the walls the first half drew
    moved = res.trajectory.copy()
    moved[len(moved) // 2 :] += np.array([0.4, 0.0, np.radians(5.0)])
    bad = _score(seq, moved, res.log_odds, "mode=odometry")
    assert bad["hit_fraction_mean"] < good["hit_fraction_mean"] - 0.2
    assert bad["hit_fraction_worst_window"] < 0.5
    assert bad["conflict_fraction"] > 2 * good["conflict_fraction"] + 0.01


@pytest.mark.data
def test_scan_matching_scores_clearly_above_dead_reckoning_on_intel(shared_data):
    from slamlab.datasets.carmen import load_carmen

    full = load_carmen(shared_data / "carmen" / "intel.clf.bz2")
    seq = Sequence(name="intel-slice", scans=full.scans[:2500], body_height_m=None, sources=full.sources,
                   max_range_m=full.max_range_m, min_range_m=full.min_range_m)
    keys = ("dataset=carmen", "dataset.path=unused", "particles=10", "filter=course", "matcher=likelihood",
            "steps.min_distance_m=0.2", "steps.min_angle_rad=0.2")
    slam = run_slam(seq, build_components(_cfg(*keys)))
    dead = run_slam(seq, build_components(_cfg(*keys, "mode=odometry")))
    s = _score(seq, slam.trajectory, slam.log_odds, *keys)
    d = _score(seq, dead.trajectory, dead.log_odds, *keys, "mode=odometry")
    assert s["hit_fraction_mean"] > 0.9
    assert s["hit_fraction_mean"] > d["hit_fraction_mean"] + 0.1
    assert s["hit_fraction_p10"] > d["hit_fraction_p10"] + 0.15
    assert s["conflict_fraction"] < d["conflict_fraction"]


def test_wall_lookups_and_beam_counts_agree_with_plain_numpy():
    """The two replay kernels against plain NumPy: an endpoint is near a wall when a cell of
    its 3 x 3 block on the map is above the threshold, compared in the map's float32 (a cell
    holding float32(0.1) is not above a 0.1 threshold, as NumPy has it), and every walked cell
    of a beam counts once per beam, its end included, along `raycast.bresenham`'s cells."""
    from slamlab.eval.consistency import _count_passes, _near_wall
    from slamlab.slam.raycast import bresenham

    rng = np.random.default_rng(3)
    lo = rng.choice(np.array([0.0, 0.1, 0.2, -0.3], dtype=np.float32), size=(40, 50), p=[0.7, 0.1, 0.1, 0.1])
    rows, cols = rng.integers(0, 40, 500), rng.integers(0, 50, 500)
    rows[:4], cols[:4] = [0, 39, 0, 39], [0, 49, 49, 0]  # the map's corners: neighbours off the map
    want = np.zeros(len(rows), dtype=bool)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            r, c = rows + dr, cols + dc
            ok = (r >= 0) & (r < 40) & (c >= 0) & (c < 50)
            want[ok] |= lo[r[ok], c[ok]] > 0.1
    assert np.array_equal(_near_wall(lo, np.float32(0.1), rows, cols), want)
    assert want.any() and not want.all()

    s_row, s_col = np.array([20, 5, 33]), np.array([25, 5, 40])
    ends = np.array([0, 30, 30, 50])  # the second scan has no beams
    e_row, e_col = rng.integers(0, 40, 50), rng.integers(0, 50, 50)
    passes = np.zeros((40, 50), dtype=np.int32)
    _count_passes(passes, s_row, s_col, e_row, e_col, ends)
    expect = np.zeros((40, 50), dtype=np.int32)
    for j in range(3):
        for k in range(ends[j], ends[j + 1]):
            for r, c in bresenham(int(s_row[j]), int(s_col[j]), int(e_row[k]), int(e_col[k])):
                expect[r, c] += 1
    assert np.array_equal(passes, expect)
