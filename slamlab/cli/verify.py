"""`slamlab-verify RUN_DIR`: re-run a finished run from its saved config and say whether every
result file is identical (maps, trajectories, steps table, metrics, texture images, point
clouds; timing and memory figures excepted).

The re-run uses the run's own saved, fully composed config (`RUN_DIR/.hydra/config.yaml`),
not today's config files, so a frozen preset stays frozen. It always prints which preset and
which overrides the run was made with; `--preset NAME` also requires that the run is a
faithful `+experiment=NAME` run (only data and output paths changed) and fails at once if not.
Exit status: 0 identical, 1 different or not the required preset (one line says why),
2 the run folder cannot be verified.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

from slamlab.io.run_metrics import STATUS_OK
from slamlab.io.rundir import RunDirectory, RunFile
from slamlab.provenance import preset_violation, read_origin
from slamlab.run_compare import compare_runs


def rerun(run_dir: Path, out_dir: Path) -> subprocess.CompletedProcess:
    """Run `slamlab` again from the saved composed config into `out_dir`.

    The re-run's progress and log lines go to this process's stderr, as a run's do; its
    errors are captured so they can be shown after the verdict."""
    manifest = RunDirectory(run_dir).read_manifest() or {}
    cmd = [
        sys.executable, "-m", "slamlab.cli.app",
        "--config-path", str((run_dir / RunFile.HYDRA_DIR).resolve()), "--config-name", "config",
        # slamlab's own config folder for its log format (the saved config has no defaults list)
        "hydra.searchpath=[pkg://slamlab.conf]", "hydra/job_logging=slamlab",
        f"hydra.run.dir={out_dir}", "report=false", "progress=auto",
    ]
    cwd = manifest.get("cwd") if Path(manifest.get("cwd", "")).is_dir() else None
    try:
        out = sys.stderr.fileno()  # stdout stays for the verdict
    except (AttributeError, OSError, ValueError):  # stderr replaced by an object without a file
        out = None
    return subprocess.run(cmd, cwd=cwd, stdout=out, text=True)


def main(argv: list[str] | None = None) -> int:
    """Console entry point."""
    ap = argparse.ArgumentParser(prog="slamlab-verify", description=__doc__.splitlines()[0])
    ap.add_argument("run_dir", type=Path, help="a finished run directory")
    ap.add_argument("--preset", default=None, metavar="NAME",
                    help="require a faithful `+experiment=NAME` run (only data and output paths changed)")
    ap.add_argument("--keep", type=Path, default=None, help="write the re-run here instead of a temporary folder")
    args = ap.parse_args(argv)
    run_dir: Path = args.run_dir
    for need in (RunFile.METRICS, RunFile.MANIFEST, RunFile.HYDRA_CONFIG):
        if not (run_dir / need).exists():
            print(f"slamlab-verify: {run_dir} is not a finished run ({need} missing)", file=sys.stderr)
            return 2
    metrics = RunDirectory(run_dir).read_metrics()
    if metrics is None or metrics.status != STATUS_OK:
        print(f"slamlab-verify: {run_dir} did not finish successfully; nothing to compare", file=sys.stderr)
        return 2
    print(f"run made with: {read_origin(run_dir).describe()}", flush=True)
    if args.preset:
        why = preset_violation(run_dir, args.preset)
        if why:
            print(f"NOT PRESET {args.preset}: {run_dir}: {why}")
            return 1
    with tempfile.TemporaryDirectory(prefix="slamlab-verify-") as tmp:
        out = (args.keep or Path(tmp) / "rerun").resolve()
        print(f"re-running {run_dir} into {out} ...", file=sys.stderr, flush=True)
        proc = rerun(run_dir, out)
        if proc.returncode != 0:
            print(f"slamlab-verify: the re-run failed (exit {proc.returncode}); its messages are above", file=sys.stderr)
            return 2
        diff = compare_runs(run_dir, out)
    if diff:
        print(f"DIFFERENT: {run_dir}\nfirst difference: {diff}")
        return 1
    what = f"the {args.preset} preset, " if args.preset else ""
    print(f"IDENTICAL: {run_dir} ({what}every result file; timing and memory figures excepted)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
