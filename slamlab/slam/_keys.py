"""Small helpers every component uses to check its own config values.

Each component knows its config group (e.g. ``resampler``) so that a bad value is reported
with the full key a user typed (``resampler.threshold``), not a Python stack trace.
"""

from __future__ import annotations

import math

from slamlab.errors import ConfigError


def require_positive(group: str, name: str, value: float) -> float:
    """Return `value` as float if it is finite and > 0, else raise ConfigError(group.name)."""
    v = _number(group, name, value)
    if not v > 0.0:
        raise ConfigError(f"{group}.{name}", f"must be > 0, got {value!r}")
    return v


def require_nonnegative(group: str, name: str, value: float) -> float:
    """Return `value` as float if it is finite and >= 0, else raise ConfigError(group.name)."""
    v = _number(group, name, value)
    if not v >= 0.0:
        raise ConfigError(f"{group}.{name}", f"must be >= 0, got {value!r}")
    return v


def require_fraction(group: str, name: str, value: float) -> float:
    """Return `value` if it lies in (0, 1], else raise ConfigError(group.name)."""
    v = _number(group, name, value)
    if not 0.0 < v <= 1.0:
        raise ConfigError(f"{group}.{name}", f"must be in (0, 1], got {value!r}")
    return v


def require_int(group: str, name: str, value: int, minimum: int) -> int:
    """Return `value` as int if it is an integer >= minimum, else raise ConfigError(group.name)."""
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ConfigError(f"{group}.{name}", f"must be an integer >= {minimum}, got {value!r}")
    return int(value)


def _number(group: str, name: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ConfigError(f"{group}.{name}", f"must be a finite number, got {value!r}")
    return float(value)
