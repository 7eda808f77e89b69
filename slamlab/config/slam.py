"""Schemas of the SLAM component groups: `motion/`, `weighting/`, `resampler/`, `matcher/`,
`map/`, `filter/`. One dataclass per component is the single source of its keys, defaults,
types (Hydra checks them when it composes) and value ranges (`__post_init__`, raising
ConfigError naming the key). The YAML files in `slamlab/conf/<group>/` pick a schema and
override values; `_target_` names the class built from it (`slamlab.assemble`).

This module imports no component: the layers above it (slam, the pipeline) import it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Optional

from slamlab.config.checks import require_bool, require_choice, require_fraction, require_int, require_nonnegative, require_positive
from slamlab.errors import ConfigError


# ---- motion/ -------------------------------------------------------------------------------
@dataclass
class CourseMotionConfig:
    """`motion=course`: odometry increment (+) Gaussian noise on x, y (m) and theta (rad) in
    the robot frame. The course quotes N(0, diag[0.01 m, 0.01 m, 0.5 deg]) per 10-scan step;
    each sigma is scaled by k = |increment| / per_distance_m + |dtheta| / per_angle_rad, so
    there is no noise when the robot stands still."""

    GROUP: ClassVar[str] = "motion"
    _target_: str = "slamlab.slam.motion.CourseMotion"
    sigma_xy_m: float = 0.01  # std of x and y noise for one reference increment (m)
    sigma_theta_rad: float = 0.0087  # std of theta noise for one reference increment (rad, 0.5 deg)
    per_distance_m: float = 0.1  # reference translation (m)
    per_angle_rad: float = 0.1  # reference rotation (rad)
    growth: str = "linear"  # linear (the course: sigma x k) | sqrt (sigma x sqrt(k): spread per metre independent of the step size)
    scale_gain_per_m: float = 0.0  # learn a per-particle odometry scale at this gain (1/m; slam/odometry_scale.py); 0 = off

    def __post_init__(self) -> None:
        g = self.GROUP
        if self.growth not in ("linear", "sqrt"):
            raise ConfigError(f"{g}.growth", f"must be linear or sqrt, got {self.growth!r}")
        require_nonnegative(g, "sigma_xy_m", self.sigma_xy_m)
        require_nonnegative(g, "sigma_theta_rad", self.sigma_theta_rad)
        require_positive(g, "per_distance_m", self.per_distance_m)
        require_positive(g, "per_angle_rad", self.per_angle_rad)
        require_nonnegative(g, "scale_gain_per_m", self.scale_gain_per_m)


@dataclass
class Odometry4MotionConfig:
    """`motion=odometry4`: the standard odometry model (Probabilistic Robotics table 5.6): the
    increment is split into rot1, trans, rot2 and each is perturbed with a variance from the
    four alphas."""

    GROUP: ClassVar[str] = "motion"
    _target_: str = "slamlab.slam.motion.Odometry4Motion"
    alpha1: float = 0.05  # rotation noise from rotation (rad^2 / rad^2)
    alpha2: float = 0.01  # rotation noise from translation (rad^2 / m^2)
    alpha3: float = 0.05  # translation noise from translation (m^2 / m^2)
    alpha4: float = 0.01  # translation noise from rotation (m^2 / rad^2)
    scale_gain_per_m: float = 0.0  # learn a per-particle odometry scale at this gain (1/m; slam/odometry_scale.py); 0 = off

    def __post_init__(self) -> None:
        for name in ("alpha1", "alpha2", "alpha3", "alpha4", "scale_gain_per_m"):
            require_nonnegative(self.GROUP, name, getattr(self, name))


# ---- weighting/ ----------------------------------------------------------------------------
@dataclass
class LinearWeightingConfig:
    """`weighting=linear`: the course's w *= correlation, normalised by the sum; underflows
    fall back to uniform weights (counted in metrics.json)."""

    GROUP: ClassVar[str] = "weighting"
    _target_: str = "slamlab.slam.weighting.LinearWeighting"


@dataclass
class LinearExpWeightingConfig:
    """`weighting=linear_exp`: w *= exp(correlation / temperature) in linear space (logsumexp's
    model computed naively; overflows and underflows are counted and fall back to uniform)."""

    GROUP: ClassVar[str] = "weighting"
    _target_: str = "slamlab.slam.weighting.LinearExpWeighting"
    temperature: float = 1.0  # score units, as in logsumexp

    def __post_init__(self) -> None:
        require_positive(self.GROUP, "temperature", self.temperature)


@dataclass
class LogSumExpWeightingConfig:
    """`weighting=logsumexp` (and `logsumexp_t3`, temperature 3): log w += correlation /
    temperature, normalised with log-sum-exp; never underflows or overflows."""

    GROUP: ClassVar[str] = "weighting"
    _target_: str = "slamlab.slam.weighting.LogSumExpWeighting"
    temperature: float = 1.0  # score units: a particle scoring this much less gets e times less weight

    def __post_init__(self) -> None:
        require_positive(self.GROUP, "temperature", self.temperature)


# ---- resampler/ ----------------------------------------------------------------------------
@dataclass
class ResamplerConfig:
    """Every `resampler/` choice: resample when N_eff = 1 / sum(w^2) < threshold * N."""

    GROUP: ClassVar[str] = "resampler"
    _target_: str = "slamlab.slam.resample.SystematicResampler"
    threshold: float = 0.5  # in (0, 1]; the course uses 0.2 (20 of 100)

    def __post_init__(self) -> None:
        require_fraction(self.GROUP, "threshold", self.threshold)


@dataclass
class SystematicResamplerConfig(ResamplerConfig):
    """`resampler=systematic`: one uniform offset, N evenly spaced pointers."""

    _target_: str = "slamlab.slam.resample.SystematicResampler"


@dataclass
class StratifiedResamplerConfig(ResamplerConfig):
    """`resampler=stratified`: one uniform draw in each of N equal strata."""

    _target_: str = "slamlab.slam.resample.StratifiedResampler"


@dataclass
class MultinomialResamplerConfig(ResamplerConfig):
    """`resampler=multinomial`: N independent draws from the weights."""

    _target_: str = "slamlab.slam.resample.MultinomialResampler"


@dataclass
class ResidualResamplerConfig(ResamplerConfig):
    """`resampler=residual`: floor(N w_i) copies, the rest drawn from the residuals."""

    _target_: str = "slamlab.slam.resample.ResidualResampler"


# ---- matcher/ ------------------------------------------------------------------------------
def _check_offset_grid(g: str, xy_half_width_m: float, xy_step_m: float, yaw_half_width_rad: float, yaw_step_rad: float) -> None:
    require_nonnegative(g, "xy_half_width_m", xy_half_width_m)
    require_positive(g, "xy_step_m", xy_step_m)
    require_nonnegative(g, "yaw_half_width_rad", yaw_half_width_rad)
    require_positive(g, "yaw_step_rad", yaw_step_rad)


@dataclass
class GridMatcherConfig:
    """`matcher=grid`: the course's map correlation, i.e. the number of scan points on occupied
    cells over a grid of x/y/yaw offsets."""

    GROUP: ClassVar[str] = "matcher"
    _target_: str = "slamlab.slam.matcher.GridMatcher"
    xy_half_width_m: float = 0.2  # x and y offsets from -0.2 to +0.2 m ...
    xy_step_m: float = 0.05  # ... in 0.05 m steps: a 9 x 9 grid
    yaw_half_width_rad: float = 0.0  # yaw offsets (0 = no yaw search)
    yaw_step_rad: float = 0.01
    move_to_best: bool = True  # move each particle to its best offset
    beam_step: int = 4  # use every k-th scan point (THOR: 1081 beams; 4 keeps it faster than real time)
    max_gap_m: float = 0.0  # match only points with a scan neighbour within max_gap_m (0 = every point; see the likelihood matcher)
    prior_beam_deg: float = 0.0  # no effect (the grid matcher has no motion prior): accepted so that `matcher=grid`
    # can switch a preset that sets it (`lidar2d`)

    def __post_init__(self) -> None:
        _check_offset_grid(self.GROUP, self.xy_half_width_m, self.xy_step_m, self.yaw_half_width_rad, self.yaw_step_rad)
        require_nonnegative(self.GROUP, "prior_beam_deg", self.prior_beam_deg)
        require_int(self.GROUP, "beam_step", self.beam_step, 1)
        require_nonnegative(self.GROUP, "max_gap_m", self.max_gap_m)


@dataclass
class LikelihoodMatcherConfig:
    """`matcher=likelihood`: score = sum of exp(-d^2 / 2 sigma^2) over scan points, d the
    distance to the nearest wall; coarse x/y/yaw grid on a beam subsample, then hill climbing
    with halving steps on all used beams."""

    GROUP: ClassVar[str] = "matcher"
    _target_: str = "slamlab.slam.matcher.LikelihoodFieldMatcher"
    sigma_m: float = 0.1  # field width (m); 0.1 beat 0.05 on Intel and ACES (smoother basin)
    radius_m: float = 0.3  # field cut-off (m)
    xy_half_width_m: float = 0.1  # coarse grid: x/y offsets -0.1..0.1 m ...
    xy_step_m: float = 0.05  # ... in 0.05 m steps
    yaw_half_width_rad: float = 0.1  # coarse grid: yaw offsets -0.1..0.1 rad ...
    yaw_step_rad: float = 0.025  # ... in 0.025 rad steps
    coarse_beam_step: int = 3  # coarse grid uses every 3rd point
    beam_step: int = 1  # hill climb and score use every k-th point
    refine_levels: int = 4  # hill-climb step halvings (refine=climb)
    prior_sigma_xy_m: float = 0.05  # motion prior: an offset d from the prediction costs 0.5 (d/sigma)^2 (0 = off);
    prior_sigma_yaw_rad: float = 0.1  # keeps long corridors (ACES) from sliding, leaves room for Intel's poor yaw
    prior_beam_deg: float = 0.0  # the prior's sigmas are for a lidar with beams this far apart (degrees; 0: for any
    # lidar): the score is a sum over points, so a lidar with beams k times closer outweighs the same prior k times
    # over, and the prior's weight is multiplied by k (`LikelihoodFieldMatcher.for_beam_spacing`)
    move_to_best: bool = True
    voxel_m: float = 0.0  # match one point per voxel_m square of the scan (0 = every point): a surface
    # weighs by its size, not by the angle it covers (a person close by cannot outvote the walls)
    max_gap_m: float = 0.0  # match only points with a scan neighbour within max_gap_m (0 = every point): isolated far
    # hits on a wall seen at a grazing angle map as separate blobs that hold the match where it was (`isolated_filter`)
    isolated: str = "drop"  # the lone points max_gap_m singles out: `drop` them, or match those on a line as a
    # `stretch` of surface in the hill climb (`surface_stretches`): their across-wall position without the comb
    refine: str = "climb"  # after the coarse grid: `climb` (hill climbing, refine_levels halvings) or `gauss_newton`
    # (damped Gauss-Newton steps on the same score, slam/gauss_newton.py: ~7x fewer scores on Intel; refine_levels unused)

    def __post_init__(self) -> None:
        g = self.GROUP
        require_choice(g, "isolated", self.isolated, ("drop", "stretch"))
        require_choice(g, "refine", self.refine, ("climb", "gauss_newton"))
        if self.refine == "gauss_newton" and self.isolated == "stretch":
            raise ConfigError(f"{g}.refine", "gauss_newton does not support isolated=stretch (a stretch's score, the best of its samples, has no gradient); use refine=climb or isolated=drop")
        if self.isolated == "stretch" and not self.max_gap_m > 0:
            raise ConfigError(f"{g}.isolated", "stretch needs matcher.max_gap_m > 0 (the gap that makes a scan point a lone hit)")
        require_nonnegative(g, "prior_sigma_xy_m", self.prior_sigma_xy_m)
        require_nonnegative(g, "prior_sigma_yaw_rad", self.prior_sigma_yaw_rad)
        require_nonnegative(g, "prior_beam_deg", self.prior_beam_deg)
        require_nonnegative(g, "voxel_m", self.voxel_m)
        require_nonnegative(g, "max_gap_m", self.max_gap_m)
        require_positive(g, "sigma_m", self.sigma_m)
        require_positive(g, "radius_m", self.radius_m)
        _check_offset_grid(g, self.xy_half_width_m, self.xy_step_m, self.yaw_half_width_rad, self.yaw_step_rad)
        require_int(g, "coarse_beam_step", self.coarse_beam_step, 1)
        require_int(g, "beam_step", self.beam_step, 1)
        require_int(g, "refine_levels", self.refine_levels, 0)


# ---- map/ ----------------------------------------------------------------------------------
@dataclass
class MapConfig:
    """`map=default`: the occupancy grid in log-odds, updated by ray casting.

    This dataclass is also the settings object the grid code reads (`slam.grid.MapSettings`)."""

    GROUP: ClassVar[str] = "map"
    _target_: str = "slamlab.slam.grid.MapSettings"
    resolution_m: float = 0.05  # cell size (m)
    log_odds_occupied: float = 0.85  # added to a beam's end cell (log(0.7/0.3))
    log_odds_free: float = -0.4  # added to cells a beam crosses (log(0.4/0.6))
    clamp_min: float = -5.0  # log-odds bounds: small bounds forget moving people quickly
    clamp_max: float = 5.0
    occupied_threshold: float = 0.0  # a cell is a wall when its log-odds is above this
    ground_threshold_m: float = 0.1  # scan points lower than this above the floor hit the ground (dropped)
    min_range_m: Optional[float] = None  # beams shorter / longer than this are ignored (null = the dataset's)
    max_range_m: Optional[float] = None
    initial_size_m: float = 40.0  # side of the square grid at start (m), centred on the start pose
    growth_margin_m: float = 10.0  # extra room (m) added whenever a scan falls off the grid

    def __post_init__(self) -> None:
        g = self.GROUP
        self.resolution_m = require_positive(g, "resolution_m", self.resolution_m)
        self.log_odds_occupied = require_positive(g, "log_odds_occupied", self.log_odds_occupied)
        if not (isinstance(self.log_odds_free, (int, float)) and self.log_odds_free < 0):
            raise ConfigError(f"{g}.log_odds_free", f"must be < 0, got {self.log_odds_free!r}")
        if not (isinstance(self.clamp_min, (int, float)) and self.clamp_min < 0):
            raise ConfigError(f"{g}.clamp_min", f"must be < 0, got {self.clamp_min!r}")
        if not (isinstance(self.clamp_max, (int, float)) and self.clamp_max > 0):
            raise ConfigError(f"{g}.clamp_max", f"must be > 0, got {self.clamp_max!r}")
        self.log_odds_free, self.clamp_min, self.clamp_max = float(self.log_odds_free), float(self.clamp_min), float(self.clamp_max)
        t = self.occupied_threshold
        if not (isinstance(t, (int, float)) and self.clamp_min <= t < self.clamp_max):
            raise ConfigError(f"{g}.occupied_threshold", f"must lie in [clamp_min, clamp_max), got {t!r}")
        self.occupied_threshold = float(t)
        self.ground_threshold_m = float(self.ground_threshold_m)
        if self.min_range_m is not None:
            self.min_range_m = require_nonnegative(g, "min_range_m", self.min_range_m)
        if self.max_range_m is not None:
            self.max_range_m = require_positive(g, "max_range_m", self.max_range_m)
        if self.min_range_m is not None and self.max_range_m is not None and self.min_range_m >= self.max_range_m:
            raise ConfigError(f"{g}.max_range_m", "must be greater than map.min_range_m")
        self.initial_size_m = require_positive(g, "initial_size_m", self.initial_size_m)
        self.growth_margin_m = require_nonnegative(g, "growth_margin_m", self.growth_margin_m)


# ---- filter/ -------------------------------------------------------------------------------
def _check_online(value: object) -> None:
    if value not in ("best", "mean"):
        raise ConfigError("filter.online", f"must be best or mean, got {value!r}")


@dataclass
class CourseFilterConfig:
    """`filter=course`: every particle matches against ONE shared map, built from the
    highest-weight particle at each step."""

    GROUP: ClassVar[str] = "filter"
    _target_: str = "slamlab.slam.filters.SharedMapFilter"
    online: str = "best"  # the online (causal) pose: best (highest-weight particle) or mean (weighted mean)

    def __post_init__(self) -> None:
        _check_online(self.online)


@dataclass
class RbpfFilterConfig:
    """`filter=rbpf`: Rao-Blackwellised particle filter, a map per particle in copy-on-write
    tiles of 32 x 32 cells shared between particles until one writes."""

    GROUP: ClassVar[str] = "filter"
    _target_: str = "slamlab.slam.filters.RaoBlackwellFilter"
    step_ref_m: Optional[float] = None  # the step the matcher's motion prior is set for (null = off); a shorter
    step_ref_rad: Optional[float] = None  # step (d / step_ref_m + |a| / step_ref_rad = s < 1) gets a prior s times as narrow
    # (measured worse on ACES at half steps: left off)
    online: str = "best"  # the online (causal) pose: best (highest-weight particle) or mean (weighted mean)

    def __post_init__(self) -> None:
        _check_online(self.online)
        if (self.step_ref_m is None) != (self.step_ref_rad is None):
            raise ConfigError("filter.step_ref_rad", "set step_ref_m and step_ref_rad together (or both null)")
        if self.step_ref_m is not None:
            require_positive(self.GROUP, "step_ref_m", self.step_ref_m)
        if self.step_ref_rad is not None:
            require_positive(self.GROUP, "step_ref_rad", self.step_ref_rad)


@dataclass
class GraphFilterConfig:
    """`filter=graph`: one trajectory, no particles. Local SLAM matches each processed scan
    against a map of everything mapped so far (`local_map`); the scans also go into submaps,
    two active at once, and new nodes are searched against the finished ones by branch and
    bound; accepted loop closures and the local matches form a pose graph optimised with
    GTSAM under a robust loss (slamlab.slam.graph)."""

    GROUP: ClassVar[str] = "filter"
    _target_: str = "slamlab.slam.graph.GraphFilter"
    # ---- local SLAM
    local_map: str = "map"  # local SLAM: `map` (each scan matched against everything mapped so far, at the online poses;
    # redrawn after a large correction), `submap` (against the older active submap, as Cartographer) or `particles` (the
    # RBPF, `particles` of them, with the run's motion, weighting and resampler; restarted after a large correction).
    # `particles` measured worse than `map` (2026-11-29: sim_loops 2.0 ATE up to 2.17 m against 0.40, Intel causal 0.049
    # against 0.018 m, 5-10x the time; benchmarks/RESULTS.md), kept as the "loop closure for the RBPF" experiment
    wall_at: str = "centre"  # where a wall's likelihood-field peak sits in its cell, in the online map and the submaps:
    # `centre` (the cell's centre) or `hits` (the mean of the scan hits that fell in it, to 1/9 of a cell: slam/raycast.note_hits;
    # three bytes more a cell of those grids). Walls at cell centres stand up to half a cell inside the surface they map.
    # `centre` by measurement (2026-11-29, bench_graph.py, benchmarks/RESULTS.md): `hits` makes the smoothed path better on
    # Intel (worst 0.0206 -> 0.0186 m at 0.5 m steps) and sim_loops 2.0 (mean ATE over seeds 0-9 0.30 -> 0.21 m), but the
    # online path worse on both logs (ACES worst causal 0.045 -> 0.071 m: its online heading drifts 1-4 degrees before
    # the loop closes, against under 1), and a corridor probe lost a loop
    yaw_drift_gain_per_m: float = 0.0  # local_map=map or submap: learn the odometry's yaw drift per metre at this gain (1/m;
    # slam/odometry_yaw.py) and add it to each step's predicted turn; 0 = off. For open ground mapped at fine steps, where a
    # scan keeps few points and a node's match keeps the predicted yaw: the campus probe at 2x and 0.25 m steps at 0.02,
    # aligned ATE 0.17-1.20 -> 0.06-0.22 m (better on five of seven campus worlds, 3x world 3 worse); at the preset's 0.5 m
    # a little worse (0.08-0.15 -> 0.11-0.17 m) and ACES's online path too (mean causal over nine steps 0.051 -> 0.058 m;
    # Intel the same), so off in the preset (2026-12-02, benchmarks/RESULTS.md)
    near_hits_m: float = 0.0  # local_map=map: scan hits nearer than this to the lidar (m) stay out of the online map and its
    # redraws (the submaps and the final map keep them; 0 = none left out). Why: a person walking beside the robot leaves
    # hits beside its path that a forward-looking lidar does not see through again, and local SLAM holds the robot back
    # against them (0.8 m in 1.5 s on a corridor probe). 0.7 measured (2026-12-01, `bench_graph.py --people 12`,
    # benchmarks/RESULTS.md): probes with 12 people at 0.25 m steps worst smoothed 0.50 -> 0.13 m, at 0.5 0.072 -> 0.091;
    # without people, sim_loops and the hospital's consistency the same; Intel / ACES smoothed within 1 mm, but Intel's
    # online path worse at 0.15, 0.35 and 0.75 m steps (causal 0.022 -> 0.041, 0.020 -> 0.056, 0.053 -> 0.073); at 0.5
    # Intel is as before but a people probe lost its map (2.77 m). So off by default: for logs with people walking
    # close to the robot, at fine steps
    local_check_rad: float = 0.03  # local_map=map (not read with the others): a node whose online-map match turns it more
    # than half this (rad) away from the odometry's turn is matched again on the older active submap (recent scans only);
    # where the two matches differ in yaw by more than this, the odometry's turn is nearer the submap's, and the recent
    # scans fit the scan clearly better at their own match than both at the online map's motion and than the online map
    # fits it (slam/graph/local.py, LocalSlam._checked), the node moves by the submap's match (0 = off). Why: returning to
    # a place mapped long ago, before the loop closes, the online map holds that place where the drifted estimate put it
    # then, and local SLAM can be turned by it: the hospital log at 1.0 m steps turned 45 degrees in 25 s at the return to
    # its lobby (4368-4394 s) and its right wing stayed ~10 degrees turned (p10 0.503). 0.03 against off (2026-12-03,
    # benchmarks/RESULTS.md): the hospital at 1.0 / 0.5 / 0.35 / 1.5 m steps p10 0.503 -> 0.632, 0.589 -> 0.607, 0.583 ->
    # 0.591, 0.525 -> 0.517 (0.25, 0.75, 1.1, 1.25: no node taken, the same); Intel at six steps (18 runs), sim_loops and
    # the corridor probes: no node taken, the same bytes; the campus probe at 0.5 m steps two runs of eight take nodes,
    # smoothed 0.0308 -> 0.0289 and 0.0298 -> 0.0288 m; ACES at the preset's steps and half (jittered) the same, but at
    # 0.35 m steps smoothed 0.0369 -> 0.0402 m (one node taken) and at 0.15 m 0.0367 -> 0.0372. On since 2026-12-03: a
    # wing left turned is a broken map, 3 mm on ACES at one step is not
    local_weak_fit: float = 0.5  # local_map=map (not read with the others): a node whose online-map match turns it more than
    # 0.07 rad and more than 8 times the median of the nodes before it (the odometry's own yaw noise, once 20 nodes tell it)
    # away from the odometry's turn, while its scan fits the map there below this (mean field value, 0..1), keeps the
    # odometry's yaw, its x and y matched as usual (slam/graph/local.py, LocalSlam._held; 0 = off). Why: the hospital log
    # at 1.25 m steps turned 10.6 degrees past its odometry's turn in its lobby at a fit of 0.075 (its odometry is within
    # 0.2 degrees of the matches a node in the median); the turn stayed in the path and the return to the start fell
    # outside the loop search's windows (its end 165 m from its start). Measured 2026-12-03 (benchmarks/RESULTS.md): the
    # hospital at eight step sizes 0.25-1.5 m closes its start-return loop at every one (1.25 m: 165 -> 2.0 m from the
    # start) and the runs agree better with each other (1.25 m 39.6 -> 2.5 m rms from the 0.5 m run; 1.0 m 6.0 -> 1.4,
    # 0.25 m 4.6 -> 2.0; 1.5 m 2.6 -> 4.9 worse); Intel at six step sizes (18 runs) and the 40-run corridor probe matrix
    # hold no turn (the same bytes); ACES holds one or two in 7 of 18 runs: worst smoothed within 1 mm at the preset's
    # steps and half (0.0359 / 0.0363), 0.35 m 0.0402 -> 0.0411, and one causal 0.063 -> 0.100 m (0.98 m steps)
    redraw_m: float = 0.15  # local_map=map: when the graph puts the robot this far (m) or redraw_rad from where the
    redraw_rad: float = 0.035  # local map has it, the map is drawn again from the graph (the online pose jumps to the graph's).
    # 0.15 against 0.3 (bench_graph.py, 2026-11-29): ACES worst causal 0.0399 / 0.0382 m at 0.5 / 0.25 m steps (0.0417 /
    # 0.0517), corridor probe worst smoothed 0.113 / 0.100 m at 2x / 3x (0.140 / 0.110; worst causal 0.190 / 0.207 against
    # 0.182 / 0.156), sim_loops worst ATE 0.268 / 0.396 m at 1.5 / 2.0 (0.142 / 0.474); Intel unchanged (no redraw there)
    redraw_frame: str = "graph"  # local_map=map: the frame a redrawn online map is drawn in: `graph` (the graph's own, its
    # first node fixed) or `online` (the graph's poses moved by the one rigid motion that best lays every node where the
    # online map has it; later redraws are judged in that frame): the online path then moves at a redraw by what the
    # graph bent, not by a turn of the whole map. `graph` by measurement (2026-11-30, benchmarks/RESULTS.md): `online`
    # takes Intel's worst causal error over steps 0.44-0.56 from 0.064 to 0.042 m (mean 0.033 -> 0.024), ACES's worst
    # over 0.23-1.0 from 0.082 to 0.078, but a corridor probe (3x, world 2) lost a loop (smoothed 0.05 -> 0.24 m) and
    # sim_loops 2.0 got worse (worst aligned ATE 0.138 -> 0.156 m); the rotation about the start alone did worse still
    local_yaw_half_width_rad: float = 0.2  # local SLAM: each node's match starts from a coarse grid this wide in yaw (rad; the
    # matcher's own yaw_half_width_rad when that is wider; the scans between steps keep the matcher's): a step ends after
    # steps.min_angle_rad of turning, and the odometry's yaw error grows with the turn. 0.2 against 0.1 (2026-11-29,
    # bench_graph.py --steps 0.15,0.25,0.35,0.5,0.75,1.0 --jitter -0.02,0,0.02: 36 runs): Intel worst smoothed 0.309 -> 0.031 m
    # (at 1.0 m steps a turn's match slipped 0.3 rad and the loop never closed), median 0.0208 -> 0.0198, worst causal 0.341 ->
    # 0.068; ACES median 0.0398 -> 0.0398, worst 0.045 -> 0.049 (0.15 m steps); corridor probes unchanged
    submap_nodes: int = 20  # nodes (processed scans) inserted into each submap; a new one starts every half of it
    # ---- loop search (branch and bound on the finished submaps)
    search_resolution_m: float = 0.1  # cell of the search grid (rounded to a whole number of map cells)
    search_levels: int = 6  # branch-and-bound levels: the top node covers 2^(levels-1) cells a side
    search_every: int = 2  # search for loops from every k-th node
    query_m: float = 6.0  # search with the scans of the last this many metres together (0: the node's scan alone)
    window_m: float = 0.5  # +- x and y searched around the current estimate right after a closure (m) ...
    window_per_m: float = 0.1  # ... growing by this per metre travelled since the last accepted closure
    window_max_m: float = 100.0  # ... up to this (m). 60 until 2026-11-30: the hospital's estimate returns to its top-left
    # corridor 70-73 m off at 0.46 and 0.52 m steps (measured against a closed run's path), the screen cannot find the first
    # visit there and the loop stays open. At 100 the hospital closes at every one of nine step sizes 0.46-0.54 (p10
    # 0.531-0.610, was 0.521-0.618 with three loops open); Intel, ACES, sim_loops and the corridor probes are unchanged to
    # the last digit (their windows stay under 60 m; bench_graph.py, benchmarks/RESULTS.md)
    window_yaw_rad: float = 0.05  # +- yaw right after a closure (rad) ...
    window_yaw_per_m: float = 0.003  # ... growing per metre travelled (rad/m: 60 degrees after 350 m), to a full turn
    min_score: float = 0.55  # branch-and-bound score a candidate must reach (mean search-grid value, 0..1)
    min_refined_score: float = 0.5  # mean field value at the refined pose (0..1)
    ambiguity_ratio: float = 0.9  # rejected when another pose (ambiguity_m / ambiguity_rad away) scores this much of the best
    ambiguity_m: float = 1.0
    ambiguity_rad: float = 0.35
    wide_every: int = 5  # a wide window (over 5 m or 0.5 rad: tens of times the work) only from every k-th node, and from
    # every node while a correction waits for its group (a loop's return: the group forms within metres, not tens of metres;
    # 2026-11-29, corridor probe worst smoothed 0.113 -> 0.085 m at 2x, 0.100 -> 0.097 at 3x; Intel and ACES unchanged)
    max_submaps_per_node: int = 2  # finished submaps searched from one node: its loop candidates (the nearest submap not
    # tied to it for loop_min_path_m by where the submap was seen from, and by its known area's centre when that is another),
    # then the nearest others, this many in all with one loop candidate (one more with two). Both loop candidates against
    # the centre's alone (2026-11-29, bench_graph.py 36 runs): worst smoothed Intel 0.0203-0.0215 m at every step (was
    # 0.0198-0.0305), ACES 0.0380 at 0.5 m steps (0.0409), 0.0392-0.0418 at the others (0.0394-0.0485); worst causal
    # better at 6 of 12 steps, worse at 5; hospital p10 0.566 (0.571); sim_loops worst ATE 0.174 / 0.452 m at 1.5 / 2.0
    # (0.226 / 0.396)
    screen_resolution_m: float = 0.4  # a wide search (a long loop's return) first scores every submap not tied to the node
    # (loop_min_path_m) in reach on a grid this coarse (m; 0: off) and searches the `screen_keep` best of them, instead of
    # the nearest: tens of metres of drift put the estimate nearer to other submaps than to the place it is (the hospital's
    # right-hand loop: the estimate 12-20 m off, the first visit's submaps 8th-19th nearest of ~60). On against off
    # (2026-11-30, bench_graph.py --only logs,sim_loops --steps 0.5,0.25, same machine and hour): hospital p10 0.469 -> 0.597,
    # its corridors at right angles again (largest correction 73 m), whole run 55 -> 93 s (screen 23 s); Intel worst
    # smoothed 0.0194 -> 0.0190 m, ACES 0.0379 -> 0.0378, worst causal 0.0456 -> 0.0447; sim_loops worst ATE 0.166 / 0.454 ->
    # 0.180 / 0.462 m at 1.5 / 2.0 (mean 0.121 / 0.335 -> 0.114 / 0.304, worst aligned 0.137 / 0.235 -> 0.095 / 0.231);
    # corridor probe (worlds 0-3) worst smoothed 2.162 -> 0.048 m at 2x (world 0 lost its loop without the screen on this
    # machine's bits) and 0.054 -> 0.063 at 3x, worst causal 2.187 / 0.168 -> 0.119 / 0.127. With the steps jittered by
    # +-0.02 (--jitter=-0.02,0.02) it is mixed: ACES 0.25 worst 0.0411 / 0.0594 -> 0.0388 / 0.0546 (smoothed / causal), ACES
    # 0.5 0.0374 / 0.0453 -> 0.0389 / 0.0485, Intel 0.25 causal 0.0195 -> 0.0242, Intel 0.5 unchanged (0.0203 / 0.0398).
    # 0.8 m was cheaper (screen 11 s) and left the hospital's right wing turned
    screen_keep: int = 2  # ... this many
    screen_points: int = 128  # the screen scores at most this many of the query's points (evenly spread over it)
    # ---- verification: a closure that moves its node by more than trust_m / trust_rad needs a group of mutually
    # consistent ones
    trust_m: float = 0.1  # a closure asking for a correction within this (m) ...
    trust_rad: float = 0.02  # ... and this in yaw (rad), as a 99 % gate where the match pins the pose, enters alone
    loop_min_path_m: float = 30.0  # a larger correction comes only from a submap not tied to the robot for this long (m of path)
    group_size: int = 3  # closures from a wider window enter in pairwise-consistent groups of at least this many
    group_extent_m: float = 2.0  # ... whose nodes spread over at least this much of the path (m). 8 until 2026-11-29: at coarse
    # steps (1.0 m) a loop's return gave closures from 3 nodes within 4 m, which never formed a group (Intel at 1.0 m steps
    # 0.896 m -> 0.026 m; ACES 0.15 / 0.35 m steps 0.047 / 0.044 -> 0.042 / 0.041 m; the preset's steps, the corridor probes
    # and sim_loops 2.0 unchanged, sim_loops 1.5 worst 0.268 -> 0.226 m: bench_graph.py). Each search already matches the
    # last `query_m` of scans together, so three nodes 2 m apart are three views of that much of the building
    group_span_m: float = 20.0  # candidates wait this far (m of travel) for their group
    group_submaps: int = 2  # ... and a group's closures are matches in at least this many submaps: scans in a row matched
    # in one old submap are not independent. Where that submap saw the robot's true place only at its far edge, a place a
    # period along the corridor fits each of them better and they agree (corridor probe 3x, world 4: four closures in one
    # submap moved the robot 27 m along a corridor, the online path 20.7 m off for 190 s until a later group took it back;
    # 1 until 2026-11-30, see benchmarks/RESULTS.md)
    consistency_m: float = 0.3  # pairwise cycle error allowed (m) ...
    consistency_per_m: float = 0.02  # ... plus this per metre of the cycle's path
    consistency_rad: float = 0.05  # pairwise cycle error allowed in yaw (rad) ...
    consistency_rad_per_m: float = 0.002  # ... plus this per metre (rad/m)
    # ---- pose graph (GTSAM)
    local_sigma_m: float = 0.01  # local match between consecutive nodes: sigma = this + per_m x step (m)
    local_sigma_per_m: float = 0.02
    local_sigma_rad: float = 0.005  # ... and in yaw: this + per_rad x |turn| (rad)
    local_sigma_per_rad: float = 0.02
    local_sigma_along_per_m: float = 0.02  # ... in the step's own direction this per metre instead (m/m)
    local_slip_per_m: float = 0.1  # ... plus, where the match pinned nothing (a bare corridor), up to this share of the step
    loop_sigma_m: float = 0.03  # a loop closure's sigma in x, y (m) and yaw (rad)
    loop_sigma_rad: float = 0.01
    loss: str = "cauchy"  # robust loss on loop closures: cauchy | huber | none
    loss_scale: float = 0.5  # the loss's scale in sigmas
    prune_m: float = 0.5  # after an optimisation a closure left this far (m) or prune_rad off is dropped
    prune_rad: float = 0.15
    final_match: bool = True  # the smoothed trajectory: each scan matched once more, from its optimised pose, on a map
    # of the nodes' scans at theirs (slam/graph/final_match.py; the causal path is not touched), when the run matched the
    # scans between steps (steps.between=match; the nodes alone measured worse: no effect otherwise). Smoothed relation error
    # without -> with (2026-11-30): ACES 0.0373 -> 0.0357 m at 0.5 m steps, 0.0368 -> 0.0353 at 0.25; Intel 0.0185 ->
    # 0.0180, 0.0189 -> 0.0189; ~1 s on Intel's 13,631 scans
    online: str = "best"  # local_map=particles: the online pose is the best particle (best) or the weighted mean (mean);
    # otherwise no effect (accepted so that `filter=` can switch a preset that sets it)

    def __post_init__(self) -> None:
        g = self.GROUP
        for name in ("submap_nodes", "search_levels", "search_every", "wide_every", "max_submaps_per_node", "group_size", "group_submaps", "screen_keep", "screen_points"):
            require_int(g, name, getattr(self, name), 2 if name in ("submap_nodes",) else 1)
        if self.search_levels > 12:
            raise ConfigError(f"{g}.search_levels", f"must be at most 12, got {self.search_levels!r}")
        for name in ("search_resolution_m", "window_max_m", "ambiguity_m", "ambiguity_rad", "loop_sigma_m", "loop_sigma_rad", "trust_m", "trust_rad", "redraw_m", "redraw_rad",
                     "local_sigma_m", "local_sigma_rad", "loss_scale", "prune_m", "prune_rad", "consistency_m", "consistency_rad"):
            require_positive(g, name, getattr(self, name))
        for name in ("near_hits_m", "local_check_rad", "yaw_drift_gain_per_m", "local_yaw_half_width_rad", "screen_resolution_m", "window_m", "window_per_m", "window_yaw_rad", "window_yaw_per_m", "query_m", "loop_min_path_m", "group_extent_m", "group_span_m",
                     "consistency_per_m", "consistency_rad_per_m", "local_sigma_per_m", "local_sigma_per_rad", "local_sigma_along_per_m", "local_slip_per_m"):
            require_nonnegative(g, name, getattr(self, name))
        for name in ("min_score", "min_refined_score", "ambiguity_ratio"):
            require_fraction(g, name, getattr(self, name))
        if self.local_weak_fit != 0:  # 0 = off; else a mean field value
            require_fraction(g, "local_weak_fit", self.local_weak_fit)
        require_choice(g, "loss", self.loss, ("cauchy", "huber", "none"))
        require_choice(g, "local_map", self.local_map, ("map", "submap", "particles"))
        if self.yaw_drift_gain_per_m > 0 and self.local_map == "particles":  # each particle keeps its own motion model there
            raise ConfigError(f"{g}.yaw_drift_gain_per_m", "is for local_map=map or submap; local_map=particles learns no yaw drift")
        require_choice(g, "wall_at", self.wall_at, ("centre", "hits"))
        require_choice(g, "redraw_frame", self.redraw_frame, ("graph", "online"))
        require_bool(g, "final_match", self.final_match)
        _check_online(self.online)


__all__ = [
    "CourseMotionConfig", "Odometry4MotionConfig",
    "LinearWeightingConfig", "LinearExpWeightingConfig", "LogSumExpWeightingConfig",
    "ResamplerConfig", "SystematicResamplerConfig", "StratifiedResamplerConfig", "MultinomialResamplerConfig", "ResidualResamplerConfig",
    "GridMatcherConfig", "LikelihoodMatcherConfig", "MapConfig", "CourseFilterConfig", "RbpfFilterConfig", "GraphFilterConfig",
]
