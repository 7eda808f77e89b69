"""What the SLAM engine hands back: everything the artifacts and metrics need, in memory.

The engine never reads files and never plots; the pipeline turns a `SlamResult` into a run
directory (see docs/RUN_DIRECTORY.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import pandas as pd

from slamlab.frames import GridImage
from slamlab.geometry import FloatArray


@dataclass(slots=True)
class SlamResult:
    """Result of one SLAM (or dead-reckoning) run over a sequence of N scans.

    - `times` (N,) scan times (s), file order.
    - `trajectory` (N, 3): the final best particle's own path through its ancestry
      (smoothed), scans between processed steps filled by that particle's pose composed
      with the odometry since (`fill` names the method).
    - `causal` (N, 3): the online estimate, the best particle at each step, filled the same way.
    - `odometry` (N, 3): the raw odometry poses, shifted to start at the first estimate.
    - `log_odds`: the final occupancy map in log-odds (float32 GridImage).
    - `steps`: one row per processed step with columns
      step, scan_index, t, neff, resampled, best_weight, step_time_s.
    - `particles`, `resample_count`, `runtime_s` (wall time of the filter loop only).
    """

    times: FloatArray
    trajectory: FloatArray
    causal: FloatArray
    odometry: FloatArray
    log_odds: GridImage
    steps: pd.DataFrame
    particles: int
    resample_count: int
    runtime_s: float
    fill: str = "odometry"
    extras: dict = field(default_factory=dict)
