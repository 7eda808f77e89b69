"""Local SLAM by a Rao-Blackwellised particle filter (`filter.local_map=particles`): the
RBPF's loop closure behind its best particle (issue: "loop closure for the RBPF too").

The RBPF (`particles` particles, the run's motion model, weighting and resampler; maps per
particle in copy-on-write tiles, as `filter=rbpf`) tracks the robot and closes the loops it
can by itself: a particle whose map held together through a loop survives it. Down a bare
corridor its particles spread along it, and the one the next junction fits is kept; a single
scan matcher there only follows the odometry. What it cannot do is close a loop after tens
of metres of drift: no particle is there. So the graph runs behind it:
- each node's local edge is the best particle's own step (from its pose before the step to
  its matched pose: one hypothesis's motion, never a jump between hypotheses), and the chain
  of those steps is where the submaps are built;
- the online pose is the particles' weighted mean (or the best, `filter.online`);
- scans between steps are matched against the best particle's map;
- when the graph puts the robot far from the particles (a long loop closed by the loop
  search), the filter is restarted there: every particle at the graph's pose, all sharing
  one map drawn from every node's optimised pose (`redraw`).
Same seed, same particles: one `numpy.random.Generator(PCG64(seed))` as the particle filters.
"""

from __future__ import annotations

from collections.abc import Sequence as SequenceABC

import numpy as np

from slamlab.geometry import FloatArray, se2_between, se2_compose, weighted_mean_pose
from slamlab.slam.filters import PerParticleMaps
from slamlab.slam.graph.local import LocalSlam
from slamlab.slam.graph.submaps import FinishedSubmap, Submaps
from slamlab.slam.grid import MapSettings
from slamlab.slam.matcher import LikelihoodFieldMatcher, MatchPoints
from slamlab.slam.motion import MotionModel
from slamlab.slam.odometry_scale import learn_scales, scaled_start
from slamlab.slam.resample import Resampler
from slamlab.slam.scan import ScanBatch, ScanPoints
from slamlab.slam.weighting import Weighting


class ParticleTracker(LocalSlam):
    """Local SLAM by the RBPF (see module doc); the same interface as `LocalSlam`."""

    def __init__(self, matcher: LikelihoodFieldMatcher, settings: MapSettings, submaps: Submaps, start: FloatArray, n: int,
                 motion: MotionModel, weighting: Weighting, resampler: Resampler, seed: int, online: str) -> None:
        super().__init__(matcher, settings, submaps, "submap", start, motion.scale_gain_per_m)
        self.n = int(n)
        self.motion = motion
        self.weighting = weighting
        self.resampler = resampler
        self.online_mode = online
        self.rng = np.random.Generator(np.random.PCG64(seed))
        self.maps = PerParticleMaps(settings, self.n, (float(start[0]), float(start[1])), matcher)
        self.poses = np.tile(np.asarray(start, dtype=np.float64), (self.n, 1))
        self.logw = np.full(self.n, -np.log(self.n))
        self.scales = np.ones(self.n) if motion.scale_gain_per_m > 0 else None
        self.best = 0
        self.resamples = 0
        self.online = np.asarray(start, dtype=np.float64).copy()

    @property
    def whole(self) -> bool:
        return True  # the particles' maps hold everything: the online pose is theirs

    @property
    def reference(self) -> FloatArray:
        """The pose scans between steps are matched from: the best particle's."""
        return self.poses[self.best]

    def step(self, odometry_increment: FloatArray, scan: ScanPoints) -> FloatArray:
        """Predict every particle by the odometry increment and the motion model, match each
        against its own map and weigh it (`filter=rbpf`'s step); returns the best particle's
        own motion (the pose graph's local edge)."""
        before = self.poses
        start = before if self.scales is None else scaled_start(before, self.scales, odometry_increment)
        poses = self.motion.sample(start, odometry_increment, self.rng)
        if len(scan.xy):
            poses, scores = self.maps.match(self.matcher, poses, scan)
            self.logw = self.weighting.update(self.logw, scores)
            if self.scales is not None:
                self.scales = learn_scales(self.scales, before, poses, odometry_increment, self.motion.scale_gain_per_m)
        w = np.exp(self.logw)
        self.best = int(np.argmax(w))
        motion = se2_between(before[self.best], poses[self.best])
        self.poses = poses
        self.chain = se2_compose(self.chain, motion)
        self.online = weighted_mean_pose(poses, w) if self.online_mode == "mean" else poses[self.best].copy()
        if self.scales is not None:
            self.scale = self.scales[self.best:self.best + 1]
        return motion

    def insert(self, node: int, scan: ScanPoints) -> list[FinishedSubmap]:
        """Every particle's map takes the scan from its own pose; the submaps from the chain."""
        self.maps.update(self.poses, scan, self.best)
        return self.submaps.insert(node, self.chain, scan)

    def match_online(self, predicted: FloatArray, scans: ScanBatch | MatchPoints) -> FloatArray:
        """Scans between steps against the best particle's map (as `filter=rbpf` does)."""
        prepared = self.maps.prepare_scans(self.matcher, scans) if isinstance(scans, ScanBatch) else scans
        return self.maps.match_scans(self.matcher, self.best, predicted, prepared)

    def finish_step(self) -> None:
        """Resample when the weights ask for it (after the scans between steps were matched
        against the best particle's map)."""
        w = np.exp(self.logw)
        if self.n > 1 and self.resampler.should_resample(w):
            idx = self.resampler.indices(w, self.rng)
            self.poses = self.poses[idx]
            if self.scales is not None:
                self.scales = self.scales[idx]
            self.maps.resample(idx)
            self.logw = np.full(self.n, -np.log(self.n))
            self.best = int(np.flatnonzero(idx == self.best)[0]) if np.any(idx == self.best) else 0
            self.resamples += 1

    def redraw(self, scans: SequenceABC[ScanPoints], poses: FloatArray) -> None:
        """Restart the filter at the graph's estimate: every particle at the newest node's
        optimised pose, all sharing one map drawn from every node's scan at its optimised pose
        (`scans`, `poses` (K, 3): nodes 0..K-1), equal weights."""
        self.redraws += 1
        here = np.asarray(poses[-1], dtype=np.float64)
        maps = PerParticleMaps(self.settings, self.n, (float(poses[0, 0]), float(poses[0, 1])), self.matcher)
        one = np.zeros((self.n, 3))
        for pts, pose in zip(scans, poses):
            if len(pts.xy):
                one[0] = pose
                maps.maps.insert_scan(one, pts.xy, pts.origin, which=np.array([0]))
        maps.maps.share_all_from(0)
        maps._identical = False
        self.maps = maps
        self.poses = np.tile(here, (self.n, 1))
        self.logw = np.full(self.n, -np.log(self.n))
        self.best = 0
        self.online = here.copy()

    def memory_mb(self) -> float:
        return float(self.maps.memory()["map_mb"]) + self.submaps.memory_mb()
