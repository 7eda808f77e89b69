"""Schema of the run-level keys: `particles`, `seed`, `mode`, `steps.*`, `record.*`, `report`,
`progress` (top-level so that `slamlab -m particles=50,100,150` works as users type it)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar, Optional

from slamlab.config.checks import require_bool, require_choice, require_int
from slamlab.errors import ConfigError

MODES = ("slam", "odometry", "predict")
# record.particles: auto keeps the history where the report can draw it (every path of a
# prediction-only run; the weights of a filter with this few particles)
RECORD_AUTO_MAX_PARTICLES = 10


@dataclass
class StepsConfig:
    """Which scans the filter processes."""

    GROUP: ClassVar[str] = "steps"
    every: int = 1  # every k-th scan ...
    min_distance_m: float = 0.0  # ... or, if > 0, after travelling this far (m) since the last step
    min_angle_rad: float = 0.0  # ... or turning this much (rad); either threshold triggers a step
    skip_static_start: bool = True  # drop the scans before the robot first moves
    max_scans: Optional[int] = None  # process only the first N scans (null = all)
    max_steps: Optional[int] = None  # stop after N processed steps, e.g. 1: the first scan's map (null = all)
    between: str = "odometry"  # the pose of a scan between steps (online and smoothed path): its step's (+) the
    # `odometry` since, or the motion since as `match`ed against the step's best particle's map (mode slam only;
    # causal; the filter itself is unchanged)
    odom_jump_m: float = 2.0  # an odometry increment between two consecutive scans longer than this (m) ...
    odom_jump_rad: float = 1.57  # ... or turning more than this (rad), faster than 10 m/s or a turn a second, is a
    # reset of the odometry's frame, not motion: the filters take it as no motion (slam/odometry_jumps.py; 0 turns a
    # test off). Real logs stay far below (Intel 0.22 m / 0.28 rad, ACES 0.38 m / 1.06 rad between scans)

    def __post_init__(self) -> None:
        g = self.GROUP
        require_int(g, "every", self.every, 1)
        for name in ("min_distance_m", "min_angle_rad", "odom_jump_m", "odom_jump_rad"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not v == v or abs(v) == float("inf") or v < 0:
                raise ConfigError(f"{g}.{name}", f"must be a number >= 0, got {v!r}")
            setattr(self, name, float(v))
        require_bool(g, "skip_static_start", self.skip_static_start)
        require_int(g, "max_scans", self.max_scans, 1, allow_none=True)
        require_int(g, "max_steps", self.max_steps, 1, allow_none=True)
        require_choice(g, "between", self.between, ("odometry", "match"))


@dataclass
class RecordConfig:
    """Extra files for the report (docs/RUN_DIRECTORY.md)."""

    GROUP: ClassVar[str] = "record"
    # particles.npz, every particle's pose and weight at every step:
    # true | false | auto (on for mode=predict and for slam with <= 10 particles)
    particles: Any = "auto"
    first_scan: bool = False  # first_scan.npz, the first processed scan's points in the world frame
    replay: bool = True  # replay.npz, ~100 snapshots (map, particles, scan) for the report's replay

    def __post_init__(self) -> None:
        if self.particles not in ("auto", True, False) or isinstance(self.particles, int) and not isinstance(self.particles, bool):
            raise ConfigError("record.particles", f"must be auto, true or false, got {self.particles!r}")
        require_bool(self.GROUP, "replay", self.replay)
        require_bool(self.GROUP, "first_scan", self.first_scan)


@dataclass
class RunConfig:
    """One run's top-level knobs."""

    # Each field's docstring is its one line in `slamlab --help` (slamlab.cli.help).
    particles: int = 100
    """number of particles"""
    seed: int = 0
    """the filter's random seed: same config + seed = same trajectory, bit for bit"""
    mode: str = "slam"
    """slam | odometry (dead reckoning, to compare) | predict (particles move, never weighted)"""
    steps: StepsConfig = field(default_factory=StepsConfig)
    """which scans the filter processes: every k-th, after a distance or turn; a slice"""
    record: RecordConfig = field(default_factory=RecordConfig)
    """extra files for the report: particles.npz, first_scan.npz, replay.npz"""
    report: bool = True
    """write report.html in the run directory"""
    progress: str = "auto"
    """auto (a bar on a terminal, log lines otherwise) | bar | log | off"""

    def __post_init__(self) -> None:
        require_int("", "particles", self.particles, 1)
        require_int("", "seed", self.seed, 0)
        require_choice("", "mode", self.mode, MODES)

    @property
    def record_particles(self) -> bool:
        """`record.particles` with `auto` decided for this run."""
        r = self.record.particles
        if r == "auto":
            return self.mode == "predict" or (self.mode == "slam" and self.particles <= RECORD_AUTO_MAX_PARTICLES)
        return bool(r)
