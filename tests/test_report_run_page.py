"""The run report's replay, error over time and ground-detection frames, on real runs.

Two real runs through the `slamlab` app (a short default simulated run with RGB-D, and the
first 800 Intel scans with benchmark relations); the files they record are checked against
the run's own results, and each page is opened in headless Chromium, which reports from
inside the page whether every image decodes and the replay moves
(benchmarks/screenshot_reports.py `page_check`)."""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import slamlab
from slamlab.artifacts import read_map
from slamlab.frames import GridImage
from slamlab.report import write_run_report
from slamlab.report.replay_section import frame_image
from slamlab.assemble import build_components
from slamlab.slam.engine import run_slam
from slamlab.slam.replay import SNAPSHOTS, reduce_map, snapshot_steps
from test_slam_engine import _cfg, _room_sequence

_spec = importlib.util.spec_from_file_location(
    "screenshot_reports", Path(__file__).resolve().parents[1] / "benchmarks" / "screenshot_reports.py")
shots = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(shots)

CONF = Path(slamlab.__file__).resolve().parent / "conf"
SLAMLAB = shutil.which("slamlab", path=str(Path(sys.executable).parent)) or shutil.which("slamlab")
PAGE_LIMIT_BYTES = 8 * 1024 * 1024
needs_browser = pytest.mark.skipif(
    shots.find_browser() is None and os.environ.get("SLAMLAB_REQUIRE_BROWSER") != "1", reason="Chromium not installed")


def _run(run_dir: Path, cache: Path, *overrides: str) -> Path:
    if SLAMLAB is None:
        pytest.skip("the slamlab app is not installed")
    env = dict(os.environ, SLAMLAB_CACHE_DIR=str(cache), MPLBACKEND="Agg")
    cmd = [SLAMLAB, "-cp", str(CONF), *overrides, "progress=off", f"hydra.run.dir={run_dir}"]
    proc = subprocess.run(cmd, cwd=run_dir.parent, env=env, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return run_dir


@pytest.fixture(scope="module")
def sim_run(tmp_path_factory, sim_cache: Path) -> Path:
    return _run(tmp_path_factory.mktemp("sim") / "run", sim_cache, "dataset.duration_s=12")


@pytest.fixture(scope="module")
def intel_run(tmp_path_factory, sim_cache: Path, shared_data: Path) -> Path:
    return _run(tmp_path_factory.mktemp("intel") / "run", sim_cache, "dataset=carmen",
                f"dataset.path={shared_data / 'carmen' / 'intel.clf.bz2'}", "steps.max_scans=800")


def _replay(run: Path) -> dict[str, np.ndarray]:
    with np.load(run / "replay.npz") as z:
        return {k: np.asarray(z[k]) for k in z.files}


# ---- fast: no run needed ------------------------------------------------------------------
def test_snapshot_steps_spread_over_the_run_and_end_at_the_last_step() -> None:
    s = snapshot_steps(3400)
    assert len(s) == SNAPSHOTS and s[0] == 0 and s[-1] == 3399 and np.all(np.diff(s) > 0)
    assert list(snapshot_steps(5)) == [0, 1, 2, 3, 4]


def test_recording_the_replay_does_not_change_the_filter() -> None:
    seq = _room_sequence()
    on = run_slam(seq, build_components(_cfg("particles=20", "seed=7", "record.replay=true")))
    off = run_slam(seq, build_components(_cfg("particles=20", "seed=7", "record.replay=false")))
    assert off.replay is None and on.replay is not None
    assert np.array_equal(on.trajectory, off.trajectory) and np.array_equal(on.log_odds.data, off.log_odds.data)
    # the last snapshot is the final map, reduced
    last, _ = reduce_map(on.log_odds)
    n = on.replay["map_shape"][-1]
    assert np.array_equal(on.replay["map_pixels"][-int(n[0] * n[1]):].reshape(n), last)


def test_frame_image_places_a_snapshot_in_the_window() -> None:
    # a 2 x 2 m snapshot: one occupied cell (0) at x in [1, 2), y in [0, 1), the rest free (255)
    pixels = np.full((2, 2), 255, np.uint8)
    pixels[0, 1] = 0
    img = frame_image(pixels, np.array([0.0, 2.0, 0.0, 2.0]), (-1.0, 3.0, -1.0, 3.0), 4, 4)
    # 1 m pixels, row 0 = top (y in [2, 3)): outside the snapshot is unknown grey
    assert img[0, 0] == 128 and img[1, 1] == 255 and img[2, 2] == 0 and img[2, 1] == 255 and img[3, 3] == 128


@pytest.mark.slow
def test_replay_keeps_its_frames_inside_the_page_budget(tmp_path: Path, monkeypatch) -> None:
    from slamlab.report import replay_section as rs
    from slamlab.report.rundir import load_run

    # a fabricated run with 40 snapshots of a noisy (incompressible) map
    rng = np.random.default_rng(0)
    n, shape = 40, (64, 64)
    (tmp_path / "metrics.json").write_text(json.dumps({"status": "ok"}))
    np.savez(tmp_path / "replay.npz", step=np.arange(n), scan_index=np.arange(n), t=np.arange(n, dtype=float),
             poses=np.zeros((n, 3, 3), np.float32), best=np.zeros(n, np.int64), scan_xy=np.zeros((0, 2), np.float32),
             scan_count=np.zeros(n, np.int64), map_pixels=rng.integers(0, 256, n * 64 * 64).astype(np.uint8),
             map_shape=np.tile(shape, (n, 1)), map_extent=np.tile([0.0, 6.4, 0.0, 6.4], (n, 1)))
    full = rs.replay_section(load_run(tmp_path))
    assert full is not None and full.count == n
    budget = sum(len(f) for f in full.frames) // 3
    monkeypatch.setattr(rs, "FRAMES_BUDGET_BYTES", budget)
    thinned = rs.replay_section(load_run(tmp_path))
    assert n // 4 <= thinned.count <= n // 3 + 1 and sum(len(f) for f in thinned.frames) <= budget * 1.1
    snaps = json.loads(thinned.data_json)["snaps"]
    assert len(snaps) == thinned.count and snaps[-1]["step"] == n - 1  # the end of the run stays


# ---- real runs --------------------------------------------------------------------------------
@pytest.mark.slow
def test_sim_run_records_a_replay_that_matches_its_results(sim_run: Path) -> None:
    z = _replay(sim_run)
    metrics = json.loads((sim_run / "metrics.json").read_text())
    steps = pd.read_csv(sim_run / "steps.csv")
    assert len(z["step"]) == min(SNAPSHOTS, metrics["processed_steps"]) and z["step"][-1] == metrics["processed_steps"] - 1
    assert z["poses"].shape == (len(z["step"]), metrics["particles"], 3)
    assert np.array_equal(z["scan_index"], steps["scan_index"].to_numpy()[z["step"]])
    # the best particle of each snapshot is the causal estimate at that scan
    causal = np.loadtxt(sim_run / "trajectory_causal.tum")
    best = z["poses"][np.arange(len(z["best"])), z["best"]]
    assert np.allclose(best[:, :2], causal[z["scan_index"], 1:3], atol=1e-4)
    # the last snapshot is the final map, reduced; the map grows over the run
    final = read_map(sim_run)
    pixels, _ = reduce_map(GridImage(final.data, final.resolution_m, final.origin_xy))
    n = z["map_shape"][-1]
    assert np.array_equal(z["map_pixels"][-int(n[0] * n[1]):].reshape(n), pixels)
    # the observed area (m^2) grows as the robot explores (37 -> 76 m^2 on this run)
    at = np.concatenate([[0], np.cumsum(z["map_shape"][:, 0] * z["map_shape"][:, 1])])
    ext = z["map_extent"]
    known = [np.count_nonzero(z["map_pixels"][at[i]:at[i + 1]] != 128) * (ext[i, 1] - ext[i, 0]) * (ext[i, 3] - ext[i, 2])
             / (at[i + 1] - at[i]) for i in range(len(ext))]
    assert known[-1] > 1.5 * known[0] and known[-1] >= max(known) - 1.0


@pytest.mark.slow
def test_sim_run_keeps_labelled_ground_frames_and_the_true_texture(sim_run: Path) -> None:
    from PIL import Image

    with np.load(sim_run / "ground_frames.npz") as z:
        names = [str(v) for v in z["detectors"]]
        scores = np.asarray(z["scores"])
        assert set(names) == {"threshold", "plane", "image_plane"} and 4 <= len(z["index"]) <= 6
        assert np.isfinite(scores).all() and (scores > 0.5).all()  # labelled frames: P and R known, detectors work
        reg = z["registered_0"]
        assert reg.ndim == 3 and reg.shape[:2] == z["mask_0_threshold"].shape and reg.max() > 0
    tex = np.asarray(Image.open(sim_run / "texture.png"))
    truth = np.asarray(Image.open(sim_run / "texture_truth.png"))
    assert truth.shape == tex.shape
    shown = truth[..., 3] > 0
    assert not (shown & (tex[..., 3] == 0)).any() and shown.mean() > 0.9 * (tex[..., 3] > 0).mean()
    # the texture is close to the truth where both are shown (colour error ~10 of 255)
    diff = np.abs(tex[shown, :3].astype(float) - truth[shown, :3]).mean()
    metrics = json.loads((sim_run / "metrics.json").read_text())
    assert diff < 3 * metrics["texture"]["colour_error"] + 5


@pytest.mark.slow
@pytest.mark.data
def test_intel_run_writes_per_relation_errors_that_match_its_metrics(intel_run: Path) -> None:
    rel = pd.read_csv(intel_run / "relations.csv")
    m = json.loads((intel_run / "metrics.json").read_text())["relations"]
    assert len(rel) == m["count"]
    assert np.isclose(rel["slam_trans_m"].mean(), m["trans_abs_mean_m"], rtol=1e-4)
    assert np.isclose(rel["slam_rot_deg"].mean(), m["rot_abs_mean_deg"], rtol=1e-4)
    assert np.isclose(rel["odometry_trans_m"].mean(), m["odometry"]["trans_abs_mean_m"], rtol=1e-4)
    # the same errors split into local and loop relations (eval.relations.relation_errors, loop_min_dt_s); the first
    # 800 Intel scans hold only local relations, so the loop part is empty (the split is tested in test_relations)
    loop = (rel["t2"] - rel["t1"]) >= m["loop_min_dt_s"]
    for part, mask in (("local", ~loop), ("loop", loop)):
        assert m[part]["count"] == m["causal"][part]["count"] == m["odometry"][part]["count"] == mask.sum()
        if mask.any():
            assert np.isclose(rel["slam_trans_m"][mask].mean(), m[part]["trans_abs_mean_m"], rtol=1e-4)
            assert np.isclose(rel["odometry_trans_m"][mask].mean(), m["odometry"][part]["trans_abs_mean_m"], rtol=1e-4)
        else:
            assert m[part]["trans_abs_mean_m"] is None or np.isnan(m[part]["trans_abs_mean_m"])
    # all local here, so each path's local part is its whole: the online split scores the online path
    for path in (m, m["causal"], m["odometry"]):
        assert path["local"]["trans_abs_mean_m"] == pytest.approx(path["trans_abs_mean_m"], rel=1e-12)
    assert m["causal"]["trans_abs_mean_m"] != m["trans_abs_mean_m"]


@pytest.mark.slow
@pytest.mark.browser
@needs_browser
@pytest.mark.parametrize("which", ["sim", "intel"])
def test_run_page_in_chromium_has_errors_over_time_ground_frames_and_a_working_replay(which: str, request) -> None:
    run = request.getfixturevalue(f"{which}_run")
    t0 = time.perf_counter()
    page = write_run_report(run)
    build_s = time.perf_counter() - t0
    size = page.stat().st_size
    print(f"{which}: report {size / 1e6:.2f} MB built in {build_s:.1f} s")
    assert size < PAGE_LIMIT_BYTES
    found = shots.page_check(page)
    assert found["failed"] == [] and found["images"] >= 5
    assert found["replay_frames"] == len(_replay(run)["step"]) and found["replay_slider"] and found["replay_changes"]
    assert "errors" in found["sections"] and "replay" in found["sections"]
    html = page.read_text(encoding="utf-8")
    if which == "sim":
        assert "ground" in found["sections"]
        assert "ATE RMSE" in html and "texture colour error, SLAM / odometry" in html
    else:
        assert "ground" not in found["sections"]  # no RGB-D in a CARMEN log
        assert "rel. rotation error" in html and "odometry rel. error, the baseline" in html
        assert "online estimate&#39;s rel. error, local / loop relations" in html or "online estimate's rel. error, local / loop relations" in html


def test_compiled_templates_kept_in_the_cache_folder_when_it_can_be_written(tmp_path, monkeypatch):
    # a report process loads the templates compiled by an earlier one (Jinja2's bytecode cache)
    # and renders the same page; code compiled under other settings lives in another folder
    # (Jinja2 would take it for this template's); where the folder cannot be made, templates
    # are compiled as before
    import jinja2

    from slamlab.report import html

    (tmp_path / "t").mkdir()
    (tmp_path / "t" / "page.html").write_text("<p>{{ name }}</p>\n{% if true %}\n  kept\n{% endif %}\n")
    loader = jinja2.FileSystemLoader(str(tmp_path / "t"))

    def page(cache: jinja2.BytecodeCache | None) -> str:
        return html.make_environment(loader, cache).get_template("page.html").render(name="<b>x</b>")

    monkeypatch.setenv("SLAMLAB_CACHE_DIR", str(tmp_path / "cache"))
    first = page(html.compiled_templates())
    kept = list((tmp_path / "cache" / "templates").glob("*/__jinja2_*.cache"))
    assert len(kept) == 1 and kept[0].stat().st_size > 0
    assert page(html.compiled_templates()) == first == page(None)
    assert "&lt;b&gt;" in first and "{%" not in first and "\n\n" not in first  # escaped, blocks trimmed
    monkeypatch.setattr(html, "_BLOCKS", {"trim_blocks": False, "lstrip_blocks": False})
    assert html.compiled_templates().directory != str(kept[0].parent)
    (tmp_path / "a_file").write_text("")
    monkeypatch.setenv("SLAMLAB_CACHE_DIR", str(tmp_path / "a_file"))
    assert html.compiled_templates() is None
