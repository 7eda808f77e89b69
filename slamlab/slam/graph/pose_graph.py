"""The pose graph: nodes (one per processed scan) joined by the local matches and the loop
closures, optimised with GTSAM (`gtsam.BetweenFactorPose2`; ISAM2, Kaess et al. 2012; and
Levenberg-Marquardt).

- Node k follows node k-1 by local SLAM's relative pose (a `BetweenFactorPose2` whose sigma
  grows with the step: `local_sigma_m + local_sigma_per_m x distance`, likewise in yaw; plus
  the slack local SLAM reports where its match pinned nothing);
  node 0 is held by a prior at the start pose.
- A loop closure is a `BetweenFactorPose2` from a submap's anchor node to the node whose scan
  matched it, under a robust loss (Cauchy by default): a residual of r sigmas weighs
  1 / (1 + r^2), so a closure left metres off by the others pulls with almost nothing.
- `update` hands the new nodes and closures to ISAM2, which keeps the optimum up to date
  incrementally (a new node or a closure re-solves only the part of the graph it touches):
  the estimate of the newest node after each update is the graph's online answer.
- `optimise_batch` runs Levenberg-Marquardt over the whole graph and restarts ISAM2 from the
  result. When a verified group of closures asks for a correction (`trusted`), it first takes
  that group in as it says: one LM run with those closures' plain Gaussian noise (the others
  under the loss), then the run under the loss from there. From the drifted estimate alone,
  under the loss, closures tens of sigmas off weigh less than bending the path and the
  closures that hold its drifted shape: LM stops with the loop open, and the group would be
  pruned (ACES at 1 m steps: a 1.4 m return left open). LAGO (orientations, then positions,
  without the loss) was the start before: it takes no robust loss and only diagonal sigmas, so
  a corridor match's covariance, long across the node's axes, pulled along the corridor, and
  the start it gave broke half the earlier closures (ACES at 1 m steps, a 3.8 m return).
The estimate of every node is kept as an (N, 3) array (x m, y m, yaw rad): the newest node
after every update, all of them after `refresh` and `optimise_batch`.
"""

from __future__ import annotations

import time
from collections.abc import Collection
from dataclasses import dataclass, replace

import gtsam
import numpy as np

from slamlab.geometry import FloatArray, se2_between, se2_compose, wrap_angle
from slamlab.slam.graph.small_linalg import mahalanobis_sq, sym_eig


@dataclass(frozen=True, slots=True)
class GraphNoise:
    """The edges' sigmas and the loop closures' robust loss."""

    local_sigma_m: float
    local_sigma_per_m: float
    local_sigma_rad: float
    local_sigma_per_rad: float
    loop_sigma_m: float
    loop_sigma_rad: float
    loss: str  # cauchy | huber | none
    loss_scale: float
    local_sigma_along_per_m: float = 0.0  # in the step's own direction, where larger than local_sigma_per_m


@dataclass(frozen=True, slots=True)
class Optimisation:
    """One whole-graph optimisation: wall time (s), LM iterations (of its last run), how many
    closures it first took in as they say (`trusted`), the largest move of any node (m), and
    whether it was a trial the caller took back (`restore`): its move never reached the estimate."""

    seconds: float
    iterations: int
    trusted: int
    moved_max_m: float
    taken_back: bool = False


def _pose(p: FloatArray) -> gtsam.Pose2:
    return gtsam.Pose2(float(p[0]), float(p[1]), float(p[2]))


# ISAM2: relinearise a variable whose linear step exceeds 0.05 (m or rad), checked every 10th
# update (the relinearisation, not the solve, is skipped in between)
RELINEARIZE_THRESHOLD = 0.05
RELINEARIZE_SKIP = 10


class PoseGraph:
    """Nodes and edges (see module doc); node ids are 0, 1, 2, ... in the order added, loop
    closure ids 0, 1, 2, ... likewise."""

    def __init__(self, start: FloatArray, noise: GraphNoise) -> None:
        self.noise = noise
        self.start = np.asarray(start, dtype=np.float64).copy()
        self._x = np.zeros((1024, 3))
        self._x[0] = self.start
        self.n = 1
        self.chain: list[tuple[FloatArray, FloatArray]] = []  # (relative pose, covariance) of node k from k-1, k >= 1
        self.loops: list[tuple[int, int, FloatArray]] = []  # (anchor node, node, relative pose)
        self.loop_cov: list[FloatArray] = []  # each closure's covariance
        self._ties: np.ndarray | None = None  # `active_ties`, made when first asked for after a change
        self.active: list[bool] = []
        self._prior_noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([1e-3, 1e-3, 1e-4]))
        self._loss = {"cauchy": gtsam.noiseModel.mEstimator.Cauchy, "huber": gtsam.noiseModel.mEstimator.Huber}.get(noise.loss)
        self.optimisations: list[Optimisation] = []
        self.update_seconds = 0.0
        self._restart()

    # ---- building
    @property
    def poses(self) -> FloatArray:
        """(N, 3) the current estimate of every node (a view)."""
        return self._x[: self.n]

    def add_node(self, relative: FloatArray, slack: FloatArray | None = None) -> int:
        """A node following the last one by `relative` (its pose seen from the last node's, as
        local SLAM matched it); its estimate continues the last one's. The edge's covariance:
        the local sigmas of a step that long (module doc) plus `slack` (3, 3; the new node's
        frame), what local SLAM could not pin (down a corridor, the distance travelled along
        it). Returns its id. It reaches ISAM2 at the next `update`."""
        if self.n == len(self._x):
            self._x = np.concatenate([self._x, np.zeros_like(self._x)])
        rel = np.asarray(relative, dtype=np.float64).copy()
        nz = self.noise
        dist = float(np.hypot(rel[0], rel[1]))
        across = nz.local_sigma_m + nz.local_sigma_per_m * dist
        along = nz.local_sigma_m + max(nz.local_sigma_along_per_m, nz.local_sigma_per_m) * dist
        cov = np.diag([across**2, across**2, (nz.local_sigma_rad + nz.local_sigma_per_rad * abs(float(rel[2]))) ** 2])
        if dist > 0 and along > across:  # the step's own direction: where a match down a corridor is least sure
            u = rel[:2] / dist
            cov[:2, :2] += (along**2 - across**2) * np.outer(u, u)
        if slack is not None:
            cov = cov + slack
        k = self.n
        self._x[k] = se2_compose(self._x[k - 1], rel)
        self.chain.append((rel, cov))
        self._pending.append((False, k))
        self.n += 1
        return k

    @property
    def active_ties(self) -> np.ndarray:
        """(T, 2) int: (anchor, node) of every closure in the graph."""
        if self._ties is None:
            self._ties = np.array([(a, i) for (a, i, _), on in zip(self.loops, self.active) if on], dtype=np.int64).reshape(-1, 2)
        return self._ties

    def add_loop(self, anchor: int, node: int, relative: FloatArray, covariance: FloatArray | None = None) -> int:
        """A loop closure: `node`'s pose seen from `anchor`'s is `relative`, with `covariance`
        (3, 3; in the node's frame, m^2 and rad^2; default: the loop sigmas). Returns its id.
        It reaches ISAM2 at the next `update`."""
        if covariance is None:
            covariance = np.diag([self.noise.loop_sigma_m**2, self.noise.loop_sigma_m**2, self.noise.loop_sigma_rad**2])
        self.loops.append((int(anchor), int(node), np.asarray(relative, dtype=np.float64).copy()))
        self.loop_cov.append(np.asarray(covariance, dtype=np.float64).copy())
        self.active.append(True)
        self._ties = None
        loop = len(self.loops) - 1
        self._pending.append((True, loop))
        return loop

    def drop_loop(self, loop: int) -> None:
        """Take loop closure `loop` out of the graph (at the next `update`; its id stays)."""
        if not self.active[loop]:
            return
        self.active[loop] = False
        self._ties = None
        if loop in self._slot:
            self._removals.append(self._slot.pop(loop))
        else:  # not in ISAM2 yet
            self._pending.remove((True, loop))

    def revive_loop(self, loop: int) -> None:
        """Put a closure `drop_loop` took out back into the graph (at the next `update`)."""
        if self.active[loop]:
            return
        self.active[loop] = True
        self._ties = None
        self._pending.append((True, loop))

    # ---- solving
    def update(self) -> None:
        """Hand the new nodes and closures (and removals) to ISAM2; the newest node's estimate
        becomes ISAM2's."""
        if not self._pending and not self._removals:
            return
        t0 = time.perf_counter()
        self._submit()
        k = self.n - 1
        p = self._isam.calculateEstimatePose2(k)
        self._x[k] = (p.x(), p.y(), p.theta())
        self.update_seconds += time.perf_counter() - t0

    def refresh(self) -> None:
        """Every node's estimate from ISAM2 (after `update`)."""
        t0 = time.perf_counter()
        est = gtsam.utilities.extractPose2(self._isam.calculateEstimate())
        self._x[: len(est)] = est
        self.update_seconds += time.perf_counter() - t0

    def optimise_batch(self, trusted: Collection[int] = ()) -> Optimisation:
        """Levenberg-Marquardt over the whole graph from the current estimate, the closures
        `trusted` (ids) first taken in without the robust loss (see module doc); the estimate
        becomes the result and ISAM2 restarts from it."""
        t0 = time.perf_counter()
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(50)
        params.setRelativeErrorTol(1e-6)
        initial = self._values(self.poses)
        trust = frozenset(int(j) for j in trusted)
        if trust:
            initial = gtsam.LevenbergMarquardtOptimizer(self._full_graph(trust), initial, params).optimize()
        lm = gtsam.LevenbergMarquardtOptimizer(self._full_graph(), initial, params)
        new = gtsam.utilities.extractPose2(lm.optimize())
        new[:, 2] = wrap_angle(new[:, 2])
        moved = float(np.max(np.hypot(*(new[:, :2] - self.poses[:, :2]).T)))
        self._x[: self.n] = new
        self._restart()
        o = Optimisation(time.perf_counter() - t0, int(lm.iterations()), len(trust), moved)
        self.optimisations.append(o)
        return o

    def restore(self, poses: FloatArray, taken_back: int = 0) -> None:
        """Set every node's estimate to `poses` (N, 3) and restart ISAM2 from it (after a
        trial the caller took back); the last `taken_back` optimisations are marked as such."""
        self._x[: self.n] = poses
        self._restart()
        for j in range(max(len(self.optimisations) - taken_back, 0), len(self.optimisations)):
            self.optimisations[j] = replace(self.optimisations[j], taken_back=True)

    def loops_off(self, loops: np.ndarray, m: float, rad: float, free_along: np.ndarray | None = None) -> np.ndarray:
        """(L,) bool: which of `loops` (ids) the current estimate leaves more than `m` metres or
        `rad` radians off where they pin the pose: r^T (C + diag(m^2, m^2, rad^2))^-1 r > 1,
        r the residual, C the closure's covariance (a corridor match's residual along the
        corridor, where its covariance is metres wide, counts only past those metres).
        `free_along` (L,) bool: for these (corridor matches) the residual along the
        covariance's widest direction does not count at all."""
        if len(loops) == 0:
            return np.zeros(0, dtype=bool)
        a = np.array([self.loops[j][0] for j in loops])
        i = np.array([self.loops[j][1] for j in loops])
        z = np.array([self.loops[j][2] for j in loops])
        d = se2_between(z, se2_between(self._x[a], self._x[i]))
        d[:, 2] = wrap_angle(d[:, 2])
        cov = np.array([self.loop_cov[j] for j in loops]) + np.diag([m**2, m**2, rad**2])
        q = mahalanobis_sq(d, cov)
        if free_along is not None:
            for j in np.flatnonzero(free_along):
                # sym_eig, not np.linalg.eigh (OpenBLAS's kernels differ per CPU: small_linalg); eigenvalues ascending, the
                # last along the corridor; the residual counted in the two pinned directions only, summed in a fixed order
                w, v = sym_eig(cov[j])
                r0 = d[j, 0] * v[0, 0] + d[j, 1] * v[1, 0] + d[j, 2] * v[2, 0]
                r1 = d[j, 0] * v[0, 1] + d[j, 1] * v[1, 1] + d[j, 2] * v[2, 1]
                q[j] = r0 * r0 / w[0] + r1 * r1 / w[1]
        return q > 1.0

    # ---- internals
    def _chain_factor(self, k: int) -> gtsam.BetweenFactorPose2:
        """The local edge into node k, with its covariance."""
        rel, cov = self.chain[k - 1]
        return gtsam.BetweenFactorPose2(k - 1, k, _pose(rel), gtsam.noiseModel.Gaussian.Covariance(cov))

    def _loop_factor(self, loop: int, robust: bool = True) -> gtsam.BetweenFactorPose2:
        """Closure `loop` as a factor: its covariance, under the robust loss unless `robust`
        is False (a closure taken in as it says)."""
        a, i, z = self.loops[loop]
        gauss = gtsam.noiseModel.Gaussian.Covariance(self.loop_cov[loop])
        noise = gauss if self._loss is None or not robust else gtsam.noiseModel.Robust.Create(self._loss.Create(self.noise.loss_scale), gauss)
        return gtsam.BetweenFactorPose2(a, i, _pose(z), noise)

    def _submit(self, prior: bool = False) -> None:
        """One ISAM2 update with the pending factors (in the order they came), the new nodes'
        values and the removals; remembers each closure's factor slot."""
        factors = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        if prior:
            factors.add(gtsam.PriorFactorPose2(0, _pose(self.start), self._prior_noise))
            values.insert(0, _pose(self._x[0]))
        for is_loop, j in self._pending:
            if is_loop:
                factors.add(self._loop_factor(j))
            else:
                factors.add(self._chain_factor(j))
                values.insert(j, _pose(self._x[j]))
        result = self._isam.update(factors, values, self._removals)
        slots = list(result.getNewFactorsIndices())[1 if prior else 0:]
        for (is_loop, j), slot in zip(self._pending, slots):
            if is_loop:
                self._slot[j] = int(slot)
        self._pending: list[tuple[bool, int]] = []  # (is a closure, node or closure id) not yet in ISAM2
        self._removals: list[int] = []

    def _full_graph(self, trusted: frozenset[int] = frozenset()) -> gtsam.NonlinearFactorGraph:
        """Every node and active closure; the closures `trusted` without the robust loss."""
        g = gtsam.NonlinearFactorGraph()
        g.add(gtsam.PriorFactorPose2(0, _pose(self.start), self._prior_noise))
        for k in range(1, self.n):
            g.add(self._chain_factor(k))
        for j, on in enumerate(self.active):
            if on:
                g.add(self._loop_factor(j, robust=j not in trusted))
        return g

    def _values(self, poses: FloatArray) -> gtsam.Values:
        values = gtsam.Values()
        for k in range(len(poses)):
            values.insert(k, _pose(poses[k]))
        return values

    def _restart(self) -> None:
        """A new ISAM2 holding the whole graph at the current estimate."""
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(RELINEARIZE_THRESHOLD)
        params.relinearizeSkip = RELINEARIZE_SKIP
        self._isam = gtsam.ISAM2(params)
        self._slot: dict[int, int] = {}  # closure id -> its factor's index in ISAM2
        self._pending = [(False, k) for k in range(1, self.n)] + [(True, j) for j, on in enumerate(self.active) if on]
        self._removals = []
        self._submit(prior=True)
