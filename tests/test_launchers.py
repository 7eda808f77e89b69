"""Sweeps through the parallel and cluster launchers: every job finishes, the sweep report
lists each run with the numbers in its metrics.json."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow


@pytest.mark.parametrize("launcher", ["joblib", "submitit_cpu"])
def test_parallel_sweep_writes_runs_and_report(launcher, tmp_path, sim_cache):
    sweep = tmp_path / "sweep"
    env = {**os.environ, "SLAMLAB_CACHE_DIR": str(sim_cache), "MPLBACKEND": "Agg"}
    cmd = [sys.executable, "-m", "slamlab.cli.app", "-m", f"hydra/launcher={launcher}", "particles=4,8",
           "dataset.duration_s=8", "dataset.rgbd=false", "texture=none", "progress=off",
           f"hydra.sweep.dir={sweep}"]
    if launcher == "joblib":
        cmd.append("hydra.launcher.n_jobs=2")
    proc = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    page = (sweep / "report.html").read_text()
    for job, particles in (("0", 4), ("1", 8)):
        m = json.loads((sweep / job / "metrics.json").read_text())
        assert m["status"] == "ok" and m["particles"] == particles
        assert f"{m['trajectory']['rmse_m']:.3f}" in page
