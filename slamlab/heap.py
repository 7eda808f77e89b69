"""Freed memory handed back to the system between a run's phases (issue 44).

`release_freed_memory`: after a phase that freed much (reading a log, the filter's maps, a
report figure), the free pages of malloc's heaps go back to the system before the next phase
starts. It does nothing where the C library is not glibc, and never changes a result.

`release_pages`: the pages of an array being copied into a larger one given back as they are
copied (a growing map holds one copy at a time, not two).

`one_heap_for_all_threads`: every thread allocates from the main heap, so what a thread frees
is not kept resident in a heap of its own.

`give_back`: the resident pages of an address range let go (`release_pages`, and
`code_pages` for LLVM's code); `give_back_file_pages` for an array mapped from a file.

Not done: a fixed 1 MB mmap threshold (`mallopt`), which gives every large array back the
moment it is freed (Intel's whole run with report 309 MB against 326 MB here), because every
such array is then mapped and faulted in afresh: the default sim run took 61,569 -> 920,161
minor page faults and 0.45 -> 1.93 s of system CPU.
"""

from __future__ import annotations

import ctypes
import mmap
import sys
from functools import cache
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np


@cache
def _glibc(name: str):
    """A function of the process's own C library when it is glibc's (Linux), else None."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        return getattr(ctypes.CDLL(None), name)  # musl has no malloc_trim
    except (OSError, AttributeError):
        return None


M_ARENA_MAX = -8  # glibc's mallopt parameter: how many heaps (arenas) threads may spread their allocations over


def one_heap_for_all_threads() -> bool:
    """Make every thread allocate from the one (main) heap, where glibc gives each new thread
    that allocates a heap of its own (up to 8 per core), which keeps what was freed in it
    resident for that thread. Must run before a second thread first allocates (`slamlab`'s
    import does). True when the C library took it (glibc).
    Why: the loop search runs its wide searches on two Python threads (`graph.loops.side_by_side`)
    and numba's threads allocate too (a kernel's arrays); the hospital log's peak with those
    threads on heaps of their own 528-547 -> 556-578 MB over four runs, on one heap 530 MB, at the
    same speed. Results never depend on it."""
    mallopt = _glibc("mallopt")
    if mallopt is None:
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return mallopt(M_ARENA_MAX, 1) == 1


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


def release_pages(a: np.ndarray, start: int, stop: int) -> int:
    """Give back to the system the whole memory pages inside bytes [start, stop) of the
    C-contiguous array `a`, whose values there are never read again (they read as zeros
    afterwards: `madvise(MADV_DONTNEED)`). Returns the byte offset released up to (the last
    whole page's end), to pass as the next call's `start`; `start` when nothing was released
    (a partial page waits for the next call). Does nothing off Linux.

    Why: copying a large array into a larger one (a growing map) holds both at once; giving
    back the old one's pages as they are copied keeps one copy resident instead of two."""
    base = a.ctypes.data
    page = mmap.PAGESIZE
    lo = -(-(base + start) // page) * page  # first whole page at or after start
    hi = (base + stop) // page * page  # end of the last whole page before stop
    if hi <= lo or not give_back(lo, hi):
        return start
    return hi - base


def give_back_file_pages(a: np.memmap) -> None:
    """Let go of the resident pages of `a`, an array memory-mapped read-only from a file: they
    are read again from the page cache when next touched (the same bytes). Why: a cached log's
    arrays are read whole once to check them (`array_cache.read_entry`), then a scan at a
    time; Intel's 12 MB stayed resident from the check on."""
    if a.mode != "r":
        raise ValueError(f"give_back_file_pages: {a.filename} is mapped for writing ({a.mode!r}): its pages are not only the file's")
    page = mmap.PAGESIZE
    base = a.ctypes.data
    lo = -(-base // page) * page  # whole pages only: the first and last may hold the file's header or another array
    hi = (base + a.nbytes) // page * page
    if hi > lo:
        give_back(lo, hi)


def give_back(lo: int, hi: int) -> bool:
    """`madvise(MADV_DONTNEED)` on the page-aligned addresses [lo, hi): their resident pages
    go; a private file mapping's read from the file again when next touched, anonymous memory
    reads as zeros. True when done (Linux)."""
    advise = _glibc("madvise")
    dontneed = getattr(mmap, "MADV_DONTNEED", None)
    if advise is None or dontneed is None:
        return False
    advise.argtypes, advise.restype = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int], ctypes.c_int
    return advise(lo, hi - lo, dontneed) == 0
