"""Sweeps through the parallel and cluster launchers (joblib, submitit, Ray on this machine and
on a running Ray cluster): every job finishes, the sweep report lists each run with the
numbers in its metrics.json."""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from slamlab.report.html import fmt_number

pytestmark = pytest.mark.slow


def run_sweep(launcher_args: list[str], tmp_path: Path, sim_cache: Path, **env_vars: str) -> subprocess.CompletedProcess:
    """A 2-job sweep (particles=4,8) on a short simulated sequence; checks its runs and report."""
    sweep = tmp_path / "sweep"
    env = {**os.environ, "SLAMLAB_CACHE_DIR": str(sim_cache), "MPLBACKEND": "Agg", **env_vars}
    cmd = [sys.executable, "-m", "slamlab.cli.app", "-m", *launcher_args, "particles=4,8",
           "dataset.duration_s=8", "dataset.rgbd=false", "texture=none", "progress=off",
           f"hydra.sweep.dir={sweep}"]
    proc = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    page = (sweep / "report.html").read_text()
    for job, particles in (("0", 4), ("1", 8)):
        m = json.loads((sweep / job / "metrics.json").read_text())
        assert m["status"] == "ok" and m["particles"] == particles
        assert fmt_number(m["trajectory"]["rmse_m"]) in page  # as the report writes it (4 significant digits)
    return proc


@pytest.mark.parametrize("launcher", ["joblib", "submitit_cpu", "ray"])
def test_parallel_sweep_writes_runs_and_report(launcher, tmp_path, sim_cache):
    args = [f"hydra/launcher={launcher}"] + (["hydra.launcher.n_jobs=2"] if launcher == "joblib" else [])
    proc = run_sweep(args, tmp_path, sim_cache)
    if launcher == "ray":  # the jobs ran as Ray tasks on a Ray instance started for the sweep
        assert "Started a local Ray instance" in proc.stderr and "(_run_job pid=" in proc.stderr


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_ray_sweep_joins_a_running_cluster(tmp_path, sim_cache):
    """`hydra.launcher.ray.init.address=HOST:PORT`: the sweep runs on a cluster started
    beforehand (`ray start --head`), which the test then stops."""
    port = _free_port()
    # a throwaway cluster on loopback: no auth token to share between the head and the sweep
    no_auth = {"RAY_AUTH_MODE": "disabled"}
    ray_tmp = Path(tempfile.mkdtemp(prefix="ray", dir="/tmp"))  # short: Ray's socket paths must fit 107 chars
    log = (ray_tmp / "start.log").open("w")
    head = subprocess.Popen([str(Path(sys.executable).parent / "ray"), "start", "--head", f"--port={port}",
                             "--num-cpus=2", "--include-dashboard=false", f"--temp-dir={ray_tmp}", "--block"],
                            stdout=log, stderr=subprocess.STDOUT, env={**os.environ, **no_auth})  # fmt: skip
    try:
        deadline = time.monotonic() + 120
        while "Ray runtime started" not in (ray_tmp / "start.log").read_text():
            assert head.poll() is None and time.monotonic() < deadline, (ray_tmp / "start.log").read_text()[-2000:]
            time.sleep(0.5)
        proc = run_sweep(["hydra/launcher=ray", f"hydra.launcher.ray.init.address=127.0.0.1:{port}"], tmp_path, sim_cache,
                         **no_auth)  # fmt: skip
        assert "Connecting to existing Ray cluster" in proc.stderr
        assert "Started a local Ray instance" not in proc.stderr
    finally:
        head.send_signal(signal.SIGTERM)  # --block: stopping it stops the cluster's processes
        try:
            head.wait(timeout=60)
        except subprocess.TimeoutExpired:
            head.kill()
        log.close()
        shutil.rmtree(ray_tmp, ignore_errors=True)
