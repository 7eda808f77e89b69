"""The loop-closure issue's table: `filter=course,rbpf,graph` side by side on every log the
project has, with `+experiment=lidar2d` (CARMEN logs) or `+experiment=sim_loops`.

    .venv/bin/python benchmarks/bench_graph.py [--only logs,probes,sim_loops,hospital,timing] [--filters course,rbpf,graph] [--steps 0.5,0.25] [--jitter -0.02,0,0.02]
                                              [--lidars sick,urg,utm,sick_half] [--jobs 2] [--out DIR] [--set KEY=VALUE ...]

- logs: Intel and ACES at the preset's steps (0.5 m / 0.5 rad) and at half of them (`--steps`: any
  list, e.g. 0.15,0.25,0.35,0.5,0.75,1.0 for robustness to the step a user picks); mean
  relation error of the smoothed and of the causal (online) path (budget of the graph issue:
  Intel <= 0.022 m, ACES <= 0.037 m, both, the worst of seeds 0-4 where anything is random:
  course and rbpf run seeds 0-4, graph has no randomness and runs once per step). `--jitter
  -0.02,0,0.02` runs every step also 2 cm / 0.02 rad finer and coarser: other scans become steps,
  the graph's nearest thing to another seed (its worst over those is its robustness).
- probes: the FR079-like corridor probe (benchmarks/sim_carmen.py: the `loops` building at 2x
  and 3x, worlds 0-3; wheel odometry drifting tens of metres; written once into OUT/probes), at
  each of `--steps`: relation error, smoothed and causal, and of the loop relations alone.
  `--lidars` adds other lidars at 2x (`sim_carmen.LIDARS`: urg, utm, sick_half): the whole
  robustness matrix, 40 runs at two steps (~25 min on 2 cores), is
  `--only probes --filters graph --lidars sick,urg,utm,sick_half`. `--people N` has N people walk
  every probe's corridors (moving obstacles the map must not keep). `--layout campus` drives the same
  figure-eight outdoors (sim_carmen --layout campus: streets between buildings, trees and cars).
- sim_loops: `+experiment=sim_loops` at world_scale 1.5 and 2.0, dataset seeds 0-4
  (`texture=none report=false`): ATE RMSE unaligned and aligned, smoothed and causal (budget:
  worst <= 0.10 m unaligned, <= 0.05 m aligned).
- hospital: the Freiburg hospital log (no relations), one whole process with its report: wall,
  CPU, peak memory and the map's consistency (hit_fraction_p10 and the verdict).
- timing: one whole `slamlab +experiment=lidar2d` process per filter on Intel, with its report,
  alone: wall, CPU, peak memory (budget of the graph issue: <= 4 s, <= 250 MB).
In both, `peak_mb` is the whole process's (the kernel's ru_maxrss, report included) and
`run_peak_mb` the run's own up to its metrics (metrics.json `peak_memory_mb`, before the report).
Runs go `--jobs` at a time with one numba thread each (results do not depend on the thread
count), except timing and hospital, which run alone with the machine's threads.
"""

from __future__ import annotations

import argparse
import importlib.util
import tempfile
from pathlib import Path

import pandas as pd

from slamlab.paths import data_dir

_here = Path(__file__).resolve().parent
_spec = importlib.util.spec_from_file_location("bench_filters", _here / "bench_filters.py")
bench_filters = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench_filters)
_spec = importlib.util.spec_from_file_location("sim_carmen", _here / "sim_carmen.py")
sim_carmen = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(sim_carmen)

BUDGET = {"intel": 0.022, "aces": 0.037}  # the graph issue's relation-error budget (m), smoothed and causal
FILTERS = ("course", "rbpf", "graph")
PRESET_STEP = 0.5


def _seeds(flt: str) -> range:
    return range(1) if flt == "graph" else range(5)


def _rel(r: dict) -> dict:
    rel = r.get("relations", {})
    causal = rel.get("causal", {})
    nan = float("nan")
    return {"smoothed_m": rel.get("trans_abs_mean_m", nan), "causal_m": causal.get("trans_abs_mean_m", nan),
            "smoothed_loop_m": rel.get("loop", {}).get("trans_abs_mean_m", nan), "causal_loop_m": causal.get("loop", {}).get("trans_abs_mean_m", nan)}


def _common(r: dict) -> dict:
    g = r.get("graph") or {}
    return {"filter_s": r.get("runtime_s", float("nan")), "closures": g.get("accepted"), "status": r.get("status", "?")}


def logs(out: Path, n_jobs: int, filters: tuple[str, ...], steps: tuple[float, ...], jitters: tuple[float, ...] = (0.0,)) -> None:
    d = data_dir()
    jobs = []
    for log in BUDGET:
        for step in steps:
            for flt in filters:
                for seed in _seeds(flt):
                    for jit in jitters:  # the step thresholds moved a little: a deterministic filter's stand-in for seeds
                        at = round(step + jit, 6)
                        args = ["+experiment=lidar2d", f"filter={flt}", f"dataset.path={d / 'carmen' / (log + '.clf.bz2')}", f"seed={seed}",
                                f"steps.min_distance_m={at}", f"steps.min_angle_rad={at}"]
                        jobs.append(({"log": log, "step": step, "filter": flt, "seed": seed, "jitter": jit}, args))
    rows = [{**r["job"], **_rel(r), **_common(r), "broken": r.get("consistency", {}).get("verdict") == "likely broken"}
            for r in bench_filters._many(jobs, out / "logs", n_jobs)]
    df = pd.DataFrame(rows)
    g = df.groupby(["log", "step", "filter"]).agg(worst_smoothed_m=("smoothed_m", "max"), worst_causal_m=("causal_m", "max"),
                                                  mean_smoothed_m=("smoothed_m", "mean"), mean_causal_m=("causal_m", "mean"),
                                                  worst_loop_m=("smoothed_loop_m", "max"), filter_s=("filter_s", "mean"),
                                                  runs=("seed", "count"), flagged=("broken", "sum")).reset_index()
    g["budget_m"] = g["log"].map(BUDGET)
    g["pass"] = (g["worst_smoothed_m"] <= g["budget_m"]) & (g["worst_causal_m"] <= g["budget_m"])
    print("\n## Intel and ACES: relation error (m), worst and mean over the seeds (graph: nothing random, one run per step) "
          f"and step jitters {list(jitters)}; flagged: runs whose map-consistency verdict is `likely broken`")
    print(g.to_string(index=False, float_format=lambda v: f"{v:.4f}"))


def probes(out: Path, n_jobs: int, filters: tuple[str, ...], steps: tuple[float, ...], lidars: tuple[str, ...] = ("sick",),
           people: int = 0, defect: str = "", layout: str = "loops") -> None:
    folder = out / "probes"
    clfs = []
    for lidar in lidars:
        for scale in (2.0, 3.0) if lidar == "sick" else (2.0,):
            for world in range(4):
                stem = sim_carmen.log_stem(scale, world, lidar, people, defect, layout)
                clf = folder / f"{stem}.clf"
                if not clf.is_file():
                    sim_carmen.write_log(folder, scale, world, 0, 300, sim_carmen.ODOM["yaw_bias_deg_per_m"], lidar, people, defect, layout)
                clfs.append((lidar, scale, world, clf))
    jobs = [({"layout": layout, "lidar": lidar, "people": people, "defect": defect or "-", "scale": s, "step": st, "world": w, "filter": flt},
             ["+experiment=lidar2d", f"filter={flt}", f"dataset.path={clf}", f"steps.min_distance_m={st}", f"steps.min_angle_rad={st}"])
            for st in steps for lidar, s, w, clf in clfs for flt in filters]
    rows = [{**r["job"], **_rel(r), **_common(r)} for r in bench_filters._many(jobs, out / "probe-runs", n_jobs)]
    _runs_and_worst(pd.DataFrame(rows), f"{layout} probe (sim_carmen): relation error per run (m)", f"{layout} probe: over the four worlds", 4,
                    ["layout", "lidar", "people", "defect", "scale", "step", "filter"], mean_smoothed_m=("smoothed_m", "mean"), worst_smoothed_m=("smoothed_m", "max"),
                    mean_causal_m=("causal_m", "mean"), worst_causal_m=("causal_m", "max"), worst_loop_m=("smoothed_loop_m", "max"))


def _runs_and_worst(df: pd.DataFrame, runs_title: str, worst_title: str, digits: int, by: list[str] | None = None,
                    **aggregates: tuple[str, str]) -> None:
    """Print every run, then the runs grouped `by` (scale and filter unless said; `aggregates`
    as pandas' named aggregation)."""
    print(f"\n## {runs_title}")
    print(df.to_string(index=False, float_format=lambda v: f"{v:.{digits}f}"))
    g = df.groupby(by or ["scale", "filter"]).agg(**aggregates).reset_index()
    print(f"\n## {worst_title}")
    print(g.to_string(index=False, float_format=lambda v: f"{v:.{digits}f}"))


def sim_loops(out: Path, n_jobs: int, filters: tuple[str, ...]) -> None:
    jobs = [({"scale": scale, "seed": seed, "filter": flt},
             ["+experiment=sim_loops", f"filter={flt}", f"dataset.world_scale={scale}", f"dataset.seed={seed}", "texture=none"])
            for scale in (1.5, 2.0) for seed in range(5) for flt in filters]
    rows = []
    for r in bench_filters._many(jobs, out / "sim_loops", n_jobs):
        t = r.get("trajectory", {})
        nan = float("nan")
        lt = r.get("loop_truth") or {}
        rows.append({**r["job"], "ate_m": t.get("rmse_m", nan), "aligned_m": t.get("aligned_rmse_m", nan),
                     "causal_m": t.get("causal_rmse_m", nan), **_common(r), "wrong": lt.get("wrong", nan)})
    _runs_and_worst(pd.DataFrame(rows), "sim_loops: ATE RMSE per run (m)",
                    "sim_loops: worst of dataset seeds 0-4 (budget: <= 0.10 m unaligned, <= 0.05 m aligned)", 3,
                    worst_ate_m=("ate_m", "max"), worst_aligned_m=("aligned_m", "max"), mean_ate_m=("ate_m", "mean"),
                    worst_causal_m=("causal_m", "max"), filter_s=("filter_s", "mean"), wrong_closures=("wrong", "sum"))


def hospital(out: Path, filters: tuple[str, ...]) -> None:
    d = data_dir()
    rows = []
    for flt in filters:
        m = bench_filters.slamlab(["+experiment=lidar2d", f"filter={flt}", f"dataset.path={d / 'carmen' / 'fr-clinic_robotlaser.clf.bz2'}",
                                   "report=true"], out / f"hospital-{flt}")
        c = m.get("consistency", {})
        rows.append({"filter": flt, "wall_s": m.get("wall_s"), "cpu_s": m.get("cpu_s"), "peak_mb": m.get("whole_peak_mb"),
                     "run_peak_mb": m.get("peak_memory_mb"),
                     "hit_fraction_p10": c.get("hit_fraction_p10"), "verdict": c.get("verdict"),
                     "worst_window": c.get("contradiction_worst_window"), **_common(m)})
    print("\n## hospital (fr-clinic, 6,917 scans): graph budget <= 20 s, <= 400 MB; consistency p10 above the RBPF's")
    print(pd.DataFrame(rows).to_string(index=False, float_format=lambda v: f"{v:.3f}"))
    maps = [(flt, out / f"hospital-{flt}" / "map.png") for flt in filters]
    if all(path.is_file() for _, path in maps):
        print(f"the maps side by side: {_side_by_side(maps, out / 'hospital-maps.png')}")


def _side_by_side(maps: list[tuple[str, Path]], target: Path) -> Path:
    """The runs' map images (name, map.png) in one figure, one panel each, written to `target`."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(maps), figsize=(9 * len(maps), 6), squeeze=False)
    for ax, (name, path) in zip(axes[0], maps):
        ax.imshow(plt.imread(path), cmap="gray")
        ax.set_title(f"filter={name}")
        ax.set_axis_off()
    fig.tight_layout()
    fig.savefig(target, dpi=150)
    plt.close(fig)
    return target


def timing(out: Path, filters: tuple[str, ...]) -> None:
    d = data_dir()
    rows = []
    for flt in filters:
        m = bench_filters.slamlab(["+experiment=lidar2d", f"filter={flt}", f"dataset.path={d / 'carmen' / 'intel.clf.bz2'}", "report=true"],
                                  out / f"timing-{flt}")
        rows.append({"filter": flt, "wall_s": m.get("wall_s"), "cpu_s": m.get("cpu_s"), "filter_s": m.get("runtime_s"),
                     "peak_mb": m.get("whole_peak_mb"), "run_peak_mb": m.get("peak_memory_mb"), **_common(m)})
    print("\n## Intel, one whole process with its report, alone (graph budget <= 4 s, <= 250 MB; GMapping here 42 s CPU, 129 MB)")
    print(pd.DataFrame(rows).to_string(index=False, float_format=lambda v: f"{v:.3f}"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default="logs,probes,sim_loops,hospital,timing")
    ap.add_argument("--filters", default=",".join(FILTERS))
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", type=Path, default=None, help="keep the run folders (and the probe logs) here")
    ap.add_argument("--steps", default=f"{PRESET_STEP},{PRESET_STEP / 2}",
                    help="logs and probes: step thresholds (m and rad), comma list; the budget's are the preset's and half of them, "
                         "robustness: 0.15,0.25,0.35,0.5,0.75,1.0")
    ap.add_argument("--jitter", default="0", help="logs: offsets (m and rad) added to each step, comma list, each a run of its own "
                    "counted in the step's worst and mean: e.g. -0.02,0,0.02 (the graph has no seed; which scans become steps is its chance)")
    ap.add_argument("--lidars", default="sick", help="probes: the lidars (sim_carmen.LIDARS); the SICK at 2x and 3x, the others at 2x")
    ap.add_argument("--people", type=int, default=0, help="probes: people walking the corridors of every probe log (sim_carmen --people)")
    ap.add_argument("--defect", choices=sorted(sim_carmen.DEFECTS), default="", help="probes: every probe log with this defect (sim_carmen --defect)")
    ap.add_argument("--layout", choices=sim_carmen.LAYOUTS, default="loops", help="probes: the `loops` building or the outdoor `campus` (sim_carmen --layout)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a config override added to every run")
    args = ap.parse_args()
    if args.people < 0:
        ap.error(f"--people must be 0 or more, got {args.people}")
    bench_filters.EXTRA_OVERRIDES.extend(args.set)
    filters = tuple(args.filters.split(","))
    parts = args.only.split(",")
    if data_dir() is None and any(p in parts for p in ("logs", "hospital", "timing")):
        raise SystemExit("shared data not found: set SLAMLAB_DATA_DIR")
    with tempfile.TemporaryDirectory(prefix="slamlab-bench-graph-") as tmp:
        out = args.out or Path(tmp)
        if "timing" in parts:
            timing(out, filters)
        if "hospital" in parts:
            hospital(out, filters)
        if "logs" in parts:
            logs(out, args.jobs, filters, tuple(float(v) for v in args.steps.split(",")), tuple(float(v) for v in args.jitter.split(",")))
        if "probes" in parts:
            probes(out, args.jobs, filters, tuple(float(v) for v in args.steps.split(",")), tuple(args.lidars.split(",")), args.people, args.defect,
                   args.layout)
        if "sim_loops" in parts:
            sim_loops(out, args.jobs, filters)


if __name__ == "__main__":
    main()
