"""Peak memory of one run, not of the process: a sweep runs many jobs in one process (or in
reused worker processes), and the process's lifetime maximum (`ru_maxrss`) would give every
job at least the peak of the largest job before it.

On Linux the kernel's high-water mark (VmHWM) is reset when a run starts (writing 5 to
/proc/self/clear_refs) and read when it ends. Where that is not allowed, a thread samples the
resident size every few milliseconds; without /proc, the process's lifetime peak is all
there is, and `scope` says so.
"""

from __future__ import annotations

import re
import resource
import sys
import threading
from pathlib import Path

STATUS = Path("/proc/self/status")
CLEAR_REFS = Path("/proc/self/clear_refs")
SAMPLE_S = 0.005


def _status_mb(field: str) -> float:
    """The value of one `Name:  N kB` line of /proc/self/status (e.g. VmRSS, VmHWM), in MB."""
    m = re.search(rf"^{field}:\s+(\d+) kB", STATUS.read_text(), re.MULTILINE)
    return int(m.group(1)) / 1024.0 if m else float("nan")


def process_peak_mb() -> float:
    """Peak resident set size of this process over its whole life (MB)."""
    kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return kb / 1024.0 if sys.platform != "darwin" else kb / 1024.0 / 1024.0


class RunPeakMemory:
    """Measures the peak resident memory (MB) from construction to `peak_mb()`.

    `scope` is "run" (this run's own peak: reset high-water mark or sampling) or "process"
    (the process's lifetime peak, where neither is possible)."""

    def __init__(self) -> None:
        self._peak = 0.0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.scope = "run"
        self.method = "high-water mark reset"
        try:
            CLEAR_REFS.write_text("5")  # resets VmHWM to the current resident size
        except OSError:
            if STATUS.exists():
                self.method = "sampled"
                self._thread = threading.Thread(target=self._sample, name="peak-memory", daemon=True)
                self._thread.start()
            else:
                self.scope, self.method = "process", "ru_maxrss"

    def _sample(self) -> None:
        while not self._stop.wait(SAMPLE_S):
            self._peak = max(self._peak, _status_mb("VmRSS"))

    def peak_mb(self) -> float:
        """The peak so far (MB); stops the sampling thread, if any."""
        if self.method == "high-water mark reset":
            return _status_mb("VmHWM")
        if self._thread is not None:
            self._stop.set()
            self._thread.join()
            self._thread = None
            return max(self._peak, _status_mb("VmRSS"))
        return process_peak_mb()
