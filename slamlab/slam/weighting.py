"""Update: turn per-particle match scores into normalised weights.

The engine keeps log-weights; each scheme returns new normalised log-weights.
- `LinearWeighting`: the course's `w *= corr`, then divide by the sum. In float64 the product
  of many correlations (or of tiny weights and correlations) can underflow to all-zero;
  then the update cannot be normalised. Instead of crashing or producing NaN, it warns once
  with the reason, counts the event (`underflows`) and falls back to uniform weights.
- `LogSumExpWeighting`: `log w += corr / temperature`, normalised with log-sum-exp, which
  never underflows: the best particle always keeps log-weight >= -log N.

Adding a scheme: subclass `Weighting`, implement `update`, add `conf/weighting/NAME.yaml`.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import logging
import warnings

import numpy as np

from slamlab.geometry import FloatArray
from slamlab.slam._keys import require_positive

GROUP = "weighting"
log = logging.getLogger(__name__)


class WeightUnderflowWarning(RuntimeWarning):
    """Linear weighting lost every particle's weight to floating-point underflow."""


def logsumexp(x: FloatArray) -> float:
    """log(sum(exp(x))) without overflow or underflow (x may hold -inf)."""
    m = float(np.max(x))
    if not np.isfinite(m):
        return m
    return m + float(np.log(np.sum(np.exp(x - m))))


def effective_sample_size(weights: FloatArray) -> float:
    """N_eff = 1 / sum(w^2) for normalised weights w (1 <= N_eff <= N)."""
    w = np.asarray(weights, dtype=np.float64)
    return float(1.0 / np.sum(w * w))


class Weighting(ABC):
    """Interface: `update(log_weights (N,), scores (N,)) -> normalised log-weights (N,)`."""

    underflows: int = 0

    @abstractmethod
    def update(self, log_weights: FloatArray, scores: FloatArray) -> FloatArray:
        ...


class LinearWeighting(Weighting):
    """w *= corr, normalised by the sum. Negative correlations count as 0."""

    def __init__(self) -> None:
        self.underflows = 0

    def update(self, log_weights: FloatArray, scores: FloatArray) -> FloatArray:
        w = np.exp(np.asarray(log_weights, dtype=np.float64)) * np.clip(np.asarray(scores, dtype=np.float64), 0.0, None)
        total = float(np.sum(w))
        if not (np.isfinite(total) and total > 0.0):
            # Every product w_i * corr_i fell below the smallest float64 (~1e-308) or every
            # correlation was 0: there is nothing left to normalise. Uniform weights keep the
            # filter alive (it loses its history, like a forced resample) and we say so.
            self.underflows += 1
            msg = (
                "linear weighting underflowed: every particle's weight * correlation is 0 in "
                f"float64 (sum={total!r}); falling back to uniform weights "
                f"(occurrence {self.underflows}). Use weighting=logsumexp to avoid this."
            )
            if self.underflows == 1:
                warnings.warn(msg, WeightUnderflowWarning, stacklevel=2)
            log.warning(msg)
            n = w.shape[0]
            return np.full(n, -np.log(n))
        with np.errstate(divide="ignore"):
            return np.log(w / total)


class LogSumExpWeighting(Weighting):
    """log w += corr / temperature, normalised with log-sum-exp (never underflows).

    `temperature` is in score units: a particle whose score is `temperature` lower than the
    best's gets e (2.718) times less weight from this step.
    """

    def __init__(self, temperature: float = 1.0) -> None:
        self.temperature = require_positive(GROUP, "temperature", temperature)
        self.underflows = 0

    def update(self, log_weights: FloatArray, scores: FloatArray) -> FloatArray:
        lw = np.asarray(log_weights, dtype=np.float64) + np.asarray(scores, dtype=np.float64) / self.temperature
        return lw - logsumexp(lw)
