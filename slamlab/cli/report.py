"""`slamlab-report DIR... [-o OUT]`: one comparison report from any runs and sweeps.

A DIR may be a run directory, a sweep directory (multirun/<date>/<time>/) or any folder
holding those (e.g. `multirun/` itself). Default output: reports/<timestamp>/report.html.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from datetime import datetime
from pathlib import Path

from slamlab.errors import SlamlabError


def _default_out_dir(base: Path = Path("reports")) -> Path:
    """reports/<YYYY-mm-dd_HH-MM-SS>, with a -N suffix so a report never replaces another."""
    stamp = datetime.now().strftime("%Y-%m-%d_%H-%M-%S")
    out = base / stamp
    n = 1
    while out.exists():
        out = base / f"{stamp}-{n}"
        n += 1
    return out


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="slamlab-report",
        description="Build a self-contained HTML report comparing slamlab runs. "
        "Each DIR is a run directory, a sweep directory, or a folder of them.",
    )
    p.add_argument("dirs", nargs="+", type=Path, metavar="DIR", help="run, sweep or folder of sweeps")
    p.add_argument("-o", "--out", type=Path, default=None,
                   help="output folder (report.html + runs.csv written inside) or a path ending in .html; "
                        "default: reports/<timestamp>/")
    p.add_argument("--title", default=None, help="page title (default: the sweep name or 'Comparison of N runs')")
    p.add_argument("--run-reports", action="store_true",
                   help="also write report.html in every run directory that lacks one")
    return p


def main(argv: list[str] | None = None) -> int:
    """Entry point of the `slamlab-report` console script; returns the exit code."""
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="slamlab-report: %(levelname)s: %(message)s")
    from slamlab.io.rundir import RUN_MARKERS, RunFile
    from slamlab.report.rundir import find_run_dirs
    from slamlab.report.sweep_report import build_sweep_report

    if args.out is None:
        out_dir, filename = _default_out_dir(), RunFile.REPORT
    elif args.out.suffix.lower() in (".html", ".htm"):
        out_dir, filename = args.out.parent, args.out.name
    else:
        out_dir, filename = args.out, RunFile.REPORT
    if filename == RunFile.REPORT and any((out_dir / m).exists() for m in RUN_MARKERS):
        # a run's own report.html lives there: a comparison page must not replace it
        print(f"slamlab-report: error: {out_dir} is a run directory; choose another -o", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    try:
        if args.run_reports:
            from slamlab.report.run_report import write_run_report

            for run in find_run_dirs(args.dirs):
                if not (run / RunFile.REPORT).is_file():
                    write_run_report(run)
        path = build_sweep_report(args.dirs, out_dir, args.title, filename=filename)
    except SlamlabError as exc:
        print(f"slamlab-report: error: {exc}", file=sys.stderr)
        return 2
    print(f"{path}  ({time.perf_counter() - t0:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
