"""slamlab: configurable particle-filter SLAM with texture mapping."""

import os
import sys

__version__ = "0.1.0"

# numba's OpenMP threads (libgomp), the fallback below, by default spin between parallel
# regions. The filter launches thousands of short regions (match, map update) per run, so
# on a busy 2-core machine the spinning threads doubled the default run's CPU and wall time
# (filter 16.9 s -> 7.9 s wall with passive waiting). Set before the first kernel loads the
# OpenMP runtime; a value the user exported wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

# NumPy asks the kernel for 2 MB pages (madvise MADV_HUGEPAGE) on every array of 4 MB or
# more. An array written in a few places then costs 2 MB for each 4 kB page touched: the RBPF
# map update's flip lists (one row per particle, sized for the worst case, a few entries
# used: 100 particles of the hard simulated world held ~200 MB of RSS for ~1 MB written),
# the texture accumulators over a mostly unseen grid. Off, memory follows what is written;
# a value the user exported wins (read when NumPy is first imported, which in a slamlab
# process is after this line).
os.environ.setdefault("NUMPY_MADVISE_HUGEPAGE", "0")


def _load_tbb() -> None:
    """Make numba's parallel kernels run on Intel TBB (the `tbb` wheel, a dependency).

    numba tries TBB first and falls back to OpenMP, but pip puts libtbb in the
    environment's lib/ folder, where the dynamic loader does not look: loaded here by path,
    before any kernel starts numba's threads, it is the library numba's TBB layer links to.
    Why: TBB's threads wait briefly before they sleep, where OpenMP's (passive) sleep at the
    end of every parallel loop, thousands a run: Intel's filter 10.2-12.4 s -> 9.4-11.1 s
    wall, the default sim run's 4.7-5.3 -> 3.7-4.3 s; and with the filter's loops handed out
    one particle at a time (`engine.run_slam`) a TBB thread that is done takes the next, where
    OpenMP splits every loop in fixed blocks. The same trajectories: the kernels' results do
    not depend on the schedule.
    Skipped when the user chose a layer (NUMBA_THREADING_LAYER), when a TBB is loaded
    already (Open3D's own, too old for numba: a second copy must not load beside it), and
    where the wheel did not install one; numba then uses OpenMP as before."""
    if os.environ.get("NUMBA_THREADING_LAYER", "default") not in ("default", "tbb"):
        return
    name = {"linux": "libtbb.so.12", "darwin": "libtbb.12.dylib"}.get(sys.platform)
    path = os.path.join(sys.prefix, "lib", name) if name else None
    if path is None or not os.path.exists(path):
        return
    import ctypes

    try:
        ctypes.CDLL(name, mode=os.RTLD_NOLOAD)
        return  # a TBB is loaded already: numba checks that one
    except OSError:
        pass
    try:
        ctypes.CDLL(path, mode=ctypes.RTLD_GLOBAL)
    except OSError:
        pass  # numba falls back to OpenMP


_load_tbb()


def _one_heap() -> None:
    """All threads on one malloc heap (`heap.one_heap_for_all_threads`: why), set before any
    thread of numba's or the loop search's starts."""
    from slamlab.heap import one_heap_for_all_threads

    one_heap_for_all_threads()


_one_heap()
