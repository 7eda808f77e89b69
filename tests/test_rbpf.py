"""The filter/ group end to end: `course` is today's filter bit for bit, `rbpf` is
reproducible whatever the thread count and keeps a map per particle."""

import hashlib

import numba
import numpy as np
import pytest

from slamlab.frames import Sequence
from slamlab.assemble import build_components
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
# The same for the synthetic room of test_slam_engine (20 particles, seed 7): no data needed.
COURSE_ROOM_BEFORE = {
    "likelihood": ("75395fa8be128b067f53f3bc2def81ed6fd9283554662f217af99372c6abb19a",
                   "7b86bb37b8e03b3607986ec521f9c6893be0b4ddda132a74c89a89d3f2ca57c2"),
    "grid": ("dc171c338b20dabbe59e358fbfbd9c46f8133b72168fde16de7b7543497617aa",
             "18f91070a0c585a3336fb288a1f2649a9e3c19b02dfa4b5517d487fd197a51cc"),
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
    res = run_slam(seq, build_components(_cfg(*COURSE_KEYS, "filter=course", *extra)))
    assert (_sha(res.trajectory), _sha(res.log_odds.data)) == COURSE_BEFORE[matcher]
    assert res.extras["filter"] == "course"


@pytest.mark.slow
@pytest.mark.parametrize("matcher", ["likelihood", "grid"])
def test_course_filter_on_the_room_is_unchanged_and_is_what_old_configs_run(matcher):
    from omegaconf import OmegaConf

    seq = _room_sequence()
    keys = ("particles=20", "seed=7", f"matcher={matcher}")
    res = run_slam(seq, build_components(_cfg(*keys, "filter=course")))
    assert (_sha(res.trajectory), _sha(res.log_odds.data)) == COURSE_ROOM_BEFORE[matcher]
    # a config saved before the filter group existed has no `filter` key: it ran the course filter
    old = _cfg(*keys)
    OmegaConf.set_struct(old, False)
    del old["filter"]
    res_old = run_slam(seq, build_components(old))
    assert res_old.extras["filter"] == "course"
    assert res_old.trajectory.tobytes() == res.trajectory.tobytes()


@pytest.mark.slow
@pytest.mark.parametrize("matcher", ["likelihood", "grid"])
def test_rbpf_same_seed_gives_identical_bytes_on_one_or_two_threads(matcher):
    seq = _room_sequence()
    cfg = _cfg("filter=rbpf", "particles=12", "seed=3", f"matcher={matcher}")
    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("numba has one thread here (NUMBA_NUM_THREADS=1): nothing to compare")
    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        a = run_slam(seq, build_components(cfg))
        numba.set_num_threads(2)
        b = run_slam(seq, build_components(cfg))
    finally:
        numba.set_num_threads(before)
    assert a.trajectory.tobytes() == b.trajectory.tobytes()
    assert a.causal.tobytes() == b.causal.tobytes()
    assert a.log_odds.data.tobytes() == b.log_odds.data.tobytes()
    c = run_slam(seq, build_components(_cfg("filter=rbpf", "particles=12", "seed=4", f"matcher={matcher}")))
    assert c.trajectory.tobytes() != a.trajectory.tobytes()


@pytest.mark.slow
def test_rbpf_beats_odometry_and_reports_its_maps():
    seq = _room_sequence()
    res = run_slam(seq, build_components(_cfg("filter=rbpf", "particles=20", "matcher=likelihood")))
    # the odometry over-counts distance by 5 % (as in test_slam_engine's room test)
    true_len = (len(seq) - 6) * 0.03
    end_odo = res.odometry[-1] - res.odometry[0]
    end_est = res.trajectory[-1] - res.trajectory[0]
    assert abs(np.hypot(*end_est[:2]) - true_len) < 0.5 * abs(np.hypot(*end_odo[:2]) - true_len)
    ex = res.extras
    assert ex["filter"] == "rbpf"
    # 20 particles that diverge hold more than one map's worth of tiles and at most 20 maps'
    # (in this 6 x 4 m room every scan touches every tile, so each particle owns a full copy)
    one = run_slam(seq, build_components(_cfg("filter=rbpf", "particles=1", "matcher=likelihood"))).extras["map_tiles"]
    assert one < ex["map_tiles"] <= 20 * one
    assert ex["map_tiles"] <= ex["map_tiles_peak"]
    assert 0 < ex["map_mb"] <= ex["map_peak_mb"]
    assert ex["map_tiles_taken"] >= ex["map_tiles"]


@pytest.mark.slow
def test_rbpf_final_map_is_the_best_particles_own_map():
    """The map handed back is exactly the one built along the returned (smoothed) path: a
    single map replaying the scans at the processed steps from those poses equals it."""
    from slamlab.slam.scan import scan_to_points
    from slamlab.slam.tiles import TiledMaps

    seq = _room_sequence()
    cfg = _cfg("filter=rbpf", "particles=10", "matcher=likelihood", "seed=1")
    res = run_slam(seq, build_components(cfg))
    assert res.resample_count > 0  # the best particle's map passed through resampling
    c = build_components(cfg)
    steps = res.extras["step_scans"]
    replay = TiledMaps(c.map, 1, tuple(res.trajectory[steps[0], :2]), c.matcher.field_sigma_m, c.matcher.field_radius_m)
    for si in steps:
        pts = scan_to_points(seq.scans[si], None, seq.min_range_m, seq.max_range_m, c.map.ground_threshold_m)
        replay.insert_scan(res.trajectory[si].reshape(1, 3), pts.xy, pts.origin)
    img = replay.to_image(0)
    assert img.origin_xy == res.log_odds.origin_xy
    assert np.array_equal(img.data, res.log_odds.data)


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
    from slamlab.config.slam import RbpfFilterConfig  # the schema checks, the filter trusts it

    with pytest.raises(ConfigError, match="filter.step_ref_rad"):
        RbpfFilterConfig(step_ref_m=0.2)
    with pytest.raises(ConfigError, match="filter.step_ref_m"):
        RbpfFilterConfig(step_ref_m=-1.0, step_ref_rad=0.2)
    with pytest.raises(ConfigError, match="filter.online.*best or mean"):
        RbpfFilterConfig(online="median")


@pytest.mark.slow
def test_rbpf_short_steps_keep_the_robot_closer_to_odometry():
    """The room's odometry is 5 % long: a narrower prior (short steps against a long
    reference) lets the matcher correct less per step, so the path stays nearer odometry."""
    seq = _room_sequence()
    free = run_slam(seq, build_components(_cfg("filter=rbpf", "particles=10", "matcher=likelihood")))
    tight = run_slam(seq, build_components(_cfg("filter=rbpf", "particles=10", "matcher=likelihood", "filter.step_ref_m=3.0", "filter.step_ref_rad=30.0")))
    dev = lambda r: np.abs(r.trajectory[:, :2] - r.odometry[:, :2]).max()  # noqa: E731
    assert dev(tight) < dev(free)


def test_rbpf_online_estimate_is_the_best_particle_or_the_weighted_mean():
    """`filter.online`: the causal pose at each processed step is the highest-weight particle
    (best) or the weighted mean of the particles (mean), recomputed here from the recorded
    particles; the two differ once the particles spread."""
    from slamlab.geometry import weighted_mean_pose

    seq = _room_sequence()
    out = {}
    for online in ("best", "mean"):
        cfg = _cfg("filter=rbpf", f"filter.online={online}", "particles=15", "matcher=likelihood", "seed=3",
                   "weighting.temperature=50", "record.particles=true")
        res = run_slam(seq, build_components(cfg))
        h, steps = res.particle_history, res.extras["step_scans"]
        for k, si in enumerate(steps):
            want = h.poses[k, int(np.argmax(h.weights[k]))] if online == "best" else weighted_mean_pose(h.poses[k], h.weights[k])
            np.testing.assert_allclose(res.causal[si], want, rtol=0, atol=1e-12)  # (+) a zero odometry step
        out[online] = res
    # the same particles (the estimate does not feed back into the filter) ...
    assert out["best"].trajectory.tobytes() == out["mean"].trajectory.tobytes()
    # ... and a different online path
    assert not np.array_equal(out["best"].causal, out["mean"].causal)


@pytest.mark.data
@pytest.mark.parametrize("matcher", ["likelihood", "grid"])
def test_one_particle_in_tiles_runs_the_dense_course_filter_bit_for_bit_on_intel(shared_data, matcher):
    """The sparse tiles (filter=rbpf) against the dense grid (filter=course) on real data: with
    one particle both filters map from the same pose, so with log-odds updates whose sums are
    exact in float32 (binary fractions; the tiles' integer codes are exact for any settings)
    the runs must agree bit for bit: the same trajectory, and the tiled map equals the dense
    one on the written tiles' crop and the dense map is empty outside it."""
    from slamlab.datasets.carmen import load_carmen

    full = load_carmen(shared_data / "carmen" / "intel.clf.bz2")
    seq = Sequence(name="intel-slice", scans=full.scans[:600], body_height_m=None, sources=full.sources,
                   max_range_m=full.max_range_m, min_range_m=full.min_range_m)
    keys = ("dataset=carmen", "dataset.path=unused", "particles=1", "steps.min_distance_m=0.2", "steps.min_angle_rad=0.2",
            f"matcher={matcher}", "map.log_odds_occupied=0.875", "map.log_odds_free=-0.375")
    dense = run_slam(seq, build_components(_cfg(*keys, "filter=course")))
    tiled = run_slam(seq, build_components(_cfg(*keys, "filter=rbpf")))
    assert tiled.extras["filter"] == "rbpf" and dense.extras["filter"] == "course"
    assert tiled.trajectory.tobytes() == dense.trajectory.tobytes()
    d, t = dense.log_odds, tiled.log_odds
    assert t.resolution_m == d.resolution_m
    r0 = int(round((t.origin_xy[1] - d.origin_xy[1]) / d.resolution_m))
    c0 = int(round((t.origin_xy[0] - d.origin_xy[0]) / d.resolution_m))
    h, w = t.data.shape
    crop = d.data[r0:r0 + h, c0:c0 + w]
    assert crop.shape == t.data.shape and np.array_equal(crop, t.data)
    assert np.count_nonzero(d.data) == np.count_nonzero(crop) > 0


def _room_truth(n: int = 60) -> np.ndarray:
    """The true poses of `_room_sequence`'s scans (its own formula)."""
    s = np.minimum(np.maximum(np.arange(n) - 5, 0), n) * 0.03
    return np.column_stack([-1.5 + s, np.full(n, -0.5), 0.2 * s])


@pytest.mark.slow
@pytest.mark.parametrize("filt", ["rbpf", "course"])
def test_scans_between_steps_matched_causally_leave_the_filter_alone(filt):
    """`steps.between=match`: a scan between two steps is matched against the best
    particle's map as it was at its step, and its pose is the step's (+) the matched motion.
    The filter (steps, particles, weights) is the same as with `odometry`; the scans' motion
    from their steps comes closer to the truth than a jittery odometry's; and a run
    cut short gives the same online poses up to its end (causal: no later scan is used)."""
    from slamlab.geometry import se2_between

    import dataclasses

    room = _room_sequence()
    rng = np.random.default_rng(1)
    walk = np.cumsum(rng.normal(0.0, [0.01, 0.01, 0.005], (len(room.scans), 3)), axis=0)  # jittery odometry
    seq = dataclasses.replace(room, scans=[dataclasses.replace(f, odom=f.odom + w) for f, w in zip(room.scans, walk)])
    keys = (f"filter={filt}", "particles=10", "matcher=likelihood", "seed=2", "steps.every=4", "filter.online=mean")
    odo = run_slam(seq, build_components(_cfg(*keys)))
    mat = run_slam(seq, build_components(_cfg(*keys, "steps.between=match")))
    steps = odo.extras["step_scans"]
    assert np.array_equal(steps, mat.extras["step_scans"])
    assert odo.steps["neff"].tobytes() == mat.steps["neff"].tobytes()
    assert odo.causal[steps].tobytes() == mat.causal[steps].tobytes()
    assert odo.trajectory[steps].tobytes() == mat.trajectory[steps].tobytes()
    between = np.setdiff1d(np.arange(steps[0], len(seq.scans)), steps)
    anchor = steps[np.searchsorted(steps, between) - 1]
    truth = _room_truth()

    def err(r):  # the motion from each scan's step to it, against the true motion (m)
        return np.hypot(*(se2_between(r.causal[anchor], r.causal[between]) - se2_between(truth[anchor], truth[between]))[:, :2].T).mean()

    assert err(mat) < 0.5 * err(odo)
    # cut two scans past a step (steps 0, 4, ..., 40): scans 41 and 42 follow the cut run's last
    # step, and in the whole run they lie before step 44; matched against step 40's map in both
    assert 40 in steps and 44 in steps
    cut = run_slam(seq, build_components(_cfg(*keys, "steps.between=match", "steps.max_scans=43")))
    assert cut.causal.tobytes() == mat.causal[:43].tobytes()
    assert mat.fill == "match" and odo.fill == "odometry"
    before = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        one = run_slam(seq, build_components(_cfg(*keys, "steps.between=match")))
    finally:
        numba.set_num_threads(before)
    assert one.causal.tobytes() == mat.causal.tobytes() and one.trajectory.tobytes() == mat.trajectory.tobytes()


@pytest.mark.slow
def test_scans_between_steps_prepared_in_chunks_whatever_the_chunk(monkeypatch):
    """The scans between steps are prepared a chunk of steps at a time (`plan.BetweenScans`): the
    run is the same, to the bit, one step at a time, with scans that have no points at the
    start, inside and at the end of a chunk (they keep their odometry)."""
    import dataclasses

    from slamlab.slam import plan

    room = _room_sequence()
    blank = {1, 30, 59}  # steps every 4th scan of 60: scans 1 and 59 open and close the one 15-step chunk
    seq = dataclasses.replace(room, scans=[dataclasses.replace(f, valid=np.zeros_like(f.valid)) if i in blank else f
                                           for i, f in enumerate(room.scans)])
    keys = ("filter=rbpf", "particles=10", "matcher=likelihood", "matcher.max_gap_m=0.6", "seed=2", "steps.every=4",
            "steps.between=match")
    chunked = run_slam(seq, build_components(_cfg(*keys)))
    monkeypatch.setattr(plan.BetweenScans, "CHUNK_STEPS", 1)
    one = run_slam(seq, build_components(_cfg(*keys)))
    assert chunked.causal.tobytes() == one.causal.tobytes() and chunked.trajectory.tobytes() == one.trajectory.tobytes()
    odo = run_slam(seq, build_components(_cfg(*keys[:-1])))  # the scans between steps filled by odometry
    assert all(chunked.causal[i].tobytes() == odo.causal[i].tobytes() for i in blank)
    assert not np.array_equal(chunked.causal[40:], odo.causal[40:])  # the scans with points were matched


def test_steps_between_is_checked():
    from slamlab.errors import ConfigError

    with pytest.raises(ConfigError, match="steps.between"):
        build_components(_cfg("steps.between=interpolate"))
