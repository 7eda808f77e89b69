"""LLVM's code pages given back after numba loads a kernel (slamlab.code_pages, issue 44)."""

from __future__ import annotations

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


CHILD = textwrap.dedent(
    """
    import json, sys
    import numba
    import numpy as np
    from slamlab.code_pages import give_back_llvm_pages_after_loads

    def llvm_resident_mb():
        total, current = 0, False
        for line in open("/proc/self/smaps"):
            head = line.split()
            if "-" in head[0] and not head[0].endswith(":"):
                current = len(head) == 6 and "libllvmlite" in head[5]
            elif current and head[0] == "Rss:":
                total += int(head[1])
        return total / 1024

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
    print(json.dumps({"installed": installed, "after_first": after_first, "after_second": llvm_resident_mb(),
                      "first": first, "second": second, "again": doubled_sum(np.ones(4))}))
    """
)


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
