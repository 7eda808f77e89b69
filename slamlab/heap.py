"""Freed memory handed back to the system between a run's phases (issue 44).

`release_freed_memory`: after a phase that freed much (reading a log, the filter's maps, a
report figure), the free pages of malloc's heaps go back to the system before the next phase
starts. It does nothing where the C library is not glibc, and never changes a result.

Not done: a fixed 1 MB mmap threshold (`mallopt`), which gives every large array back the
moment it is freed (Intel's whole run with report 309 MB against 326 MB here), because every
such array is then mapped and faulted in afresh: the default sim run took 61,569 -> 920,161
minor page faults and 0.45 -> 1.93 s of system CPU.
"""

from __future__ import annotations

import ctypes
import sys
from functools import cache


@cache
def _glibc(name: str):
    """A function of the process's own C library when it is glibc's (Linux), else None."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        return getattr(ctypes.CDLL(None), name)  # musl has no malloc_trim
    except (OSError, AttributeError):
        return None


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
