"""End-to-end tests of run_slam: reproducibility, config validation, dead reckoning, a
slice of the Intel log (marked `data`)."""

from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir

from slamlab.errors import ConfigError
from slamlab.frames import ScanFrame, Sequence
from slamlab.assemble import build_components
from slamlab.slam.engine import ancestral_path, run_slam
from slamlab.slam.matcher import GridMatcher
from slamlab.slam.weighting import WeightUnderflowWarning

CONF = Path(__file__).resolve().parents[1] / "conf"


def _cfg(*overrides: str):
    with initialize_config_dir(config_dir=str(CONF), version_base=None):
        return compose(config_name="config", overrides=list(overrides))


def _room_sequence(n: int = 60) -> Sequence:
    """A robot driving 1.5 m through an L-shaped 6 x 4 m room, drifting odometry."""
    walls = [((-3, -2), (3, -2)), ((3, -2), (3, 2)), ((3, 2), (-3, 2)), ((-3, 2), (-3, -2)), ((0, 2), (0, 0.5))]
    angles = np.linspace(-np.pi, np.pi, 181, endpoint=False)
    rng = np.random.default_rng(0)
    scans = []
    for i in range(n):
        s = min(max(i - 5, 0), n) * 0.03  # 5 static scans, then 3 cm per scan
        true = np.array([-1.5 + s, -0.5, 0.2 * s])
        odom = np.array([true[0] * 1.05, true[1], true[2] + 0.02 * s])
        ranges = np.full(len(angles), np.inf)
        for (ax, ay), (bx, by) in walls:
            d = np.stack([np.cos(angles + true[2]), np.sin(angles + true[2])], 1)
            e = np.array([bx - ax, by - ay])
            den = d[:, 0] * e[1] - d[:, 1] * e[0]
            with np.errstate(divide="ignore", invalid="ignore"):
                t = ((ax - true[0]) * e[1] - (ay - true[1]) * e[0]) / den
                u = ((ax - true[0]) * d[:, 1] - (ay - true[1]) * d[:, 0]) / den
            ok = (t > 0) & (u >= 0) & (u <= 1)
            ranges = np.where(ok & (t < ranges), t, ranges)
        r = (ranges + rng.normal(0, 0.005, len(angles))).astype(np.float32)
        scans.append(ScanFrame(index=i, t=0.1 * i, odom=odom, ranges=r, angles=angles.astype(np.float32),
                               valid=np.isfinite(r), lidar_to_body=np.eye(4)))
    return Sequence(name="room", scans=scans, body_height_m=None, sources=[])


def test_same_seed_same_trajectory_bit_for_bit():
    seq = _room_sequence()
    cfg = _cfg("particles=20", "seed=7", "matcher=likelihood")
    a = run_slam(seq, build_components(cfg))
    b = run_slam(seq, build_components(cfg))
    assert a.trajectory.tobytes() == b.trajectory.tobytes()
    assert a.causal.tobytes() == b.causal.tobytes()
    assert a.log_odds.data.tobytes() == b.log_odds.data.tobytes()
    c = run_slam(seq, build_components(_cfg("particles=20", "seed=8", "matcher=likelihood")))
    assert c.trajectory.tobytes() != a.trajectory.tobytes()


def test_the_run_weighs_the_matchers_prior_for_the_sequences_beam_spacing():
    """matcher.prior_beam_deg: a prior chosen for the room's own lidar (181 beams over the full
    turn: 1.99 degrees apart) is the prior as given, to the bit; one chosen for beams 1 degree
    apart weighs half as much on this lidar, and the run changes."""
    seq = _room_sequence()
    spacing_deg = 360.0 / 181

    def run(*extra: str):
        return run_slam(seq, build_components(_cfg("particles=10", "seed=3", "matcher=likelihood", *extra)))

    plain = run()
    own = run(f"matcher.prior_beam_deg={spacing_deg:.4f}")
    assert own.trajectory.tobytes() == plain.trajectory.tobytes()
    assert run("matcher.prior_beam_deg=1.0").trajectory.tobytes() != plain.trajectory.tobytes()


def test_ancestral_path_follows_parents_not_indices():
    # 3 steps, 3 particles; pose x = 10 * step + particle index, so the path names its ancestors.
    hist = np.zeros((3, 3, 3))
    for k in range(3):
        hist[k, :, 0] = 10 * k + np.arange(3)
    parent = np.array([[0, 1, 2],   # step 0 has no parents
                       [2, 2, 0],   # step 1's particles descend from step 0's 2, 2, 0
                       [1, 0, 0]])  # step 2's from step 1's 1, 0, 0
    path = ancestral_path(hist, parent, last=0)
    # particle 0 of step 2 <- particle 1 of step 1 <- particle 2 of step 0
    np.testing.assert_array_equal(path[:, 0], [2, 11, 20])
    np.testing.assert_array_equal(ancestral_path(hist, parent, last=2)[:, 0], [2, 10, 22])


def test_smoothed_path_ends_at_the_final_best_particle():
    # the last step resamples (threshold 1.0 always does), which must not change whose path
    # is reported: the final best particle's, so its last processed pose is the causal one.
    res = run_slam(_room_sequence(), build_components(_cfg("particles=20", "matcher=likelihood", "resampler.threshold=1.0")))
    last = int(res.extras["step_scans"][-1])
    assert bool(res.steps["resampled"][-1])
    np.testing.assert_array_equal(res.trajectory[last], res.causal[last])


@pytest.mark.parametrize("matcher", ["grid", "likelihood"])
def test_slam_beats_odometry_on_a_known_room(matcher):
    seq = _room_sequence()
    res = run_slam(seq, build_components(_cfg("particles=20", f"matcher={matcher}")))
    assert res.trajectory.shape == (len(seq), 3) and len(res.steps) == res.extras["processed_steps"]
    assert list(res.steps.columns) == ["step", "scan_index", "t", "neff", "resampled", "best_weight", "step_time_s"]
    # the odometry over-counts distance by 5 % and drifts in yaw; the filter should not
    end_odo = res.odometry[-1] - res.odometry[0]
    end_est = res.trajectory[-1] - res.trajectory[0]
    true_len = (len(seq) - 6) * 0.03
    assert abs(np.hypot(*end_est[:2]) - true_len) < 0.5 * abs(np.hypot(*end_odo[:2]) - true_len)


def test_dead_reckoning_mode_follows_odometry():
    seq = _room_sequence(30)
    res = run_slam(seq, build_components(_cfg("mode=odometry")))
    np.testing.assert_allclose(res.trajectory, seq.odometry, atol=1e-9)
    assert res.particles == 1 and res.resample_count == 0


def test_linear_weighting_runs_without_underflow_on_a_good_map():
    res = run_slam(_room_sequence(30), build_components(_cfg("particles=10", "weighting=linear")))
    assert np.all(np.isfinite(res.trajectory))
    assert res.extras["weighting_underflows"] == 0


def test_linear_weighting_underflow_is_counted_and_survived(monkeypatch):
    # every correlation 0 (as on a map with no walls yet): w *= 0 leaves nothing to
    # normalise at every update; the run must go on with uniform weights and say so
    real_match = GridMatcher.match

    def zero_scores(self, grid, poses, scan):
        poses, scores = real_match(self, grid, poses, scan)
        return poses, np.zeros_like(scores)

    monkeypatch.setattr(GridMatcher, "match", zero_scores)
    with pytest.warns(WeightUnderflowWarning, match="underflowed"):
        res = run_slam(_room_sequence(30), build_components(_cfg("particles=10", "weighting=linear", "matcher=grid")))
    assert np.all(np.isfinite(res.trajectory))
    assert res.extras["weighting_underflows"] == res.extras["processed_steps"] - 1  # every update after the first
    np.testing.assert_allclose(res.steps["best_weight"][1:], 0.1)  # uniform over 10 particles


@pytest.mark.parametrize(
    "override, key",
    [
        ("particles=0", "particles"),
        ("resampler.threshold=1.5", "resampler.threshold"),
        ("resampler.threshold=0", "resampler.threshold"),
        ("map.resolution_m=-0.05", "map.resolution_m"),
        ("weighting.temperature=-1", "weighting.temperature"),
        ("steps.every=0", "steps.every"),
        ("steps.min_distance_m=-1", "steps.min_distance_m"),
        ("mode=fast", "mode"),
        ("motion.sigma_xy_m=-0.1", "motion.sigma_xy_m"),
        ("matcher.xy_step_m=0", "matcher.xy_step_m"),
        ("motion._target_=slamlab.slam.motion.NoSuchModel", "motion._target_"),
    ],
)
def test_bad_config_names_the_key(override, key):
    with pytest.raises(ConfigError) as e:
        build_components(_cfg(override))
    assert e.value.key == key and key in str(e.value)


def test_unknown_component_file_is_refused():
    with pytest.raises(Exception, match="resampler"):
        _cfg("resampler=nonsense")


@pytest.mark.data
def test_intel_slice_beats_odometry(shared_data):
    from slamlab.datasets.carmen import load_carmen
    from slamlab.eval.relations import relation_errors

    full = load_carmen(shared_data / "carmen" / "intel.clf.bz2")
    n = 2000  # the first 1000 scans barely drift (odometry 0.02 m); by 2000 it is 0.21 m
    seq = Sequence(name="intel-slice", scans=full.scans[:n], body_height_m=None, sources=full.sources,
                   max_range_m=full.max_range_m, min_range_m=full.min_range_m)
    t = seq.times
    rel = full.relations
    inside = np.isin(rel.t1, t) & np.isin(rel.t2, t)
    assert inside.sum() > 50
    from slamlab.frames import Relations

    rel = Relations(t1=rel.t1[inside], t2=rel.t2[inside], rel=rel.rel[inside])
    with initialize_config_dir(config_dir=str(CONF), version_base=None):
        cfg = compose(config_name="config", overrides=["+experiment=intel", "dataset.path=unused"])
    res = run_slam(seq, build_components(cfg))
    e = relation_errors(res.times, res.trajectory, rel)
    o = relation_errors(res.times, res.odometry, rel)
    assert e["trans_abs_mean_m"] < 0.08
    assert e["trans_abs_mean_m"] < 0.25 * o["trans_abs_mean_m"]
