"""Is the grading check free of false alarms? One honest `slamlab +experiment=grading` run,
then `slamlab-verify --preset grading` on it N times (default 20): every re-run must say
IDENTICAL (issue 11: 1 of 11 said DIFFERENT when Open3D's RANSAC decided the plane detector).

    .venv/bin/python benchmarks/bench_verify_grading.py [--reruns 20] [--out DIR]

Prints one row per re-run (verdict, seconds, first difference if any) and the count of false
DIFFERENT results; exits 1 if there is any. About 30 s per re-run on the 2-core machine.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reruns", type=int, default=20)
    ap.add_argument("--out", type=Path, default=None, help="keep the run here (default: a temporary folder)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench-verify-") as tmp:
        run = (args.out or Path(tmp)) / "grading"
        t0 = time.perf_counter()
        made = subprocess.run([sys.executable, "-m", "slamlab.cli.app", "+experiment=grading", "progress=off",
                               f"hydra.run.dir={run}"], capture_output=True, text=True)
        if made.returncode != 0:
            print(made.stderr[-3000:], file=sys.stderr)
            return 2
        print(f"grading run: {time.perf_counter() - t0:.0f} s -> {run}")
        print(f"{'re-run':>6}  {'verdict':<10} {'s':>5}  first difference")
        false = 0
        for i in range(1, args.reruns + 1):
            t0 = time.perf_counter()
            v = subprocess.run([sys.executable, "-m", "slamlab.cli.verify", "--preset", "grading", str(run)],
                               capture_output=True, text=True)
            verdict = v.stdout.strip().splitlines()[-1].split(":")[0] if v.stdout.strip() else f"exit {v.returncode}"
            diff = next((ln for ln in v.stdout.splitlines() if ln.startswith("first difference")), "")
            false += v.returncode != 0
            print(f"{i:>6}  {verdict:<10} {time.perf_counter() - t0:5.0f}  {diff}", flush=True)
        print(f"{args.reruns} verify re-runs of the grading preset: {false} false DIFFERENT (or failed)")
    return 1 if false else 0


if __name__ == "__main__":
    sys.exit(main())
