"""How long report building takes for a 12-run sweep (target: sweep report < 10 s on 2 cores, issue 14).

    .venv/bin/python benchmarks/bench_report.py [SWEEP_DIR] [--steps N]

With SWEEP_DIR, times the reports of that real sweep (written to a temp folder, the sweep
is not modified); without it, fabricates a 12-run sweep (4 particle counts x 3 seeds, one
failed run) with N filter steps per run. Prints a table: phase, seconds, output size.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("sweep", nargs="?", type=Path)
    p.add_argument("--steps", type=int, default=3000, help="filter steps per fabricated run")
    args = p.parse_args(argv)

    from slamlab.report import build_sweep_report, find_run_dirs
    from slamlab.report.run_report import render_run_report
    from slamlab.report.rundir import load_run

    with tempfile.TemporaryDirectory(prefix="slamlab-bench-") as tmp:
        tmp_path = Path(tmp)
        if args.sweep is None:
            from report_fixtures import make_sweep, particles_seed_grid

            sweep = tmp_path / "multirun" / "bench"
            make_sweep(sweep, particles_seed_grid([25, 50, 100, 200], [0, 1, 2]),
                       ["particles=25,50,100,200", "seed=0,1,2"], failures={5: "metrics"},
                       n_steps=args.steps, texture=True)
            source = f"fabricated, {args.steps} steps/run"
        else:
            sweep = args.sweep
            source = str(sweep)
        runs = find_run_dirs([sweep])

        t0 = time.perf_counter()
        sizes = 0
        for r in runs:  # rendered in memory: never touch a real run's report.html
            sizes += len(render_run_report(load_run(r)).encode())
        t_runs = time.perf_counter() - t0

        t0 = time.perf_counter()
        out = build_sweep_report([sweep], tmp_path / "report")
        t_sweep = time.perf_counter() - t0
        size = out.stat().st_size

    print(f"sweep: {source}; {len(runs)} runs")
    print(f"{'phase':<34}{'seconds':>9}{'output':>12}")
    print(f"{'run reports (all ' + str(len(runs)) + ')':<34}{t_runs:>9.2f}{sizes / 1e6:>10.2f}MB")
    print(f"{'sweep report':<34}{t_sweep:>9.2f}{size / 1e6:>10.2f}MB")
    print(f"{'total':<34}{t_runs + t_sweep:>9.2f}")
    print("target: sweep report < 10 s:", "OK" if t_sweep < 10 else "TOO SLOW")
    return 0 if t_sweep < 10 else 1


if __name__ == "__main__":
    sys.exit(main())
