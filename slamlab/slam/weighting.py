"""Update: turn per-particle match scores into normalised weights.

The engine keeps log-weights; each scheme returns new normalised log-weights.
- `LinearWeighting`: the course's `w *= corr`, then divide by the sum. In float64 the product
  of many correlations (or of tiny weights and correlations) can underflow to all-zero;
  then the update cannot be normalised. Instead of crashing or producing NaN, it warns once
  with the reason, counts the event (`underflows`) and falls back to uniform weights.
- `LinearExpWeighting`: `w *= exp(corr / temperature)` in linear space, then divide by the
  sum: the same model as log-sum-exp (the correlation is a log-likelihood) computed the naive
  way. exp(corr) overflows float64 for corr > 709.8, which THOR scans (about 1,000 beams,
  hundreds of hits) reach at every step; the product or its sum can also underflow. Either
  way the update cannot be normalised: it warns once, counts the event (`overflows`,
  `underflows`) and falls back to uniform weights, like `LinearWeighting`. Where it stays
  finite it gives the same weights as `LogSumExpWeighting` (up to rounding).
- `LogSumExpWeighting`: `log w += corr / temperature`, normalised with log-sum-exp, which
  never underflows: the best particle always keeps log-weight >= -log N.

Which observation model each implements: `linear` says p(scan | pose) is proportional to
the correlation (the course's "easy, slightly incorrect" w *= corr); `linear_exp` and
`logsumexp` say it is proportional to exp(correlation) ("easy, correct"), and only
`logsumexp` computes that safely.

Adding a scheme: subclass `Weighting`, implement `update`, add its schema
(`slamlab.config.slam`, listed in `slamlab.config.SCHEMAS`) and `conf/weighting/NAME.yaml`.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import logging
import warnings

import numpy as np

from slamlab.config.slam import LinearExpWeightingConfig as _LinExp
from slamlab.config.slam import LogSumExpWeightingConfig as _LogSumExp
from slamlab.geometry import FloatArray
from slamlab.numeric import OVERFLOW_SCORE  # noqa: F401  (exp(x) is inf in float64 above it; the report explains it too)
log = logging.getLogger(__name__)


class WeightUnderflowWarning(RuntimeWarning):
    """A linear-space weighting lost every particle's weight to floating-point underflow or
    overflow and fell back to uniform weights."""


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
    """Interface: `update(log_weights (N,), scores (N,)) -> normalised log-weights (N,)`.

    `underflows` / `overflows`: updates that could not be normalised in floating point and
    fell back to uniform weights (only the linear-space schemes can have them)."""

    underflows: int = 0
    overflows: int = 0

    @abstractmethod
    def update(self, log_weights: FloatArray, scores: FloatArray) -> FloatArray:
        ...


def _uniform_fallback(scheme: Weighting, n: int, what: str, detail: str, count: int) -> FloatArray:
    """Uniform log-weights after a failed linear-space update, with a warning the first time
    and a debug line after (on THOR scans linear_exp fails at every step; the engine logs the
    totals). Uniform weights keep the filter alive (it loses its history, like a forced
    resample) and the counts say so in metrics.json."""
    msg = (
        f"{type(scheme).__name__} {what}: {detail}; falling back to uniform weights "
        f"(occurrence {count}). Use weighting=logsumexp to avoid this."
    )
    if count == 1:
        warnings.warn(msg, WeightUnderflowWarning, stacklevel=3)
        log.warning(msg)
    else:
        log.debug(msg)
    return np.full(n, -np.log(n))


def _normalised(scheme: Weighting, w: FloatArray, total: float, product: str) -> FloatArray:
    """log(w / total) for linear-space weights `w` with sum `total`; when the sum is 0 (every
    product underflowed, or every correlation was 0) there is nothing to normalise: count it
    on `scheme.underflows` and fall back to uniform weights. `product` names what was
    multiplied, for the message."""
    if not (np.isfinite(total) and total > 0.0):
        scheme.underflows += 1
        detail = f"every particle's weight * {product} is 0 in float64 (sum={total!r})"
        return _uniform_fallback(scheme, w.shape[0], "underflowed", detail, scheme.underflows)
    with np.errstate(divide="ignore"):
        return np.log(w / total)


class LinearWeighting(Weighting):
    """w *= corr, normalised by the sum. Negative correlations count as 0."""

    def __init__(self) -> None:
        self.underflows = 0

    def update(self, log_weights: FloatArray, scores: FloatArray) -> FloatArray:
        w = np.exp(np.asarray(log_weights, dtype=np.float64)) * np.clip(np.asarray(scores, dtype=np.float64), 0.0, None)
        # products below the smallest float64 (~1e-308) underflow to 0
        return _normalised(self, w, float(np.sum(w)), "correlation")


class LinearExpWeighting(Weighting):
    """w *= exp(corr / temperature) in linear space, normalised by the sum (see module doc).

    `temperature` as in `LogSumExpWeighting`. Overflow (exp or the sum is inf) and
    underflow (the sum is 0) are counted separately and replaced by uniform weights."""

    def __init__(self, temperature: float = _LinExp.temperature) -> None:  # checked by LinearExpWeightingConfig
        self.temperature = float(temperature)
        self.underflows = 0
        self.overflows = 0

    def update(self, log_weights: FloatArray, scores: FloatArray) -> FloatArray:
        with np.errstate(over="ignore", under="ignore", invalid="ignore"):
            likelihood = np.exp(np.asarray(scores, dtype=np.float64) / self.temperature)
            w = np.exp(np.asarray(log_weights, dtype=np.float64)) * likelihood
            total = float(np.sum(w))
        if not np.isfinite(total):
            self.overflows += 1
            detail = (f"exp(correlation) overflows float64 above {OVERFLOW_SCORE:.1f} (largest correlation "
                      f"{float(np.max(scores)):.1f}, temperature {self.temperature:g}), so the weights are inf/inf")
            return _uniform_fallback(self, w.shape[0], "overflowed", detail, self.overflows)
        return _normalised(self, w, total, "exp(correlation)")


class LogSumExpWeighting(Weighting):
    """log w += corr / temperature, normalised with log-sum-exp (never underflows).

    `temperature` is in score units: a particle whose score is `temperature` lower than the
    best's gets e (2.718) times less weight from this step.
    """

    def __init__(self, temperature: float = _LogSumExp.temperature) -> None:  # checked by LogSumExpWeightingConfig
        self.temperature = float(temperature)
        self.underflows = 0

    def update(self, log_weights: FloatArray, scores: FloatArray) -> FloatArray:
        lw = np.asarray(log_weights, dtype=np.float64) + np.asarray(scores, dtype=np.float64) / self.temperature
        return lw - logsumexp(lw)
