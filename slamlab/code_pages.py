"""LLVM's code pages given back after numba has loaded a kernel (issue 44).

numba loads every kernel (compiled, or read from its cache) through LLVM: the whole of
libllvmlite.so (180 MB of machine code and tables) is mapped into the process, and loading
even one cached kernel runs LLVM's code generator and linker, spread over that library: the
kernel faults in ~45 MB of its pages (the first load, which also builds numba's runtime, ~90 MB;
`import numba` itself ~100 MB through LLVM's start-up code). Those pages stay resident in the
process long after the last kernel has loaded, while the run only executes the kernels' own
code, so they made up a third of a one-scan run's peak resident size and ~90 MB of Intel's
and the hospital's, through the whole filter.

`give_back_llvm_pages_after_loads` installs a listener on numba's compiler lock: each time a
thread lets go of it (a kernel loaded or compiled), the process's resident pages of
libllvmlite.so are given back (`madvise(MADV_DONTNEED)`). They stay in the kernel's page cache,
shared with every other process, and come back as minor page faults at the next load. Only
pages that are the file's own bytes are given back (a read-only mapping that holds no page of
its own, checked once): the library's relocated tables and data, written when it was loaded,
are never touched. So no result can change: code read again from its file is the same code.

`start_numba_runtime` makes numba's runtime ready at once, when the process is small: the
first kernel load of a process builds it (LLVM's whole code generator runs for its functions,
~38 MB of LLVM's pages resident for that load), and mid-run that sat on top of the run's data
(the one-scan run's peak, 160 MB, was that load; now 122 MB at that point).

`give_back_library_pages` does the same once, for any shared library: the graph filter gives back
GTSAM's after its import (its Python module's set-up code, run once: 24 of its 28 resident MB)
and after its last optimisation (the report never calls it).
"""

from __future__ import annotations

import mmap
import sys
from pathlib import Path

from slamlab.heap import give_back

LIBRARY = "libllvmlite.so"


def file_only_ranges(name: str, smaps: Path = Path("/proc/self/smaps")) -> list[tuple[int, int]]:
    """[start, end) address ranges of this process's mappings of the shared library whose file
    name contains `name` that are read-only and hold only the file's own pages (no anonymous,
    copied-on-write page): the ranges whose resident pages can be dropped and read again
    from the file unchanged. Empty where /proc is not there."""
    out: list[tuple[int, int]] = []
    candidate: tuple[int, int] | None = None
    try:
        lines = smaps.read_text().splitlines()
    except OSError:
        return out
    for line in lines:
        head = line.split(None, 5)
        if not head:
            continue
        if "-" in head[0] and not head[0].endswith(":"):  # a mapping's first line: range perms offset dev inode path
            candidate = None
            if len(head) == 6 and name in Path(head[5]).name and "w" not in head[1]:
                lo, hi = (int(x, 16) for x in head[0].split("-"))
                candidate = (lo, hi)
        elif head[0] == "Anonymous:" and candidate is not None:
            if int(head[1]) == 0:
                out.append(candidate)
            candidate = None
    return out


def give_back_library_pages(name: str) -> bool:
    """Give back the resident pages of the shared library whose file name contains `name`
    that are its file's own bytes (`file_only_ranges`): the code it runs next is read again
    from the page cache. True when any range was given back (Linux with /proc)."""
    ranges = file_only_ranges(name)
    for lo, hi in ranges:
        give_back(lo, hi)
    return bool(ranges)


_INSTALLED: list[bool] = []  # once per process


def give_back_llvm_pages_after_loads() -> bool:
    """From now on, give back LLVM's resident code pages whenever numba lets go of its compiler
    lock (after a kernel loaded or compiled, and once now). Once per process; numba is imported
    here. True when installed (Linux with /proc and libllvmlite.so loaded), else False."""
    if _INSTALLED:
        return True
    if not sys.platform.startswith("linux") or not hasattr(mmap, "MADV_DONTNEED"):
        return False
    import llvmlite.binding  # noqa: F401  (maps libllvmlite.so, should numba not have yet)
    from numba.core import event
    from numba.core.compiler_lock import global_compiler_lock

    ranges = file_only_ranges(LIBRARY)
    if not ranges:
        return False

    def drop() -> None:
        for lo, hi in ranges:
            give_back(lo, hi)

    class _AfterLoad(event.Listener):
        def on_start(self, ev: event.Event) -> None:
            pass

        def on_end(self, ev: event.Event) -> None:
            if not global_compiler_lock.is_locked():  # the outermost release: the load is done
                drop()

    event.register("numba:compiler_lock", _AfterLoad())
    _INSTALLED.append(True)
    drop()
    return True


def start_numba_runtime() -> None:
    """Build numba's runtime now (once per process) and give LLVM's pages back after it (the
    imports it makes run outside numba's compiler lock, so the listener may not see their
    end). Every run loads kernels, so this is work the run would do at its first kernel."""
    from numba.core.registry import cpu_target

    cpu_target.target_context.refresh()  # initialises the runtime (NRT) and numba's CPython registries
    give_back_library_pages(LIBRARY)
