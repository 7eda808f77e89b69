"""Timestamps, for every dataset: the one nearest-time lookup, and checks on scan stamps.

Relations files and RGB-D frames are matched to scans by time (`nearest_index`,
`nearest_pair`); scans that share one timestamp exactly cannot be told apart that way, so a
log whose stamps all repeat, or repeat over long runs, deserves a warning before a long run.
"""

from __future__ import annotations

import numpy as np

LONG_RUN = 5  # this many consecutive scans with one timestamp is not rounding, the clock stopped


def nearest_pair(sorted_t: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each time in `t` (s): the index of the nearest entry of `sorted_t` (s, ascending,
    non-empty; ties go to the earlier entry) and the index of the entry on its other side
    (the next nearest of the two that bracket it; the same index when `sorted_t` has one entry)."""
    t = np.asarray(t)
    n = sorted_t.size
    # (lo, hi) bracket t; outside the span they are the first or last two entries.
    hi = np.clip(np.searchsorted(sorted_t, t), 1, max(n - 1, 1))
    lo = hi - 1
    hi = np.minimum(hi, n - 1)
    take_lo = np.abs(t - sorted_t[lo]) <= np.abs(sorted_t[hi] - t)
    return np.where(take_lo, lo, hi), np.where(take_lo, hi, lo)


def nearest_index(sorted_t: np.ndarray, t: np.ndarray) -> np.ndarray:
    """For each time in `t` (s), the index of the nearest entry of `sorted_t` (s, ascending,
    non-empty); ties go to the earlier entry."""
    return nearest_pair(sorted_t, t)[0]


def repeated_stamps(times: np.ndarray, name: str) -> str | None:
    """A warning for `times` (s, file order) of sequence `name`, or None when they are fine."""
    t = np.asarray(times, dtype=np.float64)
    if t.size < 2:
        return None
    same = np.diff(t) == 0
    if same.all():
        return (f"{name}: all {t.size} scans have the same timestamp {t[0]:.6f}; relations and RGB-D "
                "frames cannot be matched to scans by time")
    # lengths of runs of equal consecutive stamps (in scans)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], same.astype(np.int8), [0]])))
    starts, ends = edges[::2], edges[1::2]  # same[start:end] all True: scans start..end share a time
    lengths = ends - starts + 1
    long = lengths >= LONG_RUN
    if not long.any():
        return None
    k = int(np.argmax(lengths))
    return (f"{name}: {int(lengths[long].sum())} scans in {int(long.sum())} run(s) of {LONG_RUN} or more repeat "
            f"one timestamp (longest: scans {starts[k]}-{ends[k]}, {lengths[k]} scans at {t[starts[k]]:.6f}); "
            "relations and RGB-D frames cannot be matched to scans by time there")
