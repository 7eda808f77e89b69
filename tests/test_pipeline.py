"""The whole run: config -> run directory, reproducibility, bad config, interruption, CLI."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hydra import compose, initialize_config_module

from cli_helpers import slamlab_cli
from slamlab import artifacts
from slamlab.cli.app import run_and_report
from slamlab.errors import ConfigError
from slamlab.pipeline import RunDirectoryInUse, run_pipeline

SHORT_SIM = ["dataset.duration_s=20", "particles=10"]


def make_cfg(overrides: list[str]):
    with initialize_config_module(config_module="slamlab.conf", version_base="1.3"):
        return compose(config_name="config", overrides=overrides)


def visible_files(folder: Path) -> list[str]:
    """What a person sees in a run folder (the hidden claim marker aside)."""
    return sorted(p.name for p in folder.iterdir() if not p.name.startswith("."))


@pytest.fixture(scope="module")
def sim_run(sim_cache, tmp_path_factory) -> Path:
    """One short simulated run with texture and report, shared by the checks below (slow: a
    fresh session generates the sequence first; `test_same_seed_...` is the quick whole run)."""
    run_dir = tmp_path_factory.mktemp("run") / "r"
    cfg = make_cfg([*SHORT_SIM, f"dataset.cache_dir={sim_cache}"])
    run_and_report(cfg, run_dir, overrides=SHORT_SIM, progress="off")  # as `slamlab` runs it
    return run_dir


@pytest.mark.slow
def test_run_directory_holds_every_artifact(sim_run):
    for name in (
        "map.png", "map.pgm", "map.yaml", "map_logodds.npz", "trajectory.tum", "trajectory_causal.tum",
        "odometry.tum", "groundtruth.tum", "steps.csv", "metrics.json", "manifest.json",
        "texture.png", "texture_over_map.png", "report.html",
    ):
        assert (sim_run / name).is_file(), name
    assert not list(sim_run.glob(f"{artifacts.TMP_MARK}*"))


@pytest.mark.slow
def test_metrics_are_consistent_with_the_files(sim_run):
    m = json.loads((sim_run / "metrics.json").read_text())
    assert m["status"] == "ok" and m["particles"] == 10
    times, traj = artifacts.read_tum(sim_run / "trajectory.tum")
    _, truth = artifacts.read_tum(sim_run / "groundtruth.tum")
    _, odom = artifacts.read_tum(sim_run / "odometry.tum")
    assert m["scans"] == len(times)
    rmse = float(np.sqrt(np.mean(np.sum((traj[:, :2] - truth[:, :2]) ** 2, axis=1))))
    assert m["trajectory"]["rmse_m"] == pytest.approx(rmse, abs=1e-6)
    # SLAM corrects the simulator's drifting odometry
    odo_rmse = float(np.sqrt(np.mean(np.sum((odom[:, :2] - truth[:, :2]) ** 2, axis=1))))
    assert m["trajectory"]["rmse_m"] < odo_rmse
    steps = pd.read_csv(sim_run / "steps.csv")
    assert m["processed_steps"] == len(steps)
    assert m["neff_min"] == pytest.approx(steps["neff"].min())
    assert m["resample_count"] == int(steps["resampled"].sum())
    assert m["texture"]["status"] == "ok" and m["texture"]["covered_area_m2"] > 1.0


@pytest.mark.slow
def test_manifest_can_reproduce_the_run(sim_run):
    man = json.loads((sim_run / "manifest.json").read_text())
    assert man["seed"] == 0 and man["config"]["particles"] == 10
    assert len(man["data"]["sha256"]) == 64 and man["data"]["files"]
    assert man["slamlab_version"]


def test_same_seed_same_bytes_other_seed_differs(sim_cache, tmp_path):
    base = [*SHORT_SIM, f"dataset.cache_dir={sim_cache}", "texture=none", "report=false", "steps.max_scans=300"]
    for name, seed in (("a", 0), ("b", 0), ("c", 1)):
        run_pipeline(make_cfg([*base, f"seed={seed}"]), tmp_path / name, progress="off")
    a, b, c = ((tmp_path / n / "trajectory.tum").read_bytes() for n in "abc")
    assert a == b
    assert a != c


@pytest.mark.parametrize(
    "override, key",
    [  # every key is checked in test_slam_engine; here: what a failed run leaves behind
        ("particles=0", "particles"),
        ("resampler.threshold=1.5", "resampler.threshold"),
        ("dataset=carmen", "dataset.path"),  # a required value left out
        ("dataset.n_clutter=-1", "dataset.n_clutter"),  # a dataset knob out of range
    ],
)
def test_impossible_values_name_the_key(override, key, tmp_path):
    cfg = make_cfg([override])
    with pytest.raises(ConfigError) as exc:
        run_pipeline(cfg, tmp_path / "r", progress="off")
    assert exc.value.key == key
    # the failed run says why, and leaves no artifacts but that
    m = json.loads((tmp_path / "r" / "metrics.json").read_text())
    assert m["status"] == "failed" and key in m["error"]
    assert visible_files(tmp_path / "r") == ["metrics.json"]


def test_a_value_of_the_wrong_type_is_refused_when_composing():
    """Types come from the schemas (`slamlab.config`): Hydra refuses `dataset.seed=abc` while
    composing, and the CLI's check says so in one line naming the key."""
    from hydra.errors import ConfigCompositionException

    from slamlab.cli.overrides import check_overrides

    with pytest.raises(ConfigCompositionException, match="dataset.seed"):
        make_cfg(["dataset.seed=abc"])
    assert check_overrides(["dataset.seed=abc"]) == (
        "config 'dataset.seed': Value 'abc' of type 'str' could not be converted to Integer")
    assert check_overrides(["-m", "particles=10,x"]).startswith("config 'particles': ")
    assert check_overrides(["particles=10", "dataset.seed=3"]) is None


def test_a_folder_claimed_by_a_running_run_is_refused(tmp_path):
    (tmp_path / "r").mkdir()
    (tmp_path / "r" / ".slamlab-run").touch()  # another process has just started here
    with pytest.raises(RunDirectoryInUse):
        run_pipeline(make_cfg(SHORT_SIM), tmp_path / "r", progress="off")
    assert visible_files(tmp_path / "r") == []


@pytest.mark.slow
def test_a_finished_run_is_never_overwritten(sim_run):
    before = (sim_run / "trajectory.tum").read_bytes()
    with pytest.raises(RunDirectoryInUse):
        run_pipeline(make_cfg(SHORT_SIM), sim_run, progress="off")
    assert (sim_run / "trajectory.tum").read_bytes() == before


def test_interrupted_run_leaves_no_half_written_files(sim_cache, tmp_path):
    cfg = make_cfg([*SHORT_SIM, f"dataset.cache_dir={sim_cache}", "texture=none"])

    def interrupt(done: int, total: int) -> None:
        if done >= total // 3:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_pipeline(cfg, tmp_path / "r", progress=interrupt)
    assert visible_files(tmp_path / "r") == ["metrics.json"]
    assert json.loads((tmp_path / "r" / "metrics.json").read_text())["status"] == "interrupted"


def _cli(args: list[str], cwd: Path, cache: Path) -> subprocess.CompletedProcess:
    return slamlab_cli(args, cwd, cache, timeout=600)


def test_cli_bad_input_is_one_clear_line(tmp_path, sim_cache, slamlab_app):
    missing = tmp_path / "nowhere.clf"
    proc = slamlab_app(["dataset=carmen", f"dataset.path={missing}", f"hydra.run.dir={tmp_path / 'r'}"], tmp_path, sim_cache)
    assert proc.returncode == 2
    assert str(missing) in proc.stderr
    assert "Traceback" not in proc.stderr
    proc = slamlab_app(["resampler=nonesuch"], tmp_path, sim_cache)
    assert proc.returncode != 0 and "resampler" in proc.stderr and "Traceback" not in proc.stderr


@pytest.mark.slow
def test_cli_refuses_a_used_run_dir(sim_run, tmp_path, sim_cache, slamlab_app):
    proc = slamlab_app([f"hydra.run.dir={sim_run}"], tmp_path, sim_cache)
    assert proc.returncode == 2 and "never overwrites" in proc.stderr
    assert json.loads((sim_run / "metrics.json").read_text())["status"] == "ok"


@pytest.mark.slow
def test_verify_says_identical_then_finds_a_tampered_line(tmp_path, sim_cache):
    run = tmp_path / "run"
    # texture on (as in the default run and the grading preset): its timings must not count,
    # its results must
    args = [*SHORT_SIM, f"dataset.cache_dir={sim_cache}", "steps.max_scans=200", "report=false",
            f"hydra.run.dir={run}"]
    assert _cli(args, tmp_path, sim_cache).returncode == 0
    env = {**os.environ, "SLAMLAB_CACHE_DIR": str(sim_cache)}
    ok = subprocess.run([sys.executable, "-m", "slamlab.cli.verify", str(run)], capture_output=True, text=True, env=env)
    assert ok.returncode == 0, ok.stdout + ok.stderr
    assert "IDENTICAL" in ok.stdout
    lines = (run / "trajectory.tum").read_text().splitlines()
    lines[50] = lines[50].replace(lines[50].split()[1], "123.000000000", 1)
    (run / "trajectory.tum").write_text("\n".join(lines) + "\n")
    bad = subprocess.run([sys.executable, "-m", "slamlab.cli.verify", str(run)], capture_output=True, text=True, env=env)
    assert bad.returncode == 1
    assert "trajectory.tum line 51" in bad.stdout


def test_ctrl_c_while_the_map_is_written_waits_for_the_writer(monkeypatch):
    """A Ctrl-C during the wait for the map's thread is held until the thread has ended (then
    raised), so the run folder's cleanup never races a file still being written."""
    import threading
    import time
    from concurrent.futures import ThreadPoolExecutor

    import slamlab.pipeline as P

    real_wait, calls = P.wait, []

    def interrupted_once(fs):
        calls.append(1)
        if len(calls) == 1:
            raise KeyboardInterrupt
        return real_wait(fs)

    monkeypatch.setattr(P, "wait", interrupted_once)
    pool, done = ThreadPoolExecutor(max_workers=1), threading.Event()
    job = pool.submit(lambda: (time.sleep(0.2), done.set()))
    with pytest.raises(KeyboardInterrupt):
        P._finish_background(pool, job)
    assert done.is_set() and len(calls) == 2


@pytest.mark.slow
def test_an_interrupted_run_writes_its_report_marked_interrupted(sim_cache, tmp_path):
    """Issue 45: a run stopped by Ctrl-C got no report. It gets one, marked interrupted, from
    what it wrote: the map and paths so far, and the verdict on them."""
    import signal

    from slamlab.cli.app import run_and_report
    from slamlab.interrupt import RunInterrupted

    cfg = make_cfg([*SHORT_SIM, f"dataset.cache_dir={sim_cache}", "texture=none"])

    def ctrl_c(done: int, total: int) -> None:
        if done >= total // 3:
            signal.raise_signal(signal.SIGINT)  # as a terminal's Ctrl-C: the run stops after this step

    with pytest.raises(RunInterrupted):
        run_and_report(cfg, tmp_path / "r", progress=ctrl_c)
    m = json.loads((tmp_path / "r" / "metrics.json").read_text())
    assert m["status"] == "interrupted" and m["partial"] is True
    page = (tmp_path / "r" / "report.html").read_text()
    assert '<span class="badge interrupted">interrupted</span>' in page and "This run was interrupted" in page
    assert f"Stopped by Ctrl-C at scan {m['interrupted_at_scan']} of {m['scans_total']}" in page
    assert 'alt="occupancy map with trajectories"' in page and 'id="verdict-line"' in page
    assert not list((tmp_path / "r").glob(".partial-*"))


def test_a_failing_texture_score_keeps_the_textures_and_says_so(sim_cache, tmp_path, monkeypatch):
    """The texture stage scores before it writes its files (memory: the scores' temporaries come
    before Open3D loads); a score that fails must still leave the textures and the SLAM results
    on disk, and the run says the texture stage failed."""
    import slamlab.eval.texture

    def broken(result, truth, truth_on_grid=None):
        raise MemoryError("no room for the true floor texture")

    monkeypatch.setattr(slamlab.eval.texture, "texture_metrics", broken)
    cfg = make_cfg([*SHORT_SIM, f"dataset.cache_dir={sim_cache}"])
    run_pipeline(cfg, tmp_path / "r")
    files = visible_files(tmp_path / "r")
    for name in ("trajectory.tum", "map.pgm", "texture.png", "texture_over_map.png", "floor.ply",
                 "texture_odometry.png", "floor_odometry.ply"):
        assert name in files
    metrics = json.loads((tmp_path / "r" / "metrics.json").read_text())
    assert metrics["texture"]["status"] == "failed" and "no room for the true floor texture" in metrics["texture"]["error"]
    assert "texture_truth.png" not in files  # it comes after the scores, which failed
