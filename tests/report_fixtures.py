"""Fabricated run and sweep directories, written exactly per docs/RUN_DIRECTORY.md.

Why fabricate: the report code must be testable without running SLAM (fast, and before the
engine exists), and these fixtures cover cases real small sweeps rarely produce (a run that
failed with metrics, one that died leaving only a log, no ground truth, a texture).
The tests that use real `slamlab -m` sweeps live beside these and skip when the app is absent.
"""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import yaml

from slamlab.artifacts import write_tum

BASE_CONFIG: dict[str, Any] = {
    "dataset": {"name": "sim", "duration_s": 10.0, "seed": 0},
    "motion": {"name": "course", "sigma_xy_m": 0.02, "sigma_theta_rad": 0.01},
    "weighting": {"name": "logsumexp"},
    "resampler": {"name": "systematic", "threshold": 0.5},
    "matcher": {"name": "grid", "window_m": 0.2},
    "map": {"resolution_m": 0.1, "log_odds_occ": 0.9},
    "ground": {"name": "threshold"},
    "texture": {"enabled": False},
    "particles": 100,
    "seed": 0,
    "mode": "slam",
    "steps": {"every": 1, "max_scans": None},
    "report": True,
    "progress": "auto",
}


def _set_dotted(cfg: dict[str, Any], key: str, value: Any) -> None:
    node = cfg
    parts = key.split(".")
    for p in parts[:-1]:
        node = node.setdefault(p, {})
    node[parts[-1]] = value


def _room_map(res: float = 0.1) -> tuple[np.ndarray, tuple[float, float]]:
    """A 12 m x 8 m room with an inner wall, log-odds: walls +4, inside -2, outside unknown;
    the grid is larger than the room so cropping is exercised."""
    origin = (-5.0, -5.0)
    h, w = int(18 / res), int(22 / res)
    data = np.zeros((h, w), dtype=np.float32)

    def cell(x: float, y: float) -> tuple[int, int]:
        return int((y - origin[1]) / res), int((x - origin[0]) / res)

    r0, c0 = cell(-1.0, -1.0)
    r1, c1 = cell(11.0, 7.0)
    data[r0:r1, c0:c1] = -2.0
    data[r0:r0 + 2, c0:c1] = 4.0
    data[r1 - 2:r1, c0:c1] = 4.0
    data[r0:r1, c0:c0 + 2] = 4.0
    data[r0:r1, c1 - 2:c1] = 4.0
    ri, ci = cell(5.0, 3.5)
    data[r0:ri, ci:ci + 2] = 4.0
    return data, origin


def make_run_dir(
    run_dir: Path,
    *,
    overrides: list[str] | None = None,
    failure: str | None = None,
    groundtruth: bool = True,
    texture: bool = False,
    n_steps: int = 300,
    hydra_files: bool = True,
) -> Path:
    """Write one run directory. `failure`: None (ok run), "metrics" (metrics.json with
    status failed + error, partial artifacts) or "log" (killed: no metrics.json, the error
    only in slamlab.log). Values in `overrides` (`key=value`) are applied to the config.
    `hydra_files=False` leaves .hydra/ alone (when real Hydra already wrote it)."""
    overrides = list(overrides or [])
    cfg = copy.deepcopy(BASE_CONFIG)
    for o in overrides:
        k, _, v = o.partition("=")
        _set_dotted(cfg, k.lstrip("+~"), yaml.safe_load(v))
    particles = int(cfg["particles"])
    seed = int(cfg["seed"])
    run_dir.mkdir(parents=True, exist_ok=True)
    if hydra_files:
        hyd = run_dir / ".hydra"
        hyd.mkdir(exist_ok=True)
        (hyd / "config.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False))
        (hyd / "overrides.yaml").write_text(yaml.safe_dump(overrides))
        (hyd / "hydra.yaml").write_text(yaml.safe_dump({"hydra": {"overrides": {"task": overrides}}}))

    if failure == "log":
        (run_dir / "slamlab.log").write_text(
            "[10:00:00][slamlab][INFO] loading dataset sim\n"
            "[10:00:01][slamlab][INFO] step 10/300\n"
            "Traceback (most recent call last):\n  File \"engine.py\", line 1, in step\n"
            "MemoryError: Unable to allocate 8.00 GiB for the correlation grid\n"
        )
        return run_dir

    rng = np.random.default_rng(1000 * seed + particles)
    n = n_steps
    t = np.linspace(0.0, 30.0, n)
    s = np.linspace(0, 1, n)
    # A loop around the room: along the bottom, up, back along the top.
    gx = np.interp(s, [0, 0.3, 0.5, 0.8, 1.0], [0.5, 9.5, 9.5, 0.5, 0.5])
    gy = np.interp(s, [0, 0.3, 0.5, 0.8, 1.0], [0.5, 0.5, 5.5, 5.5, 0.5])
    gth = np.arctan2(np.gradient(gy), np.gradient(gx))
    gt = np.column_stack([gx, gy, gth])
    drift = np.cumsum(rng.normal(0.0, 0.02, size=(n, 2)), axis=0)
    odo = gt.copy()
    odo[:, :2] += drift + np.outer(s, [0.0, 0.8])
    noise = 0.5 / np.sqrt(particles)
    slam = gt.copy()
    slam[:, :2] += rng.normal(0.0, noise, size=(n, 2))
    write_tum(run_dir / "trajectory.tum", t, slam)
    write_tum(run_dir / "trajectory_causal.tum", t, slam)
    write_tum(run_dir / "odometry.tum", t, odo)
    if groundtruth:
        write_tum(run_dir / "groundtruth.tum", t, gt)
    data, origin = _room_map()
    np.savez_compressed(run_dir / "map_logodds.npz", data=data, resolution_m=np.float64(0.1),
                        origin_xy=np.array(origin))

    neff = np.empty(n)
    resampled = np.zeros(n, dtype=bool)
    v = float(particles)
    for i in range(n):
        v *= rng.uniform(0.8, 0.99)
        if v < 0.5 * particles:
            resampled[i] = True
            neff[i] = v
            v = float(particles)
        else:
            neff[i] = v
    steps = pd.DataFrame({
        "step": np.arange(n), "scan_index": np.arange(n) * 2, "t": t, "neff": neff,
        "resampled": resampled, "best_weight": rng.uniform(0.01, 0.2, n),
        "step_time_s": rng.uniform(0.002, 0.004, n) * particles / 50,
    })
    steps.to_csv(run_dir / "steps.csv", index=False)

    err = np.linalg.norm(slam[:, :2] - gt[:, :2], axis=1)
    oerr = np.linalg.norm(odo[:, :2] - gt[:, :2], axis=1)
    runtime = float(steps["step_time_s"].sum())
    metrics: dict[str, Any] = {
        "status": "ok",
        "dataset": "sim", "scans": 2 * n, "processed_steps": n, "particles": particles, "seed": seed,
        "runtime_s": round(runtime, 4), "total_runtime_s": round(runtime + 1.5, 4),
        # run alone: CPU time a little under wall time
        "cpu_time_s": round(0.95 * runtime, 4), "total_cpu_time_s": round(0.95 * runtime + 1.4, 4),
        "scans_per_s": round(2 * n / runtime, 3), "realtime_factor": round(30.0 / runtime, 3),
        "peak_memory_mb": round(200 + particles * 0.5, 1),
        "resample_count": int(resampled.sum()), "neff_mean": float(neff.mean()), "neff_min": float(neff.min()),
        "trajectory_fill": "odometry",
        "peak_memory_scope": "run",
        # the map-consistency verdict (slamlab.eval.consistency), as a run writes it
        "consistency": {"scans_scored": n, "hit_fraction_mean": 0.95, "hit_fraction_p10": 0.9,
                        "hit_fraction_worst_window": 0.85, "contradiction_share": round(0.02 + 0.1 / np.sqrt(particles), 4),
                        "see_through_share": 0.01, "in_free_share": 0.01,
                        "contradiction_worst_window": round(0.05 + 0.2 / np.sqrt(particles), 4),
                        "broken_threshold": 0.4, "window_scans": 25, "verdict": "consistent",
                        "verdict_text": "consistent: no stretch of 25 replayed scans contradicts the map in 40% of its beams"
                                        " or more", "broken_spans": []},
    }
    if groundtruth:
        metrics["trajectory"] = {
            "rmse_m": float(np.sqrt(np.mean(err**2))), "mean_m": float(err.mean()), "max_m": float(err.max()),
            "rot_rmse_deg": 0.5, "causal_rmse_m": float(np.sqrt(np.mean(err**2))) * 1.2,
            "causal_mean_m": float(err.mean()) * 1.2,
            "odometry_rmse_m": float(np.sqrt(np.mean(oerr**2))), "odometry_mean_m": float(oerr.mean()),
        }
        metrics["map"] = {"agreement": 0.9 + 0.0005 * particles, "occupied_precision": 0.8, "occupied_recall": 0.7}
    if texture:
        colour_error = float(8.0 + 40.0 / np.sqrt(particles) + rng.uniform(0.0, 1.0))
        metrics["texture"] = {"status": "ok", "colour_error": colour_error, "covered_area_m2": 40.0,
                              "odometry": {"status": "ok", "colour_error": colour_error + 6.0}}
    if failure == "metrics":
        metrics = {"status": "failed", "error": "DataError: sim.npz: record 17, field 'ranges': expected 360 beams, got 12",
                   "dataset": "sim", "particles": particles, "seed": seed}
        (run_dir / "slamlab.log").write_text("[10:00:00][slamlab][ERROR] sim.npz: record 17 ...\n")
    (run_dir / "metrics.json").write_text(json.dumps(metrics, indent=2))
    manifest = {
        "config": cfg, "package_version": "0.1.0", "data_fingerprint": "sha256:abc123", "seed": seed,
        "command": ["slamlab", *overrides], "platform": {"python": "3.11", "machine": "x86_64"},
    }
    (run_dir / "manifest.json").write_text(json.dumps(manifest, indent=2))
    if texture:
        from PIL import Image

        img = (rng.uniform(0, 255, size=(120, 160, 3))).astype(np.uint8)
        Image.fromarray(img).save(run_dir / "texture.png")
    (run_dir / "slamlab.log").touch()
    return run_dir


def make_sweep(
    sweep_dir: Path,
    jobs: list[list[str]],
    sweep_overrides: list[str],
    failures: dict[int, str] | None = None,
    **kwargs: Any,
) -> list[Path]:
    """A Hydra multirun layout: `sweep_dir/multirun.yaml` and one run dir per job, named by
    job number. `failures` maps a job number to a failure mode of make_run_dir."""
    failures = failures or {}
    sweep_dir.mkdir(parents=True, exist_ok=True)
    (sweep_dir / "multirun.yaml").write_text(yaml.safe_dump({
        "hydra": {"mode": "MULTIRUN", "sweep": {"dir": str(sweep_dir), "subdir": "${hydra.job.num}"},
                  "overrides": {"task": sweep_overrides}},
        **BASE_CONFIG,
    }, sort_keys=False))
    return [make_run_dir(sweep_dir / str(i), overrides=o, failure=failures.get(i), **kwargs) for i, o in enumerate(jobs)]


def particles_seed_grid(particles: list[int], seeds: list[int], extra: list[str] | None = None) -> list[list[str]]:
    """The job override lists of `-m particles=... seed=...` (Hydra order: last key fastest)."""
    extra = extra or []
    return [[f"particles={p}", f"seed={s}", *extra] for p in particles for s in seeds]
