"""Reports a person opens from disk: `report.html` per run and comparison reports over runs.

Public API: `write_run_report(run_dir) -> Path` and
`build_sweep_report(dirs, out_dir, title=None) -> Path`; `load_run` / `find_run_dirs` read
run directories. Imported lazily so that `slamlab.report.callback` (loaded by Hydra at
startup) does not pull in matplotlib and pandas.
"""

from __future__ import annotations

from typing import Any

__all__ = ["write_run_report", "build_sweep_report", "load_run", "find_run_dirs"]


def __getattr__(name: str) -> Any:
    if name == "write_run_report":
        from slamlab.report.run_report import write_run_report

        return write_run_report
    if name == "build_sweep_report":
        from slamlab.report.sweep_report import build_sweep_report

        return build_sweep_report
    if name in ("load_run", "find_run_dirs"):
        from slamlab.report import rundir

        return getattr(rundir, name)
    raise AttributeError(f"module 'slamlab.report' has no attribute {name!r}")
