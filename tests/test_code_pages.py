"""LLVM's code pages given back after numba loads a kernel (slamlab.code_pages, issue 44)."""

from __future__ import annotations

import inspect
import json
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from slamlab.code_pages import file_only_ranges

LLVM = "/env/site-packages/llvmlite/binding/libllvmlite.so"
# (range, permissions, file, resident kB, anonymous kB): the mappings of a process, as /proc/self/smaps lists them
MAPPINGS = [
    ("00400000-00401000", "r--p", "/usr/bin/python3.11", 4, 0),
    ("7f0000000000-7f0000100000", "r--p", LLVM, 1024, 0),
    ("7f0000100000-7f0000500000", "r-xp", LLVM, 4096, 0),
    ("7f0000500000-7f0000600000", "r--p", LLVM, 1024, 12),  # relocated when loaded: 12 kB copied on write
    ("7f0000600000-7f0000610000", "rw-p", LLVM, 64, 0),
    ("7f0000610000-7f0000620000", "rw-p", "", 64, 64),  # anonymous memory
    ("7f0000700000-7f0000800000", "r-xp", "/env/site-packages/numpy/core/libother.so", 1024, 0),
]
SMAPS = "".join(f"{rng} {perms} 00000000 fd:01 22 {path}".rstrip() + f"\nRss: {rss} kB\nAnonymous: {anon} kB\nVmFlags: rd mr\n"
                for rng, perms, path, rss, anon in MAPPINGS)


def test_only_the_librarys_read_only_mappings_holding_nothing_of_their_own_are_chosen(tmp_path: Path) -> None:
    smaps = tmp_path / "smaps"
    smaps.write_text(SMAPS)
    # the relocated table (12 kB copied on write) and the writable data are left alone: their
    # pages are not the file's bytes; other libraries and anonymous memory are not chosen
    assert file_only_ranges("libllvmlite.so", smaps) == [(0x7F0000000000, 0x7F0000100000), (0x7F0000100000, 0x7F0000500000)]
    assert file_only_ranges("libother", smaps) == [(0x7F0000700000, 0x7F0000800000)]
    assert file_only_ranges("libnothere", smaps) == []
    assert file_only_ranges("libllvmlite.so", tmp_path / "missing") == []


def resident_mb(chosen) -> float:
    """Resident MB of this process's mappings whose file path `chosen(path)` accepts (smaps)."""
    total, current = 0, False
    for line in open("/proc/self/smaps"):
        head = line.split()
        if "-" in head[0] and not head[0].endswith(":"):
            current = len(head) == 6 and chosen(head[5])
        elif current and head[0] == "Rss:":
            total += int(head[1])
    return total / 1024


RESIDENT_MB = inspect.getsource(resident_mb)  # the same helper, in the child processes below
CHILD = textwrap.dedent(
    """
    import json, sys
    import numba
    import numpy as np
    from slamlab.code_pages import give_back_llvm_pages_after_loads

    {resident_mb}
    def llvm_resident_mb():
        return resident_mb(lambda path: "libllvmlite" in path)

    installed = give_back_llvm_pages_after_loads() if sys.argv[1] == "on" else False

    @numba.njit
    def doubled_sum(a):
        return (a * 2.0).sum()

    first = doubled_sum(np.arange(10.0))
    after_first = llvm_resident_mb()

    @numba.njit
    def spread(a):
        return a.max() - a.min()

    second = spread(np.array([3.0, -1.5, 2.0]))
    print(json.dumps({{"installed": installed, "after_first": after_first, "after_second": llvm_resident_mb(),
                      "first": first, "second": second, "again": doubled_sum(np.ones(4))}}))
    """
).format(resident_mb=RESIDENT_MB)


def _child(mode: str) -> dict:
    out = subprocess.run([sys.executable, "-c", CHILD, mode], capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc/self/smaps and madvise: Linux")
def test_llvm_leaves_the_resident_set_after_each_kernel_loads_and_kernels_still_compile_and_run() -> None:
    on, off = _child("on"), _child("off")
    assert on["installed"] is True and off["installed"] is False
    # without: compiling a kernel keeps tens of MB of LLVM's code resident (~90 MB here)
    assert off["after_first"] > 30 and off["after_second"] > 30
    # with: a few pages at most once each load has ended, and a later compile still works
    assert on["after_first"] < 8 and on["after_second"] < 8
    for run in (on, off):
        assert (run["first"], run["second"], run["again"]) == (90.0, 4.5, 8.0)


RUNTIME_AND_GTSAM_CHILD = textwrap.dedent(
    """
    import json
    from slamlab.code_pages import give_back_library_pages, start_numba_runtime

    {resident_mb}

    import gtsam
    after_import = resident_mb(lambda path: "gtsam" in path)
    given = give_back_library_pages("gtsam")
    after_give_back = resident_mb(lambda path: "gtsam" in path)
    p = gtsam.Pose2(1.0, 2.0, 0.5).between(gtsam.Pose2(-0.5, 4.0, -1.0))
    start_numba_runtime()
    from numba.core.runtime import nrt
    print(json.dumps({{"after_import": after_import, "given": given, "after_give_back": after_give_back,
                      "between": [p.x(), p.y(), p.theta()], "runtime": nrt.rtsys._init,
                      "llvm": resident_mb(lambda path: "libllvmlite" in path)}}))
    """
).format(resident_mb=RESIDENT_MB)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc/self/smaps and madvise: Linux")
def test_gtsams_pages_go_after_its_import_and_it_still_computes_and_numbas_runtime_starts_without_keeping_llvm() -> None:
    gtsam = pytest.importorskip("gtsam")
    out = subprocess.run([sys.executable, "-c", RUNTIME_AND_GTSAM_CHILD], capture_output=True, text=True, check=True)
    got = json.loads(out.stdout.strip().splitlines()[-1])
    # importing gtsam runs its Python module's set-up code across ~24 MB of the library, once
    # (its relocated tables and data, ~4 MB, are not the file's bytes: they stay)
    assert got["given"] is True and got["after_import"] > 20 and got["after_give_back"] < 6
    expected = gtsam.Pose2(1.0, 2.0, 0.5).between(gtsam.Pose2(-0.5, 4.0, -1.0))
    assert got["between"] == [expected.x(), expected.y(), expected.theta()]
    # the runtime is built (what a first kernel load would do) and LLVM's pages went after it
    assert got["runtime"] is True and got["llvm"] < 8


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc/self/smaps and madvise: Linux")
def test_a_cached_logs_arrays_leave_the_resident_set_after_their_check_and_read_the_same(tmp_path: Path, monkeypatch) -> None:
    import numpy as np

    from slamlab.datasets import array_cache
    from slamlab.heap import give_back_file_pages

    monkeypatch.setenv("SLAMLAB_CACHE_DIR", str(tmp_path / "cache"))
    ranges = np.random.default_rng(3).random((2000, 361)).astype(np.float32)  # 2.9 MB
    assert array_cache.write_entry("carmen", "log", {"ranges": ranges}, {"v": 1})
    arrays, _ = array_cache.read_entry("carmen", "log")
    path = (array_cache.entry_dir("carmen", "log") / "ranges.npy").resolve()
    assert resident_mb(lambda p: p == str(path)) < 0.1  # the checksum read every page; they went after it
    assert np.array_equal(arrays["ranges"], ranges)  # read again from the file, the same values
    assert resident_mb(lambda p: p == str(path)) > 2.5
    mapped = np.load(path, mmap_mode="r+")
    with pytest.raises(ValueError, match="mapped for writing"):
        give_back_file_pages(mapped)  # its pages may hold what was written to it: never dropped
