"""Runs never mislabel each other and fail cleanly, through the real `slamlab` command:
two runs started together into one folder, Ctrl-C (SIGINT) to a running process, a sweep
with a failing job."""

from __future__ import annotations

import json
import signal
import subprocess
from pathlib import Path

import pytest
import yaml

from cli_helpers import slamlab_start
from slamlab import artifacts
from slamlab.report.rundir import load_run

pytestmark = pytest.mark.slow  # real processes started together, interrupted, killed; sweeps

QUICK = ["steps.max_scans=300", "texture=none", "report=false", "progress=off", "dataset.duration_s=20"]


def start(args: list[str], cwd: Path, cache: Path) -> subprocess.Popen:
    return slamlab_start(args, cwd, cache)


@pytest.mark.parametrize("interpolated", [False, True])
def test_two_runs_started_together_into_one_folder(tmp_path, sim_cache, interpolated):
    # the sequence is generated once first, so both runs reach Hydra's start at the same moment
    warm = start([*QUICK, f"hydra.run.dir={tmp_path / 'warm'}"], tmp_path, sim_cache)
    assert warm.wait(timeout=600) == 0
    for attempt in range(3):
        folder = tmp_path / f"shared{attempt}"
        # a folder named by the config (`${...}`) is the same folder, and claimed as early
        name = f"{folder}_${{dataset.duration_s}}" if interpolated else str(folder)
        folder = Path(f"{folder}_20.0") if interpolated else folder  # the schema makes it a float
        procs = {seed: start([*QUICK, f"seed={seed}", f"hydra.run.dir={name}"], tmp_path, sim_cache)
                 for seed in (1, 2)}
        results = {seed: (p.wait(timeout=600), p.stderr.read()) for seed, p in procs.items()}
        winners = [s for s, (rc, _) in results.items() if rc == 0]
        losers = [s for s, (rc, _) in results.items() if rc != 0]
        assert len(winners) == 1 and len(losers) == 1, results
        rc, err = results[losers[0]]
        assert rc == 2 and "already holds a run" in err and "Traceback" not in err
        # everything in the folder is the winner's: results, saved config and overrides
        winner = f"seed={winners[0]}"
        assert winner in yaml.safe_load((folder / ".hydra" / "overrides.yaml").read_text())
        assert yaml.safe_load((folder / ".hydra" / "config.yaml").read_text())["seed"] == winners[0]
        assert json.loads((folder / "manifest.json").read_text())["seed"] == winners[0]
        assert json.loads((folder / "metrics.json").read_text())["seed"] == winners[0]
        assert (folder / ".slamlab-run").read_text() == str(procs[winners[0]].pid)


def test_a_refused_config_gives_the_folder_back(tmp_path, sim_cache):
    folder = tmp_path / "r"
    p = start(["resampler=nonesuch", f"hydra.run.dir={folder}"], tmp_path, sim_cache)
    assert p.wait(timeout=120) != 0
    assert not folder.exists()  # no claim left behind: the same command, fixed, can use it


def test_ctrl_c_keeps_the_partial_run_and_says_where(tmp_path, sim_cache):
    run = tmp_path / "run"
    p = start(["progress=log", "report=false", f"hydra.run.dir={run}"], tmp_path, sim_cache)
    while "SLAM  10%" not in p.stderr.readline():  # until the filter is running
        assert p.poll() is None
    p.send_signal(signal.SIGINT)
    rest = p.stderr.read()
    assert p.wait(timeout=120) == 130
    m = json.loads((run / "metrics.json").read_text())
    assert m["status"] == "interrupted" and m["partial"] is True
    k, n = m["interrupted_at_scan"], m["scans_total"]
    assert 0 < k < n == 3400
    assert rest.strip().splitlines()[-1] == f"interrupted at scan {k}/{n}; partial results in {run}"
    assert "Traceback" not in rest and rest.count("\n") <= 3  # a line or two of progress at most, then that
    # what was computed is kept: the trajectory and map up to that scan
    times, _ = artifacts.read_tum(run / "trajectory.tum")
    assert len(times) == k == m["scans"]
    assert artifacts.read_map(run).data.any()
    assert not list(run.glob(f"{artifacts.TMP_MARK}*"))


def test_a_killed_run_stays_incomplete(tmp_path, sim_cache):
    run = tmp_path / "run"
    p = start(["progress=log", "report=false", "texture=none", f"hydra.run.dir={run}"], tmp_path, sim_cache)
    while "SLAM  10%" not in p.stderr.readline():
        assert p.poll() is None
    p.send_signal(signal.SIGKILL)
    p.wait(timeout=60)
    loaded = load_run(run)  # what the reports show
    assert loaded.status == "incomplete" and not (run / "metrics.json").exists()


def test_a_sweep_with_a_failing_job_fails_after_its_report(tmp_path, sim_cache):
    sweep = tmp_path / "sweep"
    with_report = [a for a in QUICK if a != "report=false"]
    p = start(["-m", "particles=10,0", *with_report, f"hydra.sweep.dir={sweep}"], tmp_path, sim_cache)
    out, err = p.communicate(timeout=900)
    assert p.returncode == 1
    assert (sweep / "report.html").is_file()
    assert err.strip().splitlines()[-1] == (
        "1 of 2 runs failed: job 1 (particles=0): config 'particles': must be an integer >= 1, got 0")


def test_a_sweep_whose_jobs_all_finish_exits_0(tmp_path, sim_cache):
    sweep = tmp_path / "sweep"
    p = start(["-m", "seed=0,1", *QUICK, "steps.max_scans=100", f"hydra.sweep.dir={sweep}"], tmp_path, sim_cache)
    out, err = p.communicate(timeout=900)
    assert p.returncode == 0, err
    assert "runs failed" not in err


def test_each_sweep_job_reports_its_own_peak_memory(tmp_path, sim_cache):
    # job 0 holds a map of ~50x the cells of job 1; run in one process, one after the other
    sweep = tmp_path / "sweep"
    p = start(["-m", "map.resolution_m=0.007,0.05", *QUICK, "steps.max_scans=100", f"hydra.sweep.dir={sweep}"],
              tmp_path, sim_cache)
    _, err = p.communicate(timeout=900)
    assert p.returncode == 0, err
    big, small = (json.loads((sweep / job / "metrics.json").read_text()) for job in ("0", "1"))
    assert big["peak_memory_scope"] == small["peak_memory_scope"] == "run"
    # the process's lifetime peak would make job 1 report at least job 0's peak
    assert small["peak_memory_mb"] < big["peak_memory_mb"] - 150, (small["peak_memory_mb"], big["peak_memory_mb"])
