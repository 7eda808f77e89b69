"""What every filter family shares before its own loop: the run's components and which scans
it processes.

- `Components`: the checked pieces of one run, built once at the application edge
  (`slamlab.assemble`) from the config groups;
- `plan_steps`: the scans of the run (`steps.max_scans`), their times and odometry (its jumps
  bridged: `slam.odometry_jumps`), and the processed steps (`steps.select_steps`, cut at `steps.max_steps`),
  with the stretches where their scans had too few returns to match (`slam.thin_scans`);
- `BetweenScans`: the scans between two processed steps, projected and prepared a chunk of
  steps at a time (`steps.between=match`).
The particle filters' loop (`slam.engine`) and the graph's (`slam.graph.run`) both start here.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from slamlab.errors import ConfigError
from slamlab.frames import ScanFrame, Sequence, scan_odometry, scan_times
from slamlab.geometry import FloatArray
from slamlab.slam.filters import FilterKind
from slamlab.slam.grid import MapSettings
from slamlab.slam.matcher import MatchPoints, Matcher
from slamlab.slam.motion import MotionModel
from slamlab.slam.odometry_jumps import OdometryJump, bridge_jumps, find_jumps
from slamlab.slam.resample import Resampler
from slamlab.slam.scan import ScanBatch, range_limits
from slamlab.slam.steps import first_move, select_steps
from slamlab.slam.thin_scans import THIN_RETURNS, ThinScans, thin_stretches, usable_returns
from slamlab.slam.weighting import Weighting

log = logging.getLogger(__name__)
MAX_JUMPS_LOGGED = 5  # warnings for the first jumps; metrics.json lists them all


@dataclass(frozen=True, slots=True)
class Components:
    """The checked pieces of one run: the run-level knobs (`slamlab.config.run`; units in the
    names) and the component objects built from the config groups."""

    particles: int
    seed: int
    mode: str
    every: int
    min_distance_m: float
    min_angle_rad: float
    skip_static_start: bool
    max_scans: int | None
    max_steps: int | None
    between: str
    odom_jump_m: float
    odom_jump_rad: float
    motion: MotionModel
    weighting: Weighting
    resampler: Resampler
    matcher: Matcher
    map: MapSettings
    filter: FilterKind
    record_particles: bool
    record_replay: bool


@dataclass(frozen=True, slots=True)
class StepPlan:
    """The scans of a run and which of them its filter processes (`plan_steps`)."""

    scans: list[ScanFrame]
    times: FloatArray  # (N,) s, file order
    odometry: FloatArray  # (N, 3) x m, y m, theta rad: the log's, its jumps bridged (`odometry_jumps`)
    step_scans: np.ndarray  # (K,) indices of the processed scans
    odometry_jumps: list[OdometryJump]  # the jumps taken as no motion (`steps.odom_jump_m` / `odom_jump_rad`)
    step_returns: np.ndarray | None  # (K,) each processed step's usable returns (`slam.thin_scans`); None: not counted (mode is not slam)

    def jumps_up_to(self, n_scans: int) -> list[dict]:
        """The jumps among the first `n_scans` scans (a run stopped early ends there), as
        metrics.json's `odometry_jumps` lists them."""
        return [jump.as_dict() for jump in self.odometry_jumps if jump.scan < n_scans]

    def thin_up_to(self, n_steps: int) -> ThinScans | None:
        """The first `n_steps` processed steps' thin scans (`slam.thin_scans`), when worth a
        warning (metrics.json's `thin_scans`), else None."""
        if self.step_returns is None:
            return None
        thin = thin_stretches(self.step_returns[:n_steps], self.step_scans[:n_steps], self.odometry, self.times)
        return thin if thin is not None and thin.worth_a_warning else None


def plan_steps(sequence: Sequence, c: Components) -> StepPlan:
    """The scans of a run: the first `steps.max_scans` scans, and with `steps.max_steps` the
    scans up to the last processed one; their odometry with each jump taken as no motion
    (`slam.odometry_jumps`, each named in a warning); a warning when the steps' scans had too
    few returns to match for long (`slam.thin_scans`)."""
    scans = sequence.scans if c.max_scans is None else sequence.scans[: c.max_scans]
    if not scans:
        raise ConfigError("steps.max_scans", f"sequence {sequence.name!r} has no scans to process")
    times = scan_times(scans)
    odom = scan_odometry(scans)
    jumps = find_jumps(odom, times, c.odom_jump_m, c.odom_jump_rad)
    odom = bridge_jumps(odom, jumps)
    step_scans = select_steps(odom, c.every, c.min_distance_m, c.min_angle_rad, c.skip_static_start)
    if len(scans) > 1 and first_move(odom) is None:
        # the steps wait for the odometry to move: a log without odometry (its fields all zero) ends as one scan's map
        log.warning("%s: the odometry never moves (all %d scans at x=%.3f m, y=%.3f m, theta=%.3f rad): %d of them processed. "
                    "slamlab predicts every step from the odometry; a log without any (its odometry fields all zero) "
                    "cannot be mapped", sequence.name, len(scans), *odom[0], len(step_scans))
    if c.max_steps is not None and len(step_scans) > c.max_steps:
        # the run ends at its last processed scan (max_steps=1: the first scan's map alone)
        step_scans = step_scans[: c.max_steps]
        scans, times, odom = scans[: step_scans[-1] + 1], times[: step_scans[-1] + 1], odom[: step_scans[-1] + 1]
        jumps = [jump for jump in jumps if jump.scan <= step_scans[-1]]
    for jump in jumps[:MAX_JUMPS_LOGGED]:  # the jumps within the run's scans
        log.warning("%s: the odometry jumps %.2f m and %.1f deg between scans %d and %d (t = %.3f s), more than a robot moves "
                    "between two scans (steps.odom_jump_m=%g, steps.odom_jump_rad=%g): taken as a reset of its frame, not as motion",
                    sequence.name, jump.m, np.degrees(jump.rad), jump.scan - 1, jump.scan, jump.t_s, c.odom_jump_m, c.odom_jump_rad)
    if len(jumps) > MAX_JUMPS_LOGGED:
        log.warning("%s: %d more odometry jumps taken as resets (metrics.json: odometry_jumps)", sequence.name, len(jumps) - MAX_JUMPS_LOGGED)
    lo, hi = range_limits(c.map, sequence)
    matched = c.mode == "slam"  # dead reckoning and predict match nothing: nothing to say of their scans
    returns = usable_returns(scans, step_scans, sequence.body_height_m, lo, hi, c.map.ground_threshold_m) if matched else None
    plan = StepPlan(scans, times, odom, step_scans, jumps, returns)
    thin = plan.thin_up_to(len(step_scans))
    if thin is not None:
        log.warning("%s: %d of the %d processed scans (%.1f %%) had fewer than %d usable returns (%g-%g m), too few to match; "
                    "the longest such stretch, %.1f m of odometry from %.1f to %.1f s into the run, rests on the odometry alone, "
                    "and a loop through it may stay open where the map consistency check cannot see it (metrics.json: thin_scans)",
                    sequence.name, thin.steps, len(step_scans), 100 * thin.share, THIN_RETURNS, lo, hi, thin.longest_m,
                    thin.from_s, thin.to_s)
    return plan


class BetweenScans:
    """The scans between filter steps (`steps.between=match`), projected and prepared for the
    matcher `CHUNK_STEPS` steps (at most `CHUNK_SCANS` scans) at a time: one pass of NumPy
    calls for a chunk instead of a few dozen per step (Intel has 1,364 steps and 12,125 scans
    between them). Each scan's points do not depend on the scans prepared with it (tests:
    `test_prepared_scans_pick_what_points_picks_scan_by_scan`, `project_scans`' in
    test_carmen). Steps are asked for in order, each once (`of_step`)."""

    CHUNK_STEPS = 16
    CHUNK_SCANS = 2000  # at most ~0.5 MB of Intel's points however far apart the steps lie

    def __init__(self, step_scans: np.ndarray, n_scans: int, project: Callable[[int, int], ScanBatch],
                 prepare: Callable[[ScanBatch], ScanBatch | MatchPoints]) -> None:
        """`project(a, b)`: scans a..b-1's points; `prepare`: those as the matcher takes them."""
        self._steps = np.asarray(step_scans, dtype=np.int64)
        self._stop = np.append(self._steps[1:], n_scans)  # step k's scans between: steps[k] + 1 .. stop[k] - 1
        self._prepare = prepare
        self._project = project
        self._last = -1  # the chunk held serves steps up to _last - 1, its scans from _at
        self._at = 0
        self._prepared: ScanBatch | MatchPoints = ScanBatch.of([])
        self.spent_s = 0.0  # wall seconds the last `of_step` spent preparing a chunk (0: none)
        self.share_s = 0.0  # the held chunk's preparation per step it serves

    def of_step(self, k: int) -> tuple[np.ndarray, ScanBatch | MatchPoints]:
        """The scans between step k and the next that have points (their indices, scan order)
        and those scans as `ParticleMaps.prepare_scans` gives them (a scan without points keeps
        its odometry)."""
        self.spent_s = 0.0
        if k >= self._last:
            t0 = time.perf_counter()
            self._at = int(self._steps[k]) + 1
            fits = int(np.searchsorted(self._stop, self._at + self.CHUNK_SCANS, side="right"))
            self._last = max(k + 1, min(k + self.CHUNK_STEPS, fits, len(self._steps)))
            self._prepared = self._prepare(self._project(self._at, int(self._stop[self._last - 1])))
            self.spent_s = time.perf_counter() - t0
            self.share_s = self.spent_s / (self._last - k)
        a, b = int(self._steps[k]) + 1, int(self._stop[k])
        part = self._prepared.scans(a - self._at, b - self._at)
        return np.arange(a, b, dtype=np.int64)[part.counts > 0], part.nonempty()
