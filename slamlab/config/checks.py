"""Range checks for config values, shared by every schema in `slamlab.config`.

Each check knows the config group (e.g. ``resampler``) so that a bad value is reported with
the full key a user typed (``resampler.threshold``), not a Python stack trace.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

from slamlab.errors import ConfigError


def require_positive(group: str, name: str, value: float) -> float:
    """Return `value` as float if it is finite and > 0, else raise ConfigError(group.name)."""
    v = _number(group, name, value)
    if not v > 0.0:
        raise ConfigError(_key(group, name), f"must be > 0, got {value!r}")
    return v


def require_nonnegative(group: str, name: str, value: float) -> float:
    """Return `value` as float if it is finite and >= 0, else raise ConfigError(group.name)."""
    v = _number(group, name, value)
    if not v >= 0.0:
        raise ConfigError(_key(group, name), f"must be >= 0, got {value!r}")
    return v


def require_fraction(group: str, name: str, value: float) -> float:
    """Return `value` if it lies in (0, 1], else raise ConfigError(group.name)."""
    v = _number(group, name, value)
    if not 0.0 < v <= 1.0:
        raise ConfigError(_key(group, name), f"must be in (0, 1], got {value!r}")
    return v


def require_int(group: str, name: str, value: int | None, minimum: int, allow_none: bool = False) -> int | None:
    """Return `value` as int if it is an integer >= minimum (or None when allowed), else
    raise ConfigError(group.name)."""
    if value is None and allow_none:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ConfigError(_key(group, name), f"must be an integer >= {minimum}{' or null' if allow_none else ''}, got {value!r}")
    return int(value)


def require_bool(group: str, name: str, value: object) -> bool:
    """Return `value` if it is a bool, else raise ConfigError(group.name)."""
    if not isinstance(value, bool):
        raise ConfigError(_key(group, name), f"must be true or false, got {value!r}")
    return value


def require_choice(group: str, name: str, value: object, choices: Iterable[object]) -> object:
    """Return `value` if it is one of `choices`, else raise ConfigError(group.name)."""
    choices = tuple(choices)
    if value not in choices:
        raise ConfigError(_key(group, name), f"must be one of {', '.join(map(str, choices))}, got {value!r}")
    return value


def _key(group: str, name: str) -> str:
    return f"{group}.{name}" if group else name  # run-level keys (particles, seed) have no group


def _number(group: str, name: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ConfigError(_key(group, name), f"must be a finite number, got {value!r}")
    return float(value)
