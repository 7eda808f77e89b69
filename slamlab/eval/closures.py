"""Loop closures against the ground truth (simulated data): how many accepted closures are wrong.

A closure says where node i's scan is, seen from its anchor node a's. The true poses of both
scans give the true relative pose, and the closure's error is the one seen from the other,
`se2_between(true, closure)`: in node i's frame, the frame of the closure's covariance. A
match down a corridor pins nothing along the corridor (its covariance is metres wide there)
and the graph takes no pull from it there, so such a closure is not wrong for being off along
the corridor: its translation error counts only in the directions it pins (sigma below
`WRONG_M`). Wrong: off by more than `WRONG_M` there, or by more than `WRONG_DEG` in yaw.
A wrong closure that the verification let in is what bends a map (the graph's robust loss
weakens it, it does not remove it); on simulated data this count shows it directly, where
on a real log only the consistency verdict can (slamlab.eval.consistency).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from slamlab.geometry import FloatArray, se2_between, wrap_angle
from slamlab.slam.graph.loops import ACCEPTED

WRONG_M = 0.3  # m, in the directions a closure pins
WRONG_DEG = 5.0  # degrees of yaw


def pinned_error_m(error_xy: FloatArray, covariance_xy: FloatArray, pinned_sigma_m: float = WRONG_M) -> float:
    """The length (m) of `error_xy` (2,) in the directions where `covariance_xy` (2, 2, m^2)
    has a sigma below `pinned_sigma_m`: 0 along a corridor match's free direction."""
    w, v = np.linalg.eigh(np.asarray(covariance_xy, dtype=np.float64))
    pinned = v[:, np.sqrt(np.maximum(w, 0.0)) < pinned_sigma_m]
    return float(np.linalg.norm(pinned.T @ np.asarray(error_xy, dtype=np.float64)))


def closure_truth(candidates: Sequence, node_scans: np.ndarray, truth: FloatArray) -> dict:
    """`metrics.json`'s `loop_truth`: of the accepted `candidates` (`LoopCandidate`: anchor,
    node, relative, covariance, status), how many are wrong (module doc), and the largest
    errors. `node_scans[k]`: node k's scan index; `truth` (scans, 3): the true poses."""
    accepted = [c for c in candidates if c.status == ACCEPTED]
    out = {"accepted": len(accepted), "wrong": 0, "worst_m": 0.0, "worst_deg": 0.0, "wrong_m": WRONG_M, "wrong_deg": WRONG_DEG}
    if not accepted:
        return out
    scans = np.asarray(node_scans)
    anchors = scans[np.array([c.anchor for c in accepted])]
    nodes = scans[np.array([c.node for c in accepted])]
    true_rel = se2_between(truth[anchors], truth[nodes])
    error = se2_between(true_rel, np.array([c.relative for c in accepted]))
    off_m = np.array([pinned_error_m(e[:2], c.covariance[:2, :2]) for e, c in zip(error, accepted)])
    off_deg = np.degrees(np.abs(wrap_angle(error[:, 2])))
    out.update(wrong=int(np.count_nonzero((off_m > WRONG_M) | (off_deg > WRONG_DEG))),
               worst_m=float(off_m.max()), worst_deg=float(off_deg.max()))
    return out
