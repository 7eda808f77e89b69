"""Which metrics.json keys the reports show, how they are labelled, and which way is better.

One table of names keeps the run report, the sweep table and the plots consistent.
Keys are dotted paths into metrics.json (docs/RUN_DIRECTORY.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from slamlab.report.rundir import as_float


@dataclass(frozen=True, slots=True)
class MetricSpec:
    """`better` is "min", "max", or None (informative only: no best value marked)."""

    key: str
    label: str
    better: str | None
    table: bool = True  # False: kept in runs.csv and the run report, left out of the wide HTML table
    hide_when_zero: bool = False  # a warning count: in the HTML table only when some run has one
    detail: bool = False  # in the HTML table behind "all columns" (hidden at first: the table fits 1400 px)


# Order = column order in the sweep table.
METRICS: tuple[MetricSpec, ...] = (
    MetricSpec("trajectory.rmse_m", "ATE RMSE (m)", "min"),
    MetricSpec("trajectory.mean_m", "ATE mean (m)", "min", table=False),
    MetricSpec("trajectory.max_m", "ATE max (m)", "min", detail=True),
    MetricSpec("trajectory.rot_rmse_deg", "rot RMSE (°)", "min"),
    MetricSpec("trajectory.aligned_rmse_m", "aligned ATE RMSE (m)", "min", table=False),
    MetricSpec("trajectory.causal_rmse_m", "causal RMSE (m)", "min", table=False),
    # Odometry error is a property of the data, not of the filter: shown, never "best".
    MetricSpec("trajectory.odometry_rmse_m", "odometry RMSE (m)", None, detail=True),
    MetricSpec("relations.trans_abs_mean_m", "rel. trans err (m)", "min"),
    MetricSpec("relations.rot_abs_mean_deg", "rel. rot err (°)", "min", detail=True),
    # local relations span seconds (tracking), loop relations a revisit (loop closure): eval.relations
    MetricSpec("relations.local.trans_abs_mean_m", "rel. err local (m)", "min", table=False),
    MetricSpec("relations.loop.trans_abs_mean_m", "rel. err loop (m)", "min"),
    MetricSpec("relations.causal.trans_abs_mean_m", "online rel. err (m)", "min", table=False),
    MetricSpec("relations.causal.local.trans_abs_mean_m", "online rel. err local (m)", "min", table=False),
    MetricSpec("relations.causal.loop.trans_abs_mean_m", "online rel. err loop (m)", "min", table=False),
    MetricSpec("map.agreement", "map agree\u00adment", "max"),
    MetricSpec("map.occupied_precision", "occ. precision", "max", table=False),
    MetricSpec("map.occupied_recall", "occ. recall", "max", table=False),
    # self-consistency (no ground truth needed): slamlab.eval.consistency
    # the share of replayed beams that contradict the final map, over the run and in its worst stretch
    # (a soft hyphen in "contra-dicting": the table's narrow headers wrap there)
    MetricSpec("consistency.contradiction_share", "beams contra\u00addicting map", "min"),
    MetricSpec("consistency.contradiction_worst_window", "worst stretch contra\u00addicting", "min"),
    MetricSpec("consistency.hit_fraction_mean", "scan hits on map", "max", table=False),
    MetricSpec("consistency.hit_fraction_p10", "scan hits p10", "max", table=False),
    MetricSpec("consistency.conflict_fraction", "wall conflicts", "min", table=False),
    # linear-space weightings: updates that fell back to uniform weights (weighting=linear_exp, linear),
    # beside the accuracy they explain
    MetricSpec("weighting_overflows", "weight overflows", "min", hide_when_zero=True),
    MetricSpec("weighting_underflows", "weight underflows", "min", hide_when_zero=True),
    # Texture: mean |RGB - true floor colour| (0-255) on covered cells, along the SLAM path
    # and, as the baseline it should beat, along the odometry path.
    MetricSpec("texture.colour_error", "texture colour err", "min"),
    MetricSpec("texture.odometry.colour_error", "texture err (odometry)", None, detail=True),
    MetricSpec("texture.covered_area_m2", "texture area (m²)", None, table=False),
    # Wall time next to CPU time: wall time grows when jobs share the cores, CPU time does not.
    MetricSpec("runtime_s", "wall time (s)", "min"),
    MetricSpec("cpu_time_s", "CPU time (s)", "min"),
    MetricSpec("total_runtime_s", "total wall (s)", "min", detail=True),
    MetricSpec("total_cpu_time_s", "total CPU (s)", "min", table=False),
    MetricSpec("scans_per_s", "scans/s", "max"),
    MetricSpec("realtime_factor", "× real time", "max", detail=True),
    MetricSpec("peak_memory_mb", "peak memory (MB)", "min"),
    MetricSpec("map_memory.map_mb", "map MB (end)", "min", detail=True),
    MetricSpec("map_memory.map_peak_mb", "map MB (peak)", "min", table=False),
    MetricSpec("resample_count", "re\u00adsamples", None),
    MetricSpec("neff_mean", "N_eff mean", None),
    MetricSpec("neff_min", "N_eff min", None, detail=True),
)
METRIC_BY_KEY = {m.key: m for m in METRICS}

# Accuracy metrics tried in order for the "error versus parameter" plots.
ACCURACY_KEYS = ("trajectory.rmse_m", "relations.trans_abs_mean_m", "map.agreement")

# The headline metrics of a sweep, one per question (accuracy, rotation, runtime, memory,
# texture); within a group the first key the runs have is used. Runtime prefers CPU time
# because wall time is not comparable between jobs that ran side by side.
HEADLINE_GROUPS: tuple[tuple[str, ...], ...] = (
    ACCURACY_KEYS + ("consistency.contradiction_share",),
    ("trajectory.rot_rmse_deg", "relations.rot_abs_mean_deg"),
    ("cpu_time_s", "runtime_s"),
    ("peak_memory_mb",),
    ("texture.colour_error",),
)


# What only a particle filter has: a run of one trajectory (`filter=graph`, a `graph` section in
# its metrics) writes N_eff 1 and no resampling, which a table would show as if measured
PARTICLE_KEYS = frozenset({"resample_count", "neff_mean", "neff_min"})


def get_metric(metrics: dict[str, Any], key: str) -> float:
    """A dotted key from a metrics dict as float (NaN when absent, and for the particle
    filter's own keys on a run of one trajectory)."""
    if key in PARTICLE_KEYS and isinstance(metrics.get("graph"), dict):
        return float("nan")
    node: Any = metrics
    for part in key.split("."):
        if not isinstance(node, dict) or part not in node:
            return float("nan")
        node = node[part]
    return as_float(node)
