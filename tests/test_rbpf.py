"""The filter/ group end to end: `course` is today's filter bit for bit, `rbpf` is
reproducible whatever the thread count and keeps a map per particle."""

import hashlib

import numba
import numpy as np
import pytest

from slamlab.frames import Sequence
from slamlab.slam.engine import run_slam
from test_slam_engine import _cfg, _room_sequence

# The course filter on the first 1200 Intel scans (likelihood matcher, 30 particles, a step
# every 0.2 m / 0.2 rad; and the grid matcher with 20 particles): sha256 of the trajectory
# and map arrays as run_slam returned them on main 7da9d7e, before the filter group existed
# (`git worktree add /tmp/old 7da9d7e` and run the same config with PYTHONPATH=/tmp/old).
COURSE_BEFORE = {
    "likelihood": ("e750428798c266bf81e830e7e0080e0a9f925ca406b956242b684d1b70fee13b",
                   "01ef259d0ee269aa76a7a75974be3c1b91430f514ff1195d1043ad5ccbf207e0"),
    "grid": ("3320f33e320d0a2a897061d43576db9425bdc60cfe6e304c22c8a4d789860369",
             "73dd19359711fbf686a082032a2cf9570ee24fd3e5d86d6e0e37d29dccc13a9f"),
}
COURSE_KEYS = ("dataset=carmen", "dataset.path=unused", "particles=30", "steps.min_distance_m=0.2", "steps.min_angle_rad=0.2")


def _sha(a: np.ndarray) -> str:
    return hashlib.sha256(a.tobytes()).hexdigest()


@pytest.mark.data
@pytest.mark.parametrize("matcher", ["likelihood", "grid"])
def test_course_filter_reproduces_the_trajectory_from_before_the_filter_group(shared_data, matcher):
    from slamlab.datasets.carmen import load_carmen

    full = load_carmen(shared_data / "carmen" / "intel.clf.bz2")
    seq = Sequence(name="intel-slice", scans=full.scans[:1200], body_height_m=None, sources=full.sources,
                   max_range_m=full.max_range_m, min_range_m=full.min_range_m)
    extra = ["matcher=likelihood"] if matcher == "likelihood" else ["matcher=grid", "particles=20"]
    res = run_slam(seq, _cfg(*COURSE_KEYS, "filter=course", *extra))
    assert (_sha(res.trajectory), _sha(res.log_odds.data)) == COURSE_BEFORE[matcher]
    assert res.extras["filter"] == "course"


@pytest.mark.parametrize("matcher", ["likelihood", "grid"])
def test_rbpf_same_seed_gives_identical_bytes_on_one_or_two_threads(matcher):
    seq = _room_sequence()
    cfg = _cfg("filter=rbpf", "particles=12", "seed=3", f"matcher={matcher}")
    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        a = run_slam(seq, cfg)
        numba.set_num_threads(max(before, 2) if numba.config.NUMBA_NUM_THREADS >= 2 else 1)
        b = run_slam(seq, cfg)
    finally:
        numba.set_num_threads(before)
    assert a.trajectory.tobytes() == b.trajectory.tobytes()
    assert a.causal.tobytes() == b.causal.tobytes()
    assert a.log_odds.data.tobytes() == b.log_odds.data.tobytes()
    c = run_slam(seq, _cfg("filter=rbpf", "particles=12", "seed=4", f"matcher={matcher}"))
    assert c.trajectory.tobytes() != a.trajectory.tobytes()


def test_rbpf_beats_odometry_and_reports_its_maps():
    seq = _room_sequence()
    res = run_slam(seq, _cfg("filter=rbpf", "particles=20", "matcher=likelihood"))
    # the odometry over-counts distance by 5 % (as in test_slam_engine's room test)
    true_len = (len(seq) - 6) * 0.03
    end_odo = res.odometry[-1] - res.odometry[0]
    end_est = res.trajectory[-1] - res.trajectory[0]
    assert abs(np.hypot(*end_est[:2]) - true_len) < 0.5 * abs(np.hypot(*end_odo[:2]) - true_len)
    ex = res.extras
    assert ex["filter"] == "rbpf"
    # 20 particles that diverge hold more than one map's worth of tiles, less than 20 maps'
    assert 0 < ex["map_tiles"] <= ex["map_tiles_peak"]
    assert 0 < ex["map_mb"] <= ex["map_peak_mb"]
    assert ex["map_tiles_copied"] > 0


def test_rbpf_final_map_is_the_best_particles_own_map():
    """The map handed back is the one built along the returned best particle's path: the
    final particle's scan endpoints land on occupied cells of it."""
    seq = _room_sequence()
    res = run_slam(seq, _cfg("filter=rbpf", "particles=10", "matcher=grid", "seed=1"))
    img = res.log_odds
    occ = img.data > 0
    assert occ.sum() > 50
    # the room's walls (x = +-3, y = +-2 around the start at (-1.5, -0.5) in the odometry frame)
    ys, xs = np.nonzero(occ)
    wx = img.origin_xy[0] + (xs + 0.5) * img.resolution_m
    assert wx.max() - wx.min() == pytest.approx(6.0, abs=0.4)


def test_rbpf_step_scale_narrows_the_prior_for_short_steps_only():
    from slamlab.errors import ConfigError
    from slamlab.slam.filters import RaoBlackwellFilter, SharedMapFilter

    off = RaoBlackwellFilter()
    assert off.step_scale(np.array([0.05, 0.0, 0.3])) == 1.0
    f = RaoBlackwellFilter(step_ref_m=0.2, step_ref_rad=0.2)
    assert f.step_scale(np.array([0.1, 0.0, 0.0])) == pytest.approx(0.5)
    assert f.step_scale(np.array([0.03, 0.04, 0.05])) == pytest.approx(0.5)
    assert f.step_scale(np.array([5.0, 0.0, 0.0])) == 1.0  # long steps keep the prior
    assert SharedMapFilter().step_scale(np.array([0.1, 0.0, 0.0])) == 1.0
    with pytest.raises(ConfigError, match="filter.step_ref_rad"):
        RaoBlackwellFilter(step_ref_m=0.2)
    with pytest.raises(ConfigError, match="filter.step_ref_m"):
        RaoBlackwellFilter(step_ref_m=-1.0, step_ref_rad=0.2)


def test_rbpf_short_steps_keep_the_robot_closer_to_odometry():
    """The room's odometry is 5 % long: a narrower prior (short steps against a long
    reference) lets the matcher correct less per step, so the path stays nearer odometry."""
    seq = _room_sequence()
    free = run_slam(seq, _cfg("filter=rbpf", "particles=10", "matcher=likelihood"))
    tight = run_slam(seq, _cfg("filter=rbpf", "particles=10", "matcher=likelihood", "filter.step_ref_m=3.0", "filter.step_ref_rad=30.0"))
    dev = lambda r: np.abs(r.trajectory[:, :2] - r.odometry[:, :2]).max()  # noqa: E731
    assert dev(tight) < dev(free)
