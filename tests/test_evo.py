"""slamlab's TUM files are evo's: `evo_ape tum groundtruth.tum trajectory.tum` on a simulated
run gives the RMSE (and mean, max, rotation RMSE) that metrics.json reports."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from hydra import compose, initialize_config_module

from slamlab.pipeline import run_pipeline

pytestmark = pytest.mark.slow  # a full pipeline run checked with evo

SHORT = ["dataset.duration_s=12", "particles=10", "dataset.rgbd=false", "texture=none", "report=false"]


@pytest.fixture(scope="module")
def sim_run(sim_cache, tmp_path_factory) -> Path:
    run_dir = tmp_path_factory.mktemp("evo") / "run"
    overrides = [*SHORT, f"dataset.cache_dir={sim_cache}"]
    with initialize_config_module(config_module="slamlab.conf", version_base="1.3"):
        cfg = compose(config_name="config", overrides=overrides)
    run_pipeline(cfg, run_dir, overrides=overrides, progress="off")
    return run_dir


def evo_ape(run: Path, estimate: str, *args: str) -> dict[str, float]:
    """evo's APE statistics (rmse, mean, max, ...) of `estimate` against groundtruth.tum, at
    full precision from its results file (the printout has 6 digits)."""
    exe = Path(sys.executable).parent / "evo_ape"
    results = run / f"ape_{estimate}_{len(args)}.zip"
    proc = subprocess.run([str(exe), "tum", "groundtruth.tum", estimate, *args, "--save_results", str(results),
                           "--no_warnings"], cwd=run, capture_output=True, text=True, timeout=300)  # fmt: skip
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    printed = dict(re.findall(r"^\s*(rmse)\s+([-+0-9.eE]+)\s*$", proc.stdout, re.M))
    with zipfile.ZipFile(results) as z:
        stats = json.loads(z.read("stats.json"))
    assert float(printed["rmse"]) == pytest.approx(stats["rmse"], abs=1e-6)  # what a user reads
    return stats


def test_evo_ape_equals_the_metrics(sim_run):
    m = json.loads((sim_run / "metrics.json").read_text())["trajectory"]
    ape = evo_ape(sim_run, "trajectory.tum")  # translation part, no alignment: as slamlab scores
    assert ape["rmse"] == pytest.approx(m["rmse_m"], rel=1e-6, abs=1e-9)
    assert ape["mean"] == pytest.approx(m["mean_m"], rel=1e-6, abs=1e-9)
    assert ape["max"] == pytest.approx(m["max_m"], rel=1e-6, abs=1e-9)
    rot = evo_ape(sim_run, "trajectory.tum", "--pose_relation", "angle_deg")
    assert rot["rmse"] == pytest.approx(m["rot_rmse_deg"], rel=1e-5, abs=1e-7)
    odom = evo_ape(sim_run, "odometry.tum")
    assert odom["rmse"] == pytest.approx(m["odometry_rmse_m"], rel=1e-6, abs=1e-9)
    assert odom["rmse"] > ape["rmse"]  # the filter corrected the drift: the numbers are not alike by chance
