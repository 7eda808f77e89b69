"""A run's peak memory is its own, not the process's lifetime maximum."""

from __future__ import annotations

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
