"""What the SLAM engine hands back: everything the artifacts and metrics need, in memory.

The engine never reads files and never plots; the pipeline turns a `SlamResult` into a run
directory (see docs/RUN_DIRECTORY.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import numpy as np

from slamlab.frames import GridImage
from slamlab.geometry import FloatArray
from slamlab.io.table import Table


@dataclass(frozen=True, slots=True)
class ParticleHistory:
    """Every particle at every processed step (K steps, N particles), kept when
    `record.particles` is on.

    - `poses` (K, N, 3): after the update of step k, before any resampling;
    - `weights` (K, N): the normalised weights the resampler saw at step k;
    - `parents` (K, N): particle j of step k continues particle `parents[k, j]` of step k-1;
    - `resampled` (K,): whether step k resampled (then step k+1's parents say how).
    """

    poses: FloatArray
    weights: FloatArray
    parents: np.ndarray
    resampled: np.ndarray


@dataclass(slots=True)
class SlamResult:
    """Result of one SLAM (or dead-reckoning) run over a sequence of N scans.

    - `times` (N,) scan times (s), file order.
    - `trajectory` (N, 3): the final best particle's own path through its ancestry
      (smoothed), scans between processed steps filled by that particle's pose composed
      with the motion since: the odometry's, or (`steps.between=match`) the scan's motion
      from its step as matched against that step's best particle's map (`fill` names the
      method: "odometry" or "match").
    - `causal` (N, 3): the online estimate (`filter.online`: the best particle, or the
      particles' weighted mean, at each step), filled the same way.
    - `odometry` (N, 3): the raw odometry poses, shifted to start at the first estimate (its
      jumps bridged as no motion: `slam.odometry_jumps`, `extras["odometry_jumps"]`).
    - `log_odds`: the final occupancy map in log-odds (float32 GridImage).
    - `steps`: one row per processed step with columns
      step, scan_index, t, neff, resampled, best_weight, step_time_s (and odometry_scale,
      the best particle's, when `motion.scale_gain_per_m` > 0 in mode slam).
    - `particles`, `resample_count`, `runtime_s` (wall time of the filter loop only).
    - `particle_history`: every particle's pose and weight per step, or None (not recorded).
    - `first_scan_xy` (M, 2): the first processed scan's points in the world frame (m), as
      inserted into the first map; `first_scan_origin` (2,) the lidar's position then.
    - `replay`: ~100 snapshots of the filter for the report's replay (`slam.replay`), or None.
    """

    times: FloatArray
    trajectory: FloatArray
    causal: FloatArray
    odometry: FloatArray
    log_odds: GridImage
    steps: Table
    particles: int
    resample_count: int
    runtime_s: float
    fill: str = "odometry"
    extras: dict = field(default_factory=dict)
    particle_history: ParticleHistory | None = None
    first_scan_xy: FloatArray | None = None
    first_scan_origin: FloatArray | None = None
    replay: dict | None = None
