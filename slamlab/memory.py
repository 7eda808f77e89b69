"""Peak memory of one run, not of the process: a sweep runs many jobs in one process (or in
reused worker processes), and the process's lifetime maximum (`ru_maxrss`) would give every
job at least the peak of the largest job before it.

On Linux the kernel's high-water mark (VmHWM) is reset when a run starts (writing 5 to
/proc/self/clear_refs) and read when it ends. Where that is not allowed, a thread samples the
resident size every few milliseconds; without /proc, the process's lifetime peak is all
there is, and `scope` says so.

`release_freed_memory` hands what a phase freed back to the system before the next phase
starts (glibc keeps freed heap blocks resident for reuse otherwise), and
`keep_large_blocks_mapped` makes large arrays go back to it as soon as they are freed.
"""

from __future__ import annotations

import ctypes
import re
import resource
import sys
import threading
from functools import cache
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


@cache
def _glibc(name: str):
    """A function of the process's own C library when it is glibc's (Linux), else None."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        return getattr(ctypes.CDLL(None), name)  # musl has neither malloc_trim nor mallopt
    except (OSError, AttributeError):
        return None


M_MMAP_THRESHOLD = -3  # mallopt's parameter (malloc.h)
MMAP_THRESHOLD_BYTES = 1 << 20


def keep_large_blocks_mapped() -> None:
    """Serve every block of 1 MB or more from its own memory map, so freeing it gives it
    back to the system at once.

    Why: glibc starts at 128 kB and raises that threshold to the size of each mapped block
    freed (up to 32 MB), so once a few large arrays have come and gone, the next ones of
    their size come from the heap and stay resident after they are freed. The run report's
    figures each make 10-15 MB arrays (an RGBA map resampled at the output size): the Intel
    report's peak grew by each figure's (+84 MB for the report against +59 MB for its map
    figure alone). Setting the threshold also turns glibc's raising off. Blocks below 1 MB
    (a step's scan and particle arrays) still come from the heap, as fast as before."""
    mallopt = _glibc("mallopt")
    if mallopt is not None:
        mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
        mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)


def release_freed_memory() -> None:
    """Return the heap memory freed so far to the system, where the C library allows it.

    Why: glibc serves the many small and mid-sized blocks Python and NumPy ask for (a scan's
    4 kB of ranges, an object's few bytes) from heaps it never shrinks while any block above
    the freed ones lives, and keeps them resident for reuse. After a phase such as reading
    a THOR log through `scipy.io.loadmat` (27,560 records of the hard simulated world: 130 MB
    freed at its end) the next phase then starts that much higher, and a phase that asks
    for large arrays (mapped afresh, not from those heaps) adds its own on top. `malloc_trim`
    gives back every free page of every heap (a few ms). Results never depend on it."""
    trim = _glibc("malloc_trim")
    if trim is not None:
        trim.argtypes, trim.restype = [ctypes.c_size_t], ctypes.c_int
        trim(0)
