"""Hydra callback: write the comparison report into the sweep directory after `slamlab -m`.

Enable it in the app's config (conf/config.yaml):

    hydra:
      callbacks:
        sweep_report:
          _target_: slamlab.report.callback.SweepReportCallback

A report is a convenience, never a reason to fail a sweep whose runs all finished: every
error here is logged, none is raised.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig

from slamlab.io.rundir import SweepFile

log = logging.getLogger(__name__)

# Failed runs of the last sweep this process ran, one line each (`job 1 (particles=0): error`):
# the CLI reads it after Hydra returns, to end with "1 of 2 runs failed: ..." and exit non-zero.
LAST_SWEEP: dict[str, Any] = {"runs": 0, "failed": []}


def failed_runs(sweep_dir: Path) -> tuple[int, list[str]]:
    """(number of runs, one line per run that did not finish with status ok) in a sweep folder."""
    from slamlab.report.rundir import find_run_dirs, load_run

    runs = [load_run(p) for p in find_run_dirs([sweep_dir])]
    # name a job by what it changed from the others (the swept values), not by the shared overrides
    shared = set.intersection(*(set(r.overrides) for r in runs)) if runs else set()
    lines = []
    for r in runs:
        if not r.ok:
            own = " ".join(o for o in r.overrides if o not in shared)
            first = (r.error or r.status).strip().splitlines()[0]
            lines.append(f"job {r.name}{f' ({own})' if own else ''}: {first}")
    return len(runs), lines


class SweepReportCallback(Callback):
    """Build `<sweep dir>/report.html` (and `runs.csv`) when a multirun ends.

    `enabled=False` switches it off from config; a top-level `report: false` in the app
    config (the per-run switch) switches it off too, so one knob controls all reports.
    """

    def __init__(self, enabled: bool = True, filename: str = SweepFile.REPORT) -> None:
        self.enabled = enabled
        self.filename = filename
        self._start_dir: Path | None = None
        self._start_time = 0.0

    @staticmethod
    def _sweep_dir(config: DictConfig) -> Path | None:
        try:
            return Path(str(config.hydra.sweep.dir))
        except Exception:  # noqa: BLE001 - e.g. an interpolation that cannot resolve here
            return None

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        # Remember the sweep dir as the launcher resolves it, before any job runs: the
        # default name holds ${now:...}, so resolving it again later must give the same path.
        self._start_dir = self._sweep_dir(config)
        self._start_time = time.time()

    def _locate(self, config: DictConfig) -> Path | None:
        """The sweep directory that holds this multirun's jobs."""
        candidates = [p for p in (self._sweep_dir(config), self._start_dir) if p is not None]
        for p in candidates:
            if (p / SweepFile.MULTIRUN).is_file():
                return p
        # Fallback: if ${now} re-resolved to another time, take the newest sibling sweep
        # created since this multirun started.
        for p in candidates:
            parent = p.parent
            if parent.is_dir():
                recent = [d for d in parent.iterdir()
                          if (d / SweepFile.MULTIRUN).is_file() and d.stat().st_mtime >= self._start_time - 1.0]
                if recent:
                    return max(recent, key=lambda d: d.stat().st_mtime)
        return None

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        LAST_SWEEP.update(runs=0, failed=[])
        sweep_dir = self._locate(config)
        if sweep_dir is not None:
            try:
                LAST_SWEEP["runs"], LAST_SWEEP["failed"] = failed_runs(sweep_dir)
            except Exception as exc:  # noqa: BLE001 - counting must not hide the report
                log.error("could not count the sweep's failed runs: %s", exc)
        try:
            if not self.enabled or config.get("report", True) is False:
                return
            if sweep_dir is None:
                log.error("sweep report not written: sweep directory not found (hydra.sweep.dir=%s)",
                          self._sweep_dir(config))
                return
            from slamlab.report.sweep_report import build_sweep_report  # heavy imports only when used

            t0 = time.perf_counter()
            path = build_sweep_report([sweep_dir], sweep_dir, filename=self.filename)
            log.info("sweep report: %s (%.1f s)", path, time.perf_counter() - t0)
        except Exception as exc:  # noqa: BLE001 - a report must never fail the sweep
            log.error("sweep report not written: %s: %s", type(exc).__name__, exc, exc_info=True)
