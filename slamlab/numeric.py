"""Small numeric helpers shared by the engine and the reports (a core module: NumPy only).

The reports read a run's files and never import the SLAM engine (the layer contract in
pyproject.toml); what both need lives here.
"""

from __future__ import annotations

import numpy as np

# exp(x) is inf in float64 above this (log of the largest float64, 1.8e308): a correlation
# above it overflows a linear-space weighting (`slam.weighting`, and the report that explains it).
OVERFLOW_SCORE = float(np.log(np.finfo(np.float64).max))


def evenly_spaced(n: int, count: int) -> np.ndarray:
    """Indices of `count` of 0..n-1 (or all of them) spread evenly, first and last included."""
    if n <= 0:
        return np.zeros(0, dtype=np.int64)
    return np.unique(np.linspace(0, n - 1, min(count, n)).round().astype(np.int64))


def block_max(data: np.ndarray, k: int) -> np.ndarray:
    """Reduce a log-odds grid by k x k blocks keeping each block's largest value (the most
    occupied cell, so thin walls survive); edges padded with 0 (unknown)."""
    if k <= 1:
        return data
    # k*k strided maxima: ~20x faster than a max over a reshaped (h, k, w, k) view, which
    # matters as the engine reduces a map at every snapshot. The grid is read in place (a
    # padded copy of a building's map was 160 MB): the edge blocks' padding is the 0 taken in below
    out = data[0::k, 0::k].copy()
    for i in range(k):
        for j in range(k):
            part = data[i::k, j::k]
            view = out[: part.shape[0], : part.shape[1]]
            np.maximum(view, part, out=view)
    zero = out.dtype.type(0)  # any dtype: the RBPF tiles' integer codes too
    if data.shape[0] % k:
        np.maximum(out[-1], zero, out=out[-1])
    if data.shape[1] % k:
        np.maximum(out[:, -1], zero, out=out[:, -1])
    return out
