"""Resampling: draw a new particle set (as indices into the old one) from normalised weights.

All four schemes are unbiased (each particle's expected number of copies is N * w_i); they
differ in variance: multinomial > stratified >= systematic, residual in between. The engine
resamples only when N_eff = 1 / sum(w^2) < threshold * N (`threshold` in (0, 1]).

Adding a scheme: subclass `Resampler`, implement `indices`, add its schema
(`slamlab.config.slam`, listed in `slamlab.config.SCHEMAS`) and `conf/resampler/NAME.yaml`.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

from slamlab.config.slam import ResamplerConfig
from slamlab.geometry import FloatArray
from slamlab.slam.weighting import effective_sample_size


class Resampler(ABC):
    """Interface: `indices(weights (N,), rng) -> int64 (N,)`, plus the N_eff trigger."""

    def __init__(self, threshold: float = ResamplerConfig.threshold) -> None:  # checked by ResamplerConfig
        self.threshold = float(threshold)

    def should_resample(self, weights: FloatArray) -> bool:
        """True when N_eff < threshold * N."""
        return effective_sample_size(weights) < self.threshold * len(weights)

    @abstractmethod
    def indices(self, weights: FloatArray, rng: np.random.Generator) -> np.ndarray:
        ...


def _search(cdf: FloatArray, u: FloatArray) -> np.ndarray:
    # The last cdf value is forced to 1 so rounding never yields index N.
    idx = np.searchsorted(cdf, u, side="right")
    return np.minimum(idx, len(cdf) - 1).astype(np.int64)


def _cdf(weights: FloatArray) -> FloatArray:
    c = np.cumsum(np.asarray(weights, dtype=np.float64))
    c /= c[-1]
    c[-1] = 1.0
    return c


class MultinomialResampler(Resampler):
    """N independent draws from the weights."""

    def indices(self, weights: FloatArray, rng: np.random.Generator) -> np.ndarray:
        n = len(weights)
        return _search(_cdf(weights), np.sort(rng.random(n)))


class SystematicResampler(Resampler):
    """One uniform offset, N evenly spaced pointers: (u + i) / N."""

    def indices(self, weights: FloatArray, rng: np.random.Generator) -> np.ndarray:
        n = len(weights)
        return _search(_cdf(weights), (rng.random() + np.arange(n)) / n)


class StratifiedResampler(Resampler):
    """One uniform draw in each of N equal strata: (u_i + i) / N."""

    def indices(self, weights: FloatArray, rng: np.random.Generator) -> np.ndarray:
        n = len(weights)
        return _search(_cdf(weights), (rng.random(n) + np.arange(n)) / n)


class ResidualResampler(Resampler):
    """floor(N w_i) copies deterministically, the remainder multinomially from the residuals."""

    def indices(self, weights: FloatArray, rng: np.random.Generator) -> np.ndarray:
        w = np.asarray(weights, dtype=np.float64)
        w = w / w.sum()
        n = len(w)
        counts = np.floor(n * w).astype(np.int64)
        fixed = np.repeat(np.arange(n, dtype=np.int64), counts)
        rest = n - len(fixed)
        if rest == 0:
            return fixed
        resid = n * w - counts
        drawn = _search(_cdf(resid), np.sort(rng.random(rest)))
        return np.sort(np.concatenate([fixed, drawn]))
