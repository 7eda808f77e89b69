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

log = logging.getLogger(__name__)


class SweepReportCallback(Callback):
    """Build `<sweep dir>/report.html` (and `runs.csv`) when a multirun ends.

    `enabled=False` switches it off from config; a top-level `report: false` in the app
    config (the per-run switch) switches it off too, so one knob controls all reports.
    """

    def __init__(self, enabled: bool = True, filename: str = "report.html") -> None:
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
            if (p / "multirun.yaml").is_file():
                return p
        # Fallback: if ${now} re-resolved to another time, take the newest sibling sweep
        # created since this multirun started.
        for p in candidates:
            parent = p.parent
            if parent.is_dir():
                recent = [d for d in parent.iterdir()
                          if (d / "multirun.yaml").is_file() and d.stat().st_mtime >= self._start_time - 1.0]
                if recent:
                    return max(recent, key=lambda d: d.stat().st_mtime)
        return None

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        try:
            if not self.enabled or config.get("report", True) is False:
                return
            sweep_dir = self._locate(config)
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
