"""The speed issue's budgets, as a table: whole `slamlab` processes, each run alone.

    .venv/bin/python benchmarks/bench_speed.py [--only intel,aces,sim,one_scan] [--repeat 3] [--set KEY=VALUE] [--out DIR]

Rows (median of `--repeat` runs; numba kernels come from the on-disk cache after a warm-up):
- intel / aces: `+experiment=lidar2d` on the benchmark log. Budgets: Intel <= 8 s wall and
  <= 250 MB peak, ACES <= 5 s wall (GMapping on this machine: Intel 57 s, 129 MB).
- sim: the default run (`slamlab`, simulated THOR sequence cached, SLAM + texture + report).
  Budgets: filter >= 10x real time, whole process <= 15 s.
- one_scan: `+experiment=lidar2d` on Intel stopped after its first scan: the fixed cost of a
  process (imports, reading the log, kernels, artifacts, report). Budget: <= 1.5 s CPU.
`filter s` is the filter's own wall time (metrics.json's `runtime_s`), the part a matcher change moves;
`--set` adds a config override to every run (e.g. `matcher.refine=gauss_newton` against the preset).
`threads` is numba's threading layer and thread count as the run's manifest.json records them (`tbb x2`:
TBB, two threads; `NUMBA_THREADING_LAYER=omp` in the environment measures OpenMP instead);
`map reads` is metrics.json's `matcher_map_reads` (the cells the matcher's kernels read);
`limit s` is that at 1 ns a read: the least time those reads take on one core (the physical
limit beside each time). CPU is user + system of the process and its threads; peak is the process's peak
resident memory as metrics.json reports it.
This machine's speed drifts from hour to hour (other tenants share its cores), so the table ends
with a reference taken before and after the rows: the seconds a fresh interpreter takes for
`sum(range(10**8))` (median of 3; about 0.9 s when the machine is quiet). Compare tables of
different hours only together with it.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd

from slamlab.paths import data_dir

NS_PER_READ = 1.0


def _log(name: str) -> str:
    d = data_dir()
    if d is None:
        raise SystemExit("shared data not found: set SLAMLAB_DATA_DIR")
    return f"dataset.path={d / 'carmen' / (name + '.clf.bz2')}"


ROWS = {
    "intel": (lambda: ["+experiment=lidar2d", _log("intel"), "report=false"], {"wall_s": 8.0, "peak_mb": 250.0}),
    "aces": (lambda: ["+experiment=lidar2d", _log("aces"), "report=false"], {"wall_s": 5.0}),
    "sim": (lambda: [], {"wall_s": 15.0, "x_realtime": 10.0}),
    "one_scan": (lambda: ["+experiment=lidar2d", _log("intel"), "steps.max_scans=1"], {"cpu_s": 1.5}),
}


def one_run(args: list[str], run_dir: Path) -> dict:
    """One `slamlab` process: wall and CPU seconds, and its metrics."""
    cmd = [sys.executable, "-m", "slamlab.cli.app", *args, f"hydra.run.dir={run_dir}", "progress=off"]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=dict(os.environ))
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{proc.stderr[-2000:]}")
    m = json.loads((run_dir / "metrics.json").read_text())
    threads = json.loads((run_dir / "manifest.json").read_text())["platform"].get("numba_threads") or {}
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"wall_s": wall, "cpu_s": cpu, "peak_mb": m.get("peak_memory_mb", float("nan")),
            "x_realtime": m.get("realtime_factor") or float("nan"), "map_reads": m.get("matcher_map_reads", 0),
            "filter_s": m.get("runtime_s", float("nan")),
            "threads": f"{threads['layer']} x{threads['threads']}" if threads else "none"}


def machine_seconds(repeat: int = 3) -> float:
    """Wall seconds of `sum(range(10**8))` in a fresh interpreter, median of `repeat`: the
    machine's speed at the time, pure Python on one core (about 0.9 s when it is quiet)."""
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", "sum(range(10**8))"], check=True)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default=",".join(ROWS))
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--out", type=Path, default=None, help="keep the run folders here")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a config override added to every run (repeatable), e.g. --set matcher.refine=gauss_newton")
    a = ap.parse_args()
    rows = []
    speed_before = machine_seconds()
    with tempfile.TemporaryDirectory(prefix="slamlab-speed-") as tmp:
        out = a.out or Path(tmp)
        for name in a.only.split(","):
            make_args, budget = ROWS[name]
            one_run(make_args() + a.set + ["steps.max_scans=1", "report=false"], out / f"{name}_warm")  # kernels, caches
            runs = [one_run(make_args() + a.set, out / f"{name}_{k}") for k in range(a.repeat)]
            med = {k: statistics.median(r[k] for r in runs) for k in runs[0] if k != "threads"}
            rows.append({
                "run": name,
                "wall s": round(med["wall_s"], 2),
                "cpu s": round(med["cpu_s"], 2),
                "filter s": round(med["filter_s"], 2),
                "peak MB": round(med["peak_mb"]),
                "x realtime": round(med["x_realtime"], 1),
                "threads": runs[-1]["threads"],
                "map reads": f"{med['map_reads']:.3g}",
                "limit s": round(med["map_reads"] * NS_PER_READ * 1e-9, 2),
                "budget": ", ".join(f"{k.replace('_', ' ')} {'>=' if k == 'x_realtime' else '<='} {v:g}" for k, v in budget.items()),
                "met": all((med[k] >= v) if k == "x_realtime" else (med[k] <= v) for k, v in budget.items()),
            })
    print(pd.DataFrame(rows).to_string(index=False))
    print(f"machine speed: sum(range(10**8)) took {speed_before:.2f} s before the rows, {machine_seconds():.2f} s after "
          "(median of 3; about 0.9 s when the machine is quiet)")


if __name__ == "__main__":
    main()
