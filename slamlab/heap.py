"""How the C library's allocator holds freed memory, tuned so a run's resident memory follows
what it holds (issue 44). Both functions do nothing where the C library is not glibc.

- `keep_large_blocks_mapped`: arrays of 1 MB or more get their own memory maps, so freeing
  one gives its memory back at once;
- `release_freed_memory`: after a phase that freed many small blocks (reading a log), the
  free pages of malloc's heaps go back to the system before the next phase.
Neither changes a result: they decide only where freed memory goes.
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
