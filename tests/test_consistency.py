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
