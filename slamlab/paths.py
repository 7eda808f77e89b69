"""Where slamlab finds shared data and keeps its caches. One setting each, from the environment."""

from __future__ import annotations

import os
from pathlib import Path

DATA_DIR_ENV = "SLAMLAB_DATA_DIR"
CACHE_DIR_ENV = "SLAMLAB_CACHE_DIR"


def data_dir() -> Path | None:
    """The shared real-data folder (`SLAMLAB_DATA_DIR`, else `../shared/data` next to a
    source checkout), or None if neither exists."""
    env = os.environ.get(DATA_DIR_ENV)
    if env:
        return Path(env).expanduser().resolve()
    guess = Path(__file__).resolve().parents[2] / "shared" / "data"
    return guess if guess.is_dir() else None


def cache_dir() -> Path:
    """Where generated simulated sequences are cached (`SLAMLAB_CACHE_DIR`, else
    `$XDG_CACHE_HOME/slamlab`, else `~/.cache/slamlab`)."""
    env = os.environ.get(CACHE_DIR_ENV)
    if env:
        return Path(env).expanduser().resolve()
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg) if xdg else Path.home() / ".cache"
    return (base / "slamlab").resolve()
