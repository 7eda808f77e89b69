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
    ph, pw = (-data.shape[0]) % k, (-data.shape[1]) % k
    padded = np.pad(data, ((0, ph), (0, pw)), constant_values=0.0)
    # k*k strided maxima: ~20x faster than a max over a reshaped (h, k, w, k) view, which
    # matters as the engine reduces a map at every snapshot
    out = padded[0::k, 0::k].copy()
    for i in range(k):
        for j in range(k):
            np.maximum(out, padded[i::k, j::k], out=out)
    return out
