"""The replay's one-pass map reductions give numpy's values exactly."""

from __future__ import annotations

import numpy as np
import pytest

from slamlab.slam.map_reduce import block_max_1pass, known_bounds
from slamlab.slam.replay import block_max


@pytest.mark.parametrize("dtype", [np.float32, np.int8])  # log-odds, and the RBPF tiles' codes
@pytest.mark.parametrize("shape, k", [((37, 53), 1), ((37, 53), 4), ((64, 64), 8), ((100, 7), 36), ((5, 5), 9)])
def test_block_max_equals_numpys(shape, k, dtype):
    rng = np.random.default_rng(k)
    data = rng.normal(-2.0, 1.0, shape)  # mostly negative: padding zeros must win at the edges
    data = data.astype(np.float32) if dtype == np.float32 else np.clip(np.round(data * 20), -100, 100).astype(np.int8)
    got = block_max_1pass(data, k)
    assert got.dtype == data.dtype and np.array_equal(got, block_max(data, k) if k > 1 else data)


def test_known_bounds_equal_the_mask_of_known_cells():
    rng = np.random.default_rng(1)
    data = np.zeros((60, 80), np.float32)
    data[7:31, 12:70] = rng.normal(0.0, 1.0, (24, 58)).astype(np.float32)
    data[7:31, 12] = np.float32(1e-6)  # not "known": |v| must exceed 1e-6
    known = np.abs(data) > np.float32(1e-6)
    rows, cols = np.flatnonzero(known.any(axis=1)), np.flatnonzero(known.any(axis=0))
    assert known_bounds(data, np.float32(1e-6)) == (rows[0], rows[-1] + 1, cols[0], cols[-1] + 1)
    assert known_bounds(np.zeros((4, 4), np.float32), np.float32(1e-6))[1] == 0
