"""Odometry that jumps: a reset of the odometry's frame in the middle of a log, not motion.

A robot base whose driver restarts, or a log stitched from two recordings without a pause
between them, hands on its odometry in a new frame: between two consecutive scans the
odometry moves metres or turns further than a robot moves in the time of a scan. Taken as
motion, that one increment throws every filter's prediction metres off, the scans after it
are matched where the map has nothing, and the building is drawn twice (a probe log
re-zeroed once at 400 s: 0.029 -> 8.27 m relation error; `benchmarks/RESULTS.md`,
2026-12-01). Two recordings joined across a pause of seconds look like driving and stay
motion.

`bridge_jumps` takes each such increment as no motion: every pose from the jump on is moved
rigidly so that the scan after the jump starts where the scan before it was. The increments
after it, which is all the filters read, are kept; the matcher's motion prior and the loop
search take up whatever the robot truly moved across the jump. A jump is an increment
between consecutive scans (file order) longer than `max_m` (m) and faster than
`JUMP_SPEED_MPS`, or turning more than `max_rad` (rad) and faster than `JUMP_TURN_RPS`, over
the time between the two scans: `steps.odom_jump_m` / `steps.odom_jump_rad` (0 turns either
test off). The speeds keep a gap in the log from being taken for a jump: a probe log with
10 s of records cut out moves 3.5 m and turns 80 degrees between two scans, which the robot
did drive (taken as a jump, that run ended 13 m off). The real logs' largest increments are
far below the defaults (Intel 0.22 m / 0.28 rad, ACES 0.38 m / 1.06 rad, the Freiburg
hospital 0.27 m / 0.37 rad), so their runs are unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slamlab.geometry import FloatArray, se2_between, se2_compose, se2_inverse, wrap_angle


JUMP_SPEED_MPS = 10.0  # an increment past `max_m` is a jump only if it is also faster than this (m/s) ...
JUMP_TURN_RPS = 2 * np.pi  # ... and one past `max_rad` only if it turns faster than a turn a second
BLEND_M = 0.1  # the increment beside a jump is part of it when it differs from the next one out by more than
BLEND_RAD = 0.1  # this (m, rad): a robot's motion does not change that much from one scan to the next


@dataclass(frozen=True, slots=True)
class OdometryJump:
    """One bridged jump: the odometry's increment from scan `scan - 1` to `scan` (the run's
    scans in file order, counted from 0: a CARMEN log's or THOR sequence's scan index),
    `m` metres and `rad` radians (absolute), at scan `scan`'s time `t_s` (s)."""

    scan: int
    t_s: float
    m: float
    rad: float

    def as_dict(self) -> dict:
        """The jump as metrics.json's `odometry_jumps` lists it."""
        return {"scan": self.scan, "t_s": self.t_s, "m": self.m, "deg": float(np.degrees(self.rad))}


def _beyond(steps: FloatArray, max_m: float, max_rad: float) -> np.ndarray:
    """Which increments `steps` (K, 3) are longer than `max_m` or turn more than `max_rad` (0: not tested)."""
    out = np.zeros(len(steps), dtype=bool)
    if max_m > 0:
        out |= np.hypot(steps[:, 0], steps[:, 1]) > max_m
    if max_rad > 0:
        out |= np.abs(wrap_angle(steps[:, 2])) > max_rad
    return out


def find_jumps(odom: FloatArray, times: FloatArray, max_m: float, max_rad: float) -> list[OdometryJump]:
    """The increments of `odom` (N, 3) between consecutive poses that are part of a jump, with
    the later scan's time from `times` (N,) s. An increment is fast when it moves or turns
    faster than a robot does (`JUMP_SPEED_MPS`, `JUMP_TURN_RPS`) over the time between its
    scans (file order: a log's stamps may run backwards, so the time apart is taken as it
    comes, absolute). A jump is a fast increment longer than `max_m` or turning more than
    `max_rad` (either 0: not tested), or two fast increments in a row that are together (a
    reset that odometry interpolated at the scans' stamps, as a ROS bag's is, splits over the
    scan that falls between the frames); and the increment beside a jump is part of it when
    it differs from the one beyond it by more than `BLEND_M` or `BLEND_RAD` (the rest of a
    reset blended unevenly)."""
    if len(odom) < 2 or (max_m <= 0 and max_rad <= 0):
        return []
    inc = se2_between(odom[:-1], odom[1:])
    step_m = np.hypot(inc[:, 0], inc[:, 1])
    turn = np.abs(wrap_angle(inc[:, 2]))
    apart_s = np.abs(np.diff(np.asarray(times, dtype=np.float64)))
    fast = np.zeros(len(inc), dtype=bool)
    if max_m > 0:
        fast |= step_m > JUMP_SPEED_MPS * apart_s
    if max_rad > 0:
        fast |= turn > JUMP_TURN_RPS * apart_s
    jumped = fast & _beyond(inc, max_m, max_rad)
    if len(inc) >= 2:
        pair = fast[:-1] & fast[1:] & _beyond(se2_between(odom[:-2], odom[2:]), max_m, max_rad)
        jumped[:-1] |= pair
        jumped[1:] |= pair
    for i in np.flatnonzero(jumped):
        for beside, far in ((i - 1, i - 2), (i + 1, i + 2)):  # the increment beside a jump, the next one out
            if 0 <= beside < len(inc) and not jumped[beside]:
                usual = inc[far] if 0 <= far < len(inc) else np.zeros(3)
                d = inc[beside] - usual
                jumped[beside] |= bool(np.hypot(d[0], d[1]) > BLEND_M or abs(wrap_angle(d[2])) > BLEND_RAD)
    return [OdometryJump(int(i) + 1, float(times[i + 1]), float(step_m[i]), float(turn[i])) for i in np.flatnonzero(jumped)]


def bridge_jumps(odom: FloatArray, jumps: list[OdometryJump]) -> FloatArray:
    """`odom` (N, 3) with each jump's increment made no motion: the poses from each jump on
    moved rigidly onto the pose before it. Without jumps, `odom` itself (the same bits)."""
    if not jumps:
        return odom
    out = np.array(odom, dtype=np.float64, copy=True)
    for jump in jumps:  # in scan order: each correction carries the ones before it
        j = jump.scan
        correction = se2_compose(out[j - 1], se2_inverse(out[j]))  # takes pose j onto pose j - 1
        out[j:] = se2_compose(correction, out[j:])
    return out
