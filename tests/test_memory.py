"""A run's peak memory is its own, not the process's lifetime maximum."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from slamlab import memory
from slamlab.memory import RunPeakMemory


@pytest.mark.parametrize("method", ["high-water mark reset", "sampled"])
def test_a_later_run_does_not_inherit_an_earlier_peak(method, monkeypatch, tmp_path):
    if method == "sampled":  # where /proc/self/clear_refs may not be written
        monkeypatch.setattr(memory, "CLEAR_REFS", Path(tmp_path / "no" / "such" / "file"))
    first = RunPeakMemory()
    big = np.ones(300 * 2**20 // 8)  # 300 MB, touched
    big_peak = first.peak_mb()
    del big
    second = RunPeakMemory()
    small = np.ones(20 * 2**20 // 8)  # 20 MB
    small_peak = second.peak_mb()
    del small
    assert first.method == second.method == method and second.scope == "run"
    assert small_peak < big_peak - 200


# ---- issue 45: a sweep's jobs each report their own peak, whatever their place ------------------
def test_a_job_runs_in_a_child_and_its_end_is_the_parents_answer():
    """`_run_in_child`: the child's exit status (0, its sys.exit code, 1 for a bug with its
    traceback, 128 + N when signal N ended it); the parent's own memory is untouched."""
    import os
    import signal

    from slamlab.cli.app import _run_in_child

    grown = []
    assert _run_in_child(lambda: grown.append(np.ones(10**6))) == 0
    assert grown == []  # the child's state stays in the child
    assert _run_in_child(lambda: (_ for _ in ()).throw(SystemExit(130))) == 130
    assert _run_in_child(lambda: 1 / 0) == 1
    assert _run_in_child(lambda: os.kill(os.getpid(), signal.SIGKILL)) == 128 + signal.SIGKILL


@pytest.mark.slow
def test_the_jobs_of_a_sweep_report_peaks_that_do_not_grow_with_their_place(tmp_path, sim_cache):
    """50 particles, seeds 0/1/2 measured 444 / 539 / 523 MB when every job ran in the sweep's
    one process (each job's peak sat on what the jobs before it left allocated); the same
    sweep of short runs here, before the fix: 293 / 343 / 359 MB."""
    import json

    from cli_helpers import sweep_cli

    sweep = tmp_path / "sweep"
    out = sweep_cli(sweep, ["seed=0,1,2", "dataset.duration_s=20", "particles=20", "texture=none", "progress=off",
                            "report=false"], sim_cache)
    assert out.returncode == 0, out.stderr[-2000:]
    metrics = [json.loads((sweep / str(i) / "metrics.json").read_text()) for i in range(3)]
    peaks = [m["peak_memory_mb"] for m in metrics]
    assert all(m["peak_memory_scope"] == "run" for m in metrics)
    assert max(peaks) / min(peaks) < 1.08, peaks


# ---- one malloc heap for every thread (`heap.one_heap_for_all_threads`) ----------------------------
_HEAPS_AFTER_A_THREAD = """
import ctypes, sys, tempfile, threading
if sys.argv[1] == "slamlab":
    import slamlab  # noqa: F401
import numpy as np

def work():
    keep = [np.ones(1000) for _ in range(100)]  # a thread that allocates
    del keep

t = threading.Thread(target=work)
t.start()
t.join()
libc = ctypes.CDLL(None)
libc.fopen.restype, libc.fopen.argtypes = ctypes.c_void_p, [ctypes.c_char_p, ctypes.c_char_p]
libc.malloc_info.argtypes, libc.fclose.argtypes = [ctypes.c_int, ctypes.c_void_p], [ctypes.c_void_p]
with tempfile.NamedTemporaryFile(suffix=".xml") as f:
    fp = libc.fopen(f.name.encode(), b"w")
    libc.malloc_info(0, fp)
    libc.fclose(fp)
    print(open(f.name).read().count("<heap nr="))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's heaps (the CI machine is Linux)")
def test_after_importing_slamlab_a_thread_allocates_from_the_one_main_heap():
    """Importing slamlab leaves glibc one heap (arena) for all threads: a thread that
    allocates gets none of its own (a plain Python process: two heaps after it)."""
    def heaps(what: str) -> int:
        out = subprocess.run([sys.executable, "-c", _HEAPS_AFTER_A_THREAD, what], capture_output=True, text=True, check=True)
        return int(out.stdout.strip())

    assert heaps("plain") == 2
    assert heaps("slamlab") == 1
