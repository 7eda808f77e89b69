"""A per-particle odometry scale learnt from the matcher's corrections (`motion.scale_gain_per_m`).

Odometry that over- or under-counts distance by a few per cent (a walking robot's step
length, a wheel's radius) drifts down long corridors: the matcher's motion prior is centred
on the odometry's prediction, and where the walls give little along-track evidence the
estimate follows the prediction, a few millimetres too far every step, and the particle's
own map creeps with it.

So each particle carries a scale s (1 at the start) that multiplies the translation of its
odometry increments, and after matching s moves towards what the particle really moved:

    s <- s + g * (a - s * d)

with d the odometry's distance (m) over the step, a the particle's displacement along the
odometry's direction (m, from its pose before the step to its matched pose) and g the gain
(1/m; 1/g is the distance over which s averages). Where the map says nothing along-track
the match keeps the prediction, a = s d on average, and s stays; where it does (doors,
corners, rooms) s learns the odometry's scale and the prediction stops drifting. Where the
map says nothing, each step's motion noise and match jitter still move s a little (a random
walk of about g times the along-track noise per step), which the average over 1/g metres
keeps small. A step without scan points (no match) teaches nothing. The scale is part of a
particle's state: resampling copies it with the pose.
"""

from __future__ import annotations

import numpy as np

from slamlab.geometry import FloatArray, se2_compose

SCALE_LIMITS = (0.8, 1.25)  # scales are pinned inside: odometry this far off is a broken log, not a scale


def scaled_start(poses: FloatArray, scales: FloatArray, increment: FloatArray) -> FloatArray:
    """`poses` (N, 3) moved by (s - 1) times the increment's translation in their own frame,
    so that the motion model's unscaled increment from there lands at s times the
    translation (the increment's rotation comes after its translation, so the two compose
    exactly)."""
    u = np.asarray(increment, dtype=np.float64)
    extra = np.zeros_like(poses)
    extra[:, 0] = (scales - 1.0) * u[0]
    extra[:, 1] = (scales - 1.0) * u[1]
    return se2_compose(poses, extra)


def learn_scales(scales: FloatArray, before: FloatArray, after: FloatArray, increment: FloatArray,
                 gain_per_m: float) -> FloatArray:
    """The scales after a step: `before` (N, 3) the poses at the start of the step, `after`
    (N, 3) the matched poses, `increment` (3,) the odometry's (x m, y m, theta rad) in the
    robot frame. A step without translation (a turn on the spot) leaves them as they are."""
    u = np.asarray(increment, dtype=np.float64)
    d = float(np.hypot(u[0], u[1]))
    if d < 1e-6:
        return scales
    ux, uy = u[0] / d, u[1] / d  # the odometry's direction in the robot frame
    c, s = np.cos(before[:, 2]), np.sin(before[:, 2])
    dx = after[:, 0] - before[:, 0]
    dy = after[:, 1] - before[:, 1]
    along = (c * dx + s * dy) * ux + (-s * dx + c * dy) * uy  # displacement along it (m)
    g = min(gain_per_m * d, 1.0)  # a step longer than 1/g takes the step's own ratio
    return np.clip(scales + g * (along / d - scales), *SCALE_LIMITS)
