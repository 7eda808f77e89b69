"""SLAM speed and accuracy on the benchmark logs and the default simulated sequence.

    .venv/bin/python benchmarks/bench_slam.py [--only intel,aces,sim] [--no-warm]

Composes the shipped Hydra configs in-process (`+experiment=intel|aces`, the plain default
config for the simulation), runs `run_slam` and prints one table. Numba kernels are
compiled (or loaded from the on-disk cache) by a short warm-up run first, so `wall s` is
the steady-state filter time (`--no-warm` includes compilation in the first row). Peak RSS
is the process's maximum so far (ru_maxrss), so later rows include earlier ones' peaks.
Timings depend on machine load: on a shared 2-core box they are pessimistic.
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path

import numpy as np
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate

from slamlab.paths import data_dir
from slamlab.assemble import build_components
from slamlab.slam.engine import run_slam

REPO = Path(__file__).resolve().parents[1]
HEADER = (
    "Anchors on this 2-core machine: OpenSLAM GMapping (C++, 30 particles, 5 cm): Intel 66 s, "
    "0.048 m / 1.9 deg; ACES 37 s, 0.060 m / 1.1 deg. Raw odometry: Intel 7.37 m, ACES 0.55 m."
)


def _compose(overrides: list[str]):
    with initialize_config_dir(config_dir=str(REPO / "conf"), version_base=None):
        return compose(config_name="config", overrides=overrides)


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _warm() -> None:
    """Compile/load every numba kernel on a tiny slice so timings exclude compilation."""
    d = data_dir()
    if d is None or not (d / "carmen" / "aces.clf.bz2").exists():
        return
    from slamlab.datasets.carmen import load_carmen

    seq = load_carmen(d / "carmen" / "aces.clf.bz2")
    for m in ("likelihood", "grid"):
        run_slam(seq, build_components(_compose(["+experiment=aces", f"matcher={m}", "steps.max_scans=300", "dataset.path=x"])))


def bench_carmen(name: str) -> dict | None:
    d = data_dir()
    log = None if d is None else d / "carmen" / f"{name}.clf.bz2"
    if log is None or not log.exists():
        print(f"# {name}: log not found (set SLAMLAB_DATA_DIR)", file=sys.stderr)
        return None
    from slamlab.eval.relations import relation_errors

    cfg = _compose([f"+experiment={name}", f"dataset.path={log}"])
    seq = instantiate(cfg.dataset)
    t0 = time.perf_counter()
    res = run_slam(seq, build_components(cfg))
    wall = time.perf_counter() - t0
    e = relation_errors(res.times, res.trajectory, seq.relations)
    ec = relation_errors(res.times, res.causal, seq.relations)
    return {
        "dataset": name, "particles": res.particles, "scans": len(res.times), "steps": res.extras["processed_steps"],
        "wall_s": wall, "scans_per_s": len(res.times) / wall, "realtime": (seq.times.max() - seq.times.min()) / wall,
        "accuracy": f"rel {e['trans_abs_mean_m']:.3f}+-{e['trans_abs_std_m']:.3f} m, {e['rot_abs_mean_deg']:.2f} deg"
                    f" (causal {ec['trans_abs_mean_m']:.3f} m)",
        "peak_mb": _peak_mb(),
    }


def bench_sim() -> dict | None:
    try:
        cfg = _compose([])
        seq = instantiate(cfg.dataset)
    except Exception as exc:  # the simulator is optional for this table
        print(f"# sim: unavailable ({exc})", file=sys.stderr)
        return None
    from slamlab.eval.trajectory import trajectory_errors

    t0 = time.perf_counter()
    res = run_slam(seq, build_components(cfg))
    wall = time.perf_counter() - t0
    acc = "no ground truth"
    if seq.ground_truth is not None:
        e = trajectory_errors(res.trajectory, seq.ground_truth.poses[: len(res.times)])
        ec = trajectory_errors(res.causal, seq.ground_truth.poses[: len(res.times)])
        eo = trajectory_errors(res.odometry, seq.ground_truth.poses[: len(res.times)])
        acc = f"RMSE {e['rmse_m']:.3f} m, {e['rot_rmse_deg']:.2f} deg (causal {ec['rmse_m']:.3f}, odom {eo['rmse_m']:.3f})"
    duration = float(res.times.max() - res.times.min())
    return {
        "dataset": "sim", "particles": res.particles, "scans": len(res.times), "steps": res.extras["processed_steps"],
        "wall_s": wall, "scans_per_s": len(res.times) / wall, "realtime": duration / wall, "accuracy": acc, "peak_mb": _peak_mb(),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default="intel,aces,sim")
    ap.add_argument("--no-warm", action="store_true")
    args = ap.parse_args()
    if not args.no_warm:
        _warm()
    rows = []
    for name in args.only.split(","):
        r = bench_sim() if name == "sim" else bench_carmen(name)
        if r:
            rows.append(r)
    print(HEADER)
    print(f"numba warm: {not args.no_warm}. wall s = run_slam only (data loading excluded).")
    print(f"| {'dataset':7} | {'N':>3} | {'scans':>6} | {'steps':>5} | {'wall s':>6} | {'scans/s':>7} | {'x real time':>11} | {'accuracy':<58} | {'peak MB':>7} |")
    print("|" + "---|" * 9)
    for r in rows:
        print(f"| {r['dataset']:7} | {r['particles']:>3} | {r['scans']:>6} | {r['steps']:>5} | {r['wall_s']:6.1f} | {r['scans_per_s']:7.0f} "
              f"| {r['realtime']:11.1f} | {r['accuracy']:<58} | {r['peak_mb']:7.0f} |")
    np.set_printoptions()


if __name__ == "__main__":
    main()
