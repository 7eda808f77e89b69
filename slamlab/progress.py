"""Progress for long runs: a bar (scans done, rate, time left) on a terminal, plain log
lines every 10 % otherwise (CI logs, sweeps, files)."""

from __future__ import annotations

import logging
import sys
import time

log = logging.getLogger("slamlab")


class _LogProgress:
    def __init__(self, label: str):
        self.label = label
        self.t0 = time.perf_counter()
        self.next_pct = 10

    def __call__(self, done: int, total: int) -> None:
        pct = 100 * done // max(total, 1)
        if pct >= self.next_pct or done == total:
            el = time.perf_counter() - self.t0
            rate = done / el if el > 0 else 0.0
            left = (total - done) / rate if rate > 0 else float("nan")
            log.info("%s %3d%% %d/%d scans, %.0f scans/s, %.0f s left", self.label, pct, done, total, rate, left)
            self.next_pct = pct - pct % 10 + 10

    def close(self) -> None:
        pass


class _BarProgress:
    def __init__(self, label: str):
        from tqdm import tqdm

        self.bar = tqdm(desc=label, unit="scan", dynamic_ncols=True, file=sys.stderr)

    def __call__(self, done: int, total: int) -> None:
        if self.bar.total != total:
            self.bar.total = total
        self.bar.update(done - self.bar.n)

    def close(self) -> None:
        self.bar.close()


class _NoProgress:
    def __call__(self, done: int, total: int) -> None:
        pass

    def close(self) -> None:
        pass


def make_progress(mode: str | None, label: str = "SLAM"):
    """`auto` (bar on a terminal, log lines otherwise) | `bar` | `log` | `off`/None."""
    if mode in (None, "off", False):
        return _NoProgress()
    if mode == "bar" or (mode == "auto" and sys.stderr.isatty()):
        return _BarProgress(label)
    return _LogProgress(label)
