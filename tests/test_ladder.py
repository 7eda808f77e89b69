"""The course's preparation ladder: first scan, prediction only, a few particles, the
linear_exp weighting on THOR-sized scans, and the `+experiment=ladder` sweep."""

from __future__ import annotations

import html
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hydra import compose, initialize_config_module

from slamlab import artifacts
from slamlab.cli.app import run_and_report
from slamlab.errors import ConfigError
from slamlab.frames import ScanFrame, Sequence
from slamlab.report.particle_figures import particle_paths_figure
from slamlab.report.rundir import load_run
from slamlab.assemble import build_components
from slamlab.slam.engine import run_slam
from slamlab.slam.grid import MapSettings
from slamlab.slam.matcher import GridMatcher, LikelihoodFieldMatcher
from slamlab.slam.raycast import bresenham
from slamlab.slam.weighting import LogSumExpWeighting, WeightUnderflowWarning

SHORT_SIM = "dataset.duration_s=20"


def make_cfg(*overrides: str):
    with initialize_config_module(config_module="slamlab.conf", version_base="1.3"):
        return compose(config_name="config", overrides=list(overrides))


def _line_sequence(n: int, step_m: float, rng_seed: int | None = None) -> Sequence:
    """A robot driving straight along x, `step_m` per scan after 3 static scans; a wall at
    y = 2 m in the scans (random ranges when `rng_seed` is given)."""
    angles = np.linspace(0.2, np.pi - 0.2, 31).astype(np.float32)
    rng = None if rng_seed is None else np.random.default_rng(rng_seed)
    scans = []
    for i in range(n):
        x = max(i - 3, 0) * step_m
        ranges = (2.0 / np.sin(angles)).astype(np.float32) if rng is None else rng.uniform(0.5, 8.0, len(angles)).astype(np.float32)
        scans.append(ScanFrame(index=i, t=0.1 * i, odom=np.array([x, 0.0, 0.0]), ranges=ranges, angles=angles,
                               valid=np.ones(len(angles), bool), lidar_to_body=np.eye(4)))
    return Sequence(name="line", scans=scans, body_height_m=None, sources=[], max_range_m=10.0)


def _run(tmp_path: Path, sim_cache: Path, *overrides: str) -> tuple[Path, dict]:
    ov = [*overrides, f"dataset.cache_dir={sim_cache}"]
    run_dir = tmp_path / "run"
    metrics = run_and_report(make_cfg(*ov), run_dir, overrides=list(overrides), progress="off")
    return run_dir, metrics


# ---------------------------------------------------------------- step 1: the first scan


@pytest.mark.slow
def test_first_scan_map_holds_exactly_that_scans_hits_and_free_cells(tmp_path, sim_cache):
    run_dir, m = _run(tmp_path, sim_cache, "+experiment=ladder_first_scan", SHORT_SIM)
    # the first processed scan is the last one before the robot moves (scan 100); the run stops there
    assert m["processed_steps"] == 1 and m["scans"] == pd.read_csv(run_dir / "steps.csv")["scan_index"].iloc[0] + 1
    assert "trajectory" not in m  # nothing to score: it sits at the true start pose
    with np.load(run_dir / "first_scan.npz") as z:
        pts, sensor = z["points_xy"], z["sensor_xy"]
    grid = artifacts.read_map(run_dir)
    lo = grid.data
    res, (ox, oy) = grid.resolution_m, grid.origin_xy
    # a THOR scan, beams into the floor dropped: still hundreds of points
    assert 300 < len(pts) <= 1081

    def cell(xy):
        return np.floor((xy[..., 1] - oy) / res).astype(int), np.floor((xy[..., 0] - ox) / res).astype(int)

    # Rebuild the map from the scan alone: every beam frees the cells before its end, then
    # every end cell gets a hit (raycast order), each clamped like the map settings say.
    s = MapSettings()
    n_free = np.zeros(lo.shape, int)
    n_hit = np.zeros(lo.shape, int)
    r0, c0 = cell(sensor)
    rows, cols = cell(pts)
    for r1, c1 in zip(rows, cols):
        for r, c in bresenham(int(r0), int(c0), int(r1), int(c1))[:-1]:
            n_free[r, c] += 1
        n_hit[r1, c1] += 1
    want = np.minimum(np.maximum(n_free * s.log_odds_free, s.clamp_min) + n_hit * s.log_odds_occupied, s.clamp_max)
    touched = (n_free + n_hit) > 0
    np.testing.assert_array_equal(lo != 0, touched)  # nothing outside the scan's beams
    np.testing.assert_allclose(lo[touched], want[touched], atol=1e-5)
    occupied = lo > s.occupied_threshold
    assert occupied.sum() > 100 and np.all(n_hit[occupied] > 0)  # walls are hit cells only
    # the report shows the scan over its map
    page = (run_dir / "report.html").read_text()
    assert 'id="first-scan"' in page and f"{len(pts)} points" in page and "holds this scan only" in page
    assert "a single filter step: nothing to plot over time" in page and "N_eff over time" not in page
    assert "none (the first scan only)" in page and "dead reckoning" not in page.split('id="first-scan"')[0]


# ---------------------------------------------------------------- step 3: prediction only


def test_predict_keeps_every_path_moves_with_the_motion_model_and_uses_no_scan(monkeypatch):
    def no_matching(*_a, **_k):
        raise AssertionError("mode=predict must not match scans")

    for cls in (GridMatcher, LikelihoodFieldMatcher):
        monkeypatch.setattr(cls, "match", no_matching)
        monkeypatch.setattr(cls, "match_each", no_matching)
    cfg = make_cfg("mode=predict", "particles=40", "seed=3")
    a = run_slam(_line_sequence(40, 0.05), build_components(cfg))
    h = a.particle_history
    assert h is not None and h.poses.shape == (a.extras["processed_steps"], 40, 3)
    assert len({p.tobytes() for p in h.poses[-1]}) == 40  # 40 different paths, none merged
    np.testing.assert_array_equal(h.weights, 1 / 40)  # never weighted
    assert a.resample_count == 0 and not h.resampled.any()
    np.testing.assert_array_equal(h.parents, np.tile(np.arange(40), (len(h.parents), 1)))
    # the cloud is centred on the odometry
    np.testing.assert_allclose(h.poses[-1, :, :2].mean(axis=0), a.odometry[-1, :2], atol=0.02)
    # other scans (random ranges) give the very same particles: the scans are not used
    b = run_slam(_line_sequence(40, 0.05, rng_seed=1), build_components(cfg))
    assert b.particle_history.poses.tobytes() == h.poses.tobytes()


def test_predict_spread_after_one_metre_matches_the_configured_noise():
    n = 2000
    sxy, sth, step = 0.01, 0.02, 0.05
    cfg = make_cfg("mode=predict", f"particles={n}", f"motion.sigma_xy_m={sxy}", f"motion.sigma_theta_rad={sth}",
                   "motion.per_distance_m=0.1")
    res = run_slam(_line_sequence(60, step), build_components(cfg))
    steps = res.steps
    k = int(np.argmax(steps["distance_m"] >= 1.0 - 1e-9))
    assert steps["distance_m"][k] == pytest.approx(1.0)
    # closed form for 20 straight steps with per-step sigmas scaled by 0.05 / 0.1
    m, a, b = 20, sxy * step / 0.1, sth * step / 0.1
    var_xy = 2 * m * a**2 + step**2 * b**2 * sum(i * i for i in range(m))
    want_xy, want_th = np.sqrt(var_xy), np.sqrt(m) * b
    assert steps["expected_spread_xy_m"][k] == pytest.approx(want_xy, rel=1e-9)
    assert steps["expected_spread_theta_rad"][k] == pytest.approx(want_th, rel=1e-9)
    # sampling error of a standard deviation from n draws: about 1 / sqrt(2 n) = 1.6 %; allow 3 of them
    tol = 3 / np.sqrt(2 * n)
    assert steps["spread_xy_m"][k] == pytest.approx(want_xy, rel=tol)
    assert steps["spread_theta_rad"][k] == pytest.approx(want_th, rel=tol)
    # and the noise really is what moved them: ten times the noise, ten times the spread
    loud = run_slam(_line_sequence(60, step), build_components(make_cfg("mode=predict", f"particles={n}", f"motion.sigma_xy_m={10 * sxy}",
                                                       f"motion.sigma_theta_rad={10 * sth}", "motion.per_distance_m=0.1")))
    assert loud.steps["spread_theta_rad"][k] == pytest.approx(10 * want_th, rel=tol)


@pytest.mark.slow
def test_predict_run_report_draws_every_path_and_the_spread(tmp_path, sim_cache):
    run_dir, m = _run(tmp_path, sim_cache, "+experiment=ladder_predict", SHORT_SIM, "steps.max_scans=300")
    assert m["mode"] == "predict" and m["resample_count"] == 0
    rec = load_run(run_dir).load_particles()
    assert rec.poses.shape[1:] == (100, 3)
    fig = particle_paths_figure(None, rec, None, None)
    assert len(fig.axes[0].collections[0].get_paths()) == 100  # one line per particle
    page = (run_dir / "report.html").read_text()
    assert 'id="predict"' in page and "every particle" in page and 'id="spread-table"' in page
    steps = pd.read_csv(run_dir / "steps.csv")
    assert steps["expected_spread_xy_m"].iloc[-1] > 0 and steps["spread_xy_m"].iloc[-1] > 0


# ---------------------------------------------------------------- step 4: a few particles


def _table_rows(page: str, table_id: str) -> list[list[str]]:
    body = re.search(rf'<table id="{table_id}">(.*?)</table>', page, re.S).group(1)
    rows = []
    for tr in re.findall(r"<tr[^>]*>(.*?)</tr>", body, re.S):
        cells = re.findall(r"<td[^>]*>(.*?)</td>", tr, re.S)
        if cells:
            rows.append([html.unescape(c) for c in cells])
    return rows


@pytest.mark.slow
def test_three_particle_report_shows_the_weights_the_engine_computed(tmp_path, sim_cache, monkeypatch):
    seen: list[np.ndarray] = []
    real_update = LogSumExpWeighting.update

    def spy(self, log_weights, scores):
        out = real_update(self, log_weights, scores)
        seen.append(np.exp(out))
        return out

    monkeypatch.setattr(LogSumExpWeighting, "update", spy)
    run_dir, m = _run(tmp_path, sim_cache, "+experiment=ladder_few_particles", SHORT_SIM, "steps.max_scans=190")
    assert m["particles"] == 3 and 50 < m["processed_steps"] <= 100  # the first 100 scans stand still
    rows = _table_rows((run_dir / "report.html").read_text(), "weights-table")
    assert len(rows) == m["processed_steps"]
    shown = np.array([[float(v) for v in r[2:5]] for r in rows])
    engine = np.vstack([np.full(3, 1 / 3), *seen])  # step 0 is not weighted
    assert len(seen) == m["processed_steps"] - 1
    np.testing.assert_allclose(shown, engine, rtol=1e-5, atol=1e-300)
    # resampling is marked on exactly the steps the engine resampled, with the copies made
    steps = pd.read_csv(run_dir / "steps.csv")
    marked = np.array([r[-1].startswith("yes") for r in rows])
    np.testing.assert_array_equal(marked, steps["resampled"].to_numpy(bool))
    assert 0 < marked.sum() == m["resample_count"]
    rec = load_run(run_dir).load_particles()
    k = int(np.flatnonzero(marked)[0])
    assert rows[k][-1] == "yes: " + ", ".join(f"{j}←{p}" for j, p in enumerate(rec.parents[k + 1]))


# ---------------------------------------------------------------- linear_exp on THOR scans


@pytest.mark.slow
def test_linear_exp_overflow_on_thor_scans_is_counted_and_reported(tmp_path, sim_cache):
    # all 1,081 beams (matcher.beam_step=1): the best particle hits 750-1,070 wall cells per
    # scan, past exp's float64 limit at every update (the default beam_step=4 stays near 260)
    with pytest.warns(WeightUnderflowWarning, match="overflow"):
        run_dir, m = _run(tmp_path, sim_cache, "weighting=linear_exp", "particles=10", "texture=none", SHORT_SIM,
                          "steps.max_scans=140", "matcher.beam_step=1")
    assert m["processed_steps"] > 30  # the first 100 scans stand still
    assert m["weighting_overflows"] == m["processed_steps"] - 1 and m["weighting_underflows"] == 0
    page = (run_dir / "report.html").read_text()
    assert 'class="warning"' in page and "LinearExpWeighting" in page and "overflowed at" in page
    assert "709.8" in page


# ---------------------------------------------------------------- config and the sweep preset


@pytest.mark.parametrize("override, key", [("record.particles=sometimes", "record.particles"), ("mode=replay", "mode"),
                                           ("steps.max_steps=0", "steps.max_steps")])
def test_bad_ladder_values_name_the_key(override, key):
    with pytest.raises(ConfigError) as e:
        build_components(make_cfg(override))
    assert e.value.key == key


def test_record_first_scan_must_be_a_bool():
    # a type the schema (slamlab.config.run.RecordConfig) refuses: one line before anything runs
    from slamlab.cli.overrides import check_overrides

    assert check_overrides(["record.first_scan=maybe"]).startswith("config 'record.first_scan': ")


@pytest.mark.slow
def test_ladder_sweep_runs_every_step_into_one_report(tmp_path, sim_cache):
    sweep = tmp_path / "ladder"
    cmd = [sys.executable, "-m", "slamlab.cli.app", "+experiment=ladder", "dataset.duration_s=6", "progress=off",
           f"dataset.cache_dir={sim_cache}", f"hydra.sweep.dir={sweep}"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    modes = {}
    for i in range(5):
        m = json.loads((sweep / str(i) / "metrics.json").read_text())
        assert m["status"] == "ok"
        # a sweep its config starts (hydra.mode: MULTIRUN) is a sweep too: each step in its own
        # child process, its peak its own (Hydra leaves such a job's mode unset: issue 45)
        assert m["peak_memory_scope"] == "run"
        modes[i] = (m["mode"], m["particles"], m["processed_steps"])
    assert modes[0] == ("odometry", 1, 1)
    assert "trajectory" not in json.loads((sweep / "0" / "metrics.json").read_text())
    assert modes[1][:2] == ("odometry", 1) and modes[2][:2] == ("predict", 100)
    assert modes[3][:2] == ("slam", 3) and modes[4][:2] == ("slam", 100)
    page = (sweep / "report.html").read_text()
    for name in ("ladder_first_scan", "ladder_dead_reckoning", "ladder_predict", "ladder_few_particles", "ladder_full"):
        assert name in page


@pytest.mark.slow
def test_linear_exp_equals_logsumexp_on_thor_scans_without_overflow(tmp_path, sim_cache, monkeypatch):
    # the default beam_step=4 keeps the best correlation near 260 < 709.8: no overflow, and at
    # every update of a THOR run log-sum-exp gives the weights linear_exp computed. (Two whole
    # runs drift apart after ~100 steps: a last-bit difference flips an argmax or a resample.)
    from slamlab.slam.weighting import LinearExpWeighting

    pairs: list[tuple[np.ndarray, np.ndarray]] = []
    real_update = LinearExpWeighting.update

    def both(self, log_weights, scores):
        out = real_update(self, log_weights, scores)
        pairs.append((np.exp(out), np.exp(LogSumExpWeighting(self.temperature).update(log_weights, scores))))
        return out

    monkeypatch.setattr(LinearExpWeighting, "update", both)
    _, m = _run(tmp_path, sim_cache, "weighting=linear_exp", "particles=10", "texture=none", SHORT_SIM, "steps.max_scans=400")
    assert m["weighting_overflows"] == 0 and m["weighting_underflows"] == 0
    assert len(pairs) == m["processed_steps"] - 1 > 250
    lin, lse = np.array([a for a, _ in pairs]), np.array([b for _, b in pairs])
    np.testing.assert_allclose(lin, lse, rtol=1e-9, atol=1e-300)
    assert np.median(lin.max(axis=1)) > 0.2  # real, uneven weights (uniform would be 0.1)
