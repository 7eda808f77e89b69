"""`slamlab-verify RUN_DIR`: re-run a finished run from its saved config and say whether the
trajectory and the metrics are identical (timing and memory figures excepted).

The re-run uses the run's own saved, fully composed config (`RUN_DIR/.hydra/config.yaml`),
not today's config files, so a frozen preset stays frozen. Exit status: 0 identical,
1 different (the first difference is printed), 2 the run folder cannot be verified.
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
from pathlib import Path

COMPARED_FILES = ("trajectory.tum", "trajectory_causal.tum", "odometry.tum")
# Metrics that measure the machine, not the algorithm.
VOLATILE = re.compile(r"(runtime|_per_s$|realtime|memory|(^|_)ms(_|$)|time_s$)")


def first_text_difference(a: Path, b: Path) -> str | None:
    """None if the files are byte-identical, else where they first differ."""
    if a.read_bytes() == b.read_bytes():
        return None
    la, lb = a.read_text().splitlines(), b.read_text().splitlines()
    for i, (x, y) in enumerate(zip(la, lb), start=1):
        if x != y:
            return f"{a.name} line {i}:\n  original: {x}\n  re-run:   {y}"
    return f"{a.name}: {len(la)} lines originally, {len(lb)} in the re-run"


def first_metric_difference(a: object, b: object, path: str = "") -> str | None:
    """Compare metrics recursively, skipping volatile (timing/memory) keys."""
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            if VOLATILE.search(k):
                continue
            key = f"{path}.{k}" if path else k
            if k not in a or k not in b:
                return f"metrics.json '{key}' present in only one run"
            diff = first_metric_difference(a[k], b[k], key)
            if diff:
                return diff
        return None
    if a != b:
        return f"metrics.json '{path}': original {a!r}, re-run {b!r}"
    return None


def first_steps_difference(a: Path, b: Path) -> str | None:
    """Compare the per-step tables, except the step wall times."""
    import pandas as pd

    if not a.exists():
        return None
    ta, tb = pd.read_csv(a, dtype=str), pd.read_csv(b, dtype=str)
    cols = [c for c in ta.columns if not VOLATILE.search(c)]
    if list(ta.columns) != list(tb.columns) or len(ta) != len(tb):
        return f"steps.csv: shape {ta.shape} originally, {tb.shape} in the re-run"
    for i, (ra, rb) in enumerate(zip(ta[cols].itertuples(index=False), tb[cols].itertuples(index=False))):
        if ra != rb:
            return f"steps.csv row {i}:\n  original: {tuple(ra)}\n  re-run:   {tuple(rb)}"
    return None


def compare_runs(original: Path, rerun: Path) -> str | None:
    """None when the re-run reproduces the original, else the first difference."""
    for name in COMPARED_FILES:
        if (original / name).exists():
            if not (rerun / name).exists():
                return f"{name} missing from the re-run"
            diff = first_text_difference(original / name, rerun / name)
            if diff:
                return diff
    diff = first_steps_difference(original / "steps.csv", rerun / "steps.csv")
    if diff:
        return diff
    ma = json.loads((original / "metrics.json").read_text())
    mb = json.loads((rerun / "metrics.json").read_text())
    return first_metric_difference(ma, mb)


def rerun(run_dir: Path, out_dir: Path) -> subprocess.CompletedProcess:
    """Run `slamlab` again from the saved composed config into `out_dir`."""
    manifest = json.loads((run_dir / "manifest.json").read_text())
    cmd = [
        sys.executable, "-m", "slamlab.cli.app",
        "--config-path", str((run_dir / ".hydra").resolve()), "--config-name", "config",
        f"hydra.run.dir={out_dir}", "report=false", "progress=off",
    ]
    cwd = manifest.get("cwd") if Path(manifest.get("cwd", "")).is_dir() else None
    return subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)


def main(argv: list[str] | None = None) -> int:
    """Console entry point."""
    ap = argparse.ArgumentParser(prog="slamlab-verify", description=__doc__.splitlines()[0])
    ap.add_argument("run_dir", type=Path, help="a finished run directory")
    ap.add_argument("--keep", type=Path, default=None, help="write the re-run here instead of a temporary folder")
    args = ap.parse_args(argv)
    run_dir: Path = args.run_dir
    for need in ("metrics.json", "manifest.json", ".hydra/config.yaml"):
        if not (run_dir / need).exists():
            print(f"slamlab-verify: {run_dir} is not a finished run ({need} missing)", file=sys.stderr)
            return 2
    if json.loads((run_dir / "metrics.json").read_text()).get("status") != "ok":
        print(f"slamlab-verify: {run_dir} did not finish successfully; nothing to compare", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory(prefix="slamlab-verify-") as tmp:
        out = (args.keep or Path(tmp) / "rerun").resolve()
        proc = rerun(run_dir, out)
        if proc.returncode != 0:
            print(f"slamlab-verify: the re-run failed:\n{proc.stderr[-2000:]}", file=sys.stderr)
            return 2
        diff = compare_runs(run_dir, out)
    if diff:
        print(f"DIFFERENT: {run_dir}\nfirst difference: {diff}")
        return 1
    print(f"IDENTICAL: {run_dir} (trajectories, per-step table and metrics, timing excepted)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
