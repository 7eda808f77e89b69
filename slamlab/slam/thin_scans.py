"""Scans with too little in them to match: where a run's path rests on odometry alone.

A 2D lidar in open space (a car park, a campus lawn, a hall wider than its range) returns
nothing on most beams. Scan matching then has a handful of points to hold a pose on, the
path there is the odometry's, and a loop through such a stretch may not close. Nothing in
the map contradicts itself when the second pass lies where the first never mapped, so the
consistency verdict (`eval.consistency`) cannot see it: a probe with a 5.6 m Hokuyo URG
driven through the simulated campus (`benchmarks/sim_carmen.py --layout campus --lidar urg`)
has fewer than 20 returns in 71 % of its steps, its longest such stretch 82 m; its relation
error is 11 m, worse than the odometry's 8 m, and its verdict "consistent". So a run says so
itself: `thin_stretches` finds the processed steps whose scan has fewer than `THIN_RETURNS`
usable returns (the points the matcher gets: valid beams within the run's range limits,
above the ground threshold where the sequence knows the body's height) and the longest
stretch of them, from the last step with enough returns before it to the first one after
it (the path the odometry alone carries). A run in `mode=slam` warns, and metrics.json lists
`thin_scans`, when such steps are `WARN_SHARE` of its steps or more, or a stretch is `WARN_M`
or longer (with steps 5 m or more apart, one thin step is such a stretch). Intel, ACES and the
Freiburg hospital have no thin scan (their fewest returns: 123, 161, 27); the SICK on the
simulated campus at the preset's steps has 0.3-1.8 % of its steps thin, the longest stretch
8.2 m (worlds 0 and 2 at 2x, world 0 at 3x): no warning.
"""

from __future__ import annotations

from collections.abc import Sequence as SequenceOf
from dataclasses import dataclass

import numpy as np

from slamlab.frames import ScanFrame
from slamlab.geometry import FloatArray
from slamlab.slam.scan import scans_to_points

CHUNK = 512  # scans projected at once to count their points
THIN_RETURNS = 20  # a scan with fewer usable returns than this gives scan matching too little to hold a pose on
WARN_SHARE = 0.05  # warn when this share of the processed steps is thin ...
WARN_M = 10.0  # ... or when the odometry alone carries the path this far (m) between two steps with enough returns


@dataclass(frozen=True, slots=True)
class ThinScans:
    """The processed steps whose scan had fewer than `THIN_RETURNS` usable returns: how many,
    their `share` of the steps, and the longest stretch of consecutive ones, measured between
    the steps with enough returns around it (the path the odometry alone carries): `longest_m`
    of odometry path, from `from_s` to `to_s` (s since the run's first scan)."""

    steps: int
    share: float
    longest_m: float
    from_s: float
    to_s: float

    @property
    def worth_a_warning(self) -> bool:
        return self.share >= WARN_SHARE or self.longest_m >= WARN_M

    def as_dict(self) -> dict:
        """As metrics.json's `thin_scans` lists it."""
        return {"steps": self.steps, "share": self.share, "min_returns": THIN_RETURNS, "longest_m": self.longest_m,
                "from_s": self.from_s, "to_s": self.to_s}


def usable_returns(scans: SequenceOf[ScanFrame], which: np.ndarray, body_height_m: float | None, min_m: float, max_m: float,
                   ground_threshold_m: float) -> np.ndarray:
    """(K,) int: for the scans `which` (indices), the points the matcher gets from each
    (`scan.scans_to_points` with the run's range limits, m, and ground threshold)."""
    out = np.empty(len(which), dtype=np.int64)
    for a in range(0, len(which), CHUNK):
        frames = [scans[int(i)] for i in which[a:a + CHUNK]]
        out[a:a + len(frames)] = [len(p.xy) for p in scans_to_points(frames, body_height_m, min_m, max_m, ground_threshold_m)]
    return out


def thin_stretches(returns: np.ndarray, step_scans: np.ndarray, odom: FloatArray, times: FloatArray) -> ThinScans | None:
    """The thin steps among the processed steps `step_scans` (K,) (scan indices into `odom`
    (N, 3) and `times` (N,) s), whose scans had `returns` (K,) usable returns; None when none is thin."""
    thin = returns < THIN_RETURNS
    if not thin.any():
        return None
    path = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(odom[:, :2], axis=0).T))])  # odometry path length at each scan (m)
    at = path[step_scans]
    edges = np.flatnonzero(np.diff(np.concatenate([[0], thin.astype(np.int8), [0]])))
    best = (-1.0, 0, 0)
    for a, b in zip(edges[::2], edges[1::2]):  # thin steps a..b-1; the steps with enough returns around them: a-1 and b
        lo, hi = max(a - 1, 0), min(b, len(thin) - 1)
        if at[hi] - at[lo] > best[0]:
            best = (float(at[hi] - at[lo]), lo, hi)
    longest_m, lo, hi = best
    return ThinScans(steps=int(thin.sum()), share=float(thin.mean()), longest_m=longest_m,
                     from_s=float(times[step_scans[lo]] - times[0]), to_s=float(times[step_scans[hi]] - times[0]))
