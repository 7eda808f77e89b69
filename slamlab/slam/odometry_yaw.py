"""A learnt odometry yaw drift for the graph's local SLAM (`filter.yaw_drift_gain_per_m`).

Wheel odometry often turns a steady few degrees too little or too much per metre driven (wheels
of slightly different size, a tyre's pressure): Intel's turns 3.3 degrees a metre less than the
robot did, in every tenth of the log. Where a node's match pins the yaw (rooms, corners) the
bias costs nothing. Where it does not (down a street whose scans keep 50-70 points, mostly
trees and far walls ahead on one side) a turn about the robot and a sideways shift score alike,
the match stays near the predicted yaw, and the online heading takes on the bias: the campus
probe at 0.25 m steps gained 17 degrees in 25 m (benchmarks/RESULTS.md).

So local SLAM keeps a drift b (rad per metre, 0 at the start), adds b x d to each step's
predicted turn (d: the step's odometry distance, m) and after the match moves b towards what
the match saw:

    b <- b + min(g d, 1) x (seen - b d) / d

with seen the match's turn over the step less the odometry's (rad) and g the gain (1/m; 1/g is
the distance over which b averages). Where the scans pin the yaw b learns the odometry's bias;
where they do not, the match keeps the prediction (seen = b d) and b stays, so the prediction
carries what the well-pinned stretches taught. A turn on the spot (d = 0) teaches nothing.
The scans between steps (`steps.between=match`) are still predicted from the odometry's own turn
since their step: a fraction of a step, which their match on the online map absorbs.
"""

from __future__ import annotations

from slamlab.geometry import wrap_angle

YAW_DRIFT_LIMIT = 0.1  # rad per metre (5.7 degrees): odometry further off than this is a broken log, not a bias


def learn_yaw_drift(drift: float, matched_turn: float, odometry_turn: float, distance_m: float, gain_per_m: float) -> float:
    """The drift (rad/m) after a step: `matched_turn` the match's turn over the step (rad),
    `odometry_turn` the odometry's (rad), `distance_m` the odometry's distance (m)."""
    if distance_m < 1e-6 or gain_per_m <= 0:
        return drift
    seen = float(wrap_angle(matched_turn - odometry_turn - drift * distance_m))  # what the prediction missed (rad)
    learnt = drift + min(gain_per_m * distance_m, 1.0) * seen / distance_m
    return min(max(learnt, -YAW_DRIFT_LIMIT), YAW_DRIFT_LIMIT)
