"""`metrics.json` as one typed object (docs/RUN_DIRECTORY.md, "metrics.json").

The pipeline fills a `RunMetrics` and the run directory writes it once; the reports read it
back. Fields are in the file's key order; None means "absent from the file" (sections that
do not apply, a failed run's missing statistics). A float that is not a number is NaN here
and `null` in the file. Nested sections (trajectory, map, relations, consistency, texture,
map_memory) stay plain mappings: their keys are the evaluators' (slamlab.eval) and differ
by dataset and version.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any

STATUS_OK = "ok"
STATUS_FAILED = "failed"
STATUS_INTERRUPTED = "interrupted"

# Top-level keys whose value is a float: `null` in the file reads back as NaN.
_FLOAT_KEYS = frozenset({
    "duration_s", "runtime_s", "scans_per_s", "realtime_factor", "neff_mean", "neff_min",
    "cpu_time_s", "total_runtime_s", "total_cpu_time_s", "peak_memory_mb",
})  # fmt: skip


@dataclass(slots=True)
class RunMetrics:
    """One run's metrics.json. Units: seconds (`*_s`, wall unless `cpu_`), MB, counts."""

    # "ok", "failed" or "interrupted"; None: the file has none (written before slamlab
    # recorded it: reports read such a run as ok, slamlab-verify refuses it)
    status: str | None = STATUS_OK
    # --- filter statistics (slamlab.pipeline.filter_metrics) ---
    dataset: str | None = None
    mode: str | None = None  # "slam", "odometry" or "predict"
    filter: str | None = None  # "course", "rbpf" or "graph"
    scans: int | None = None
    processed_steps: int | None = None
    particles: int | None = None
    seed: int | None = None
    duration_s: float | None = None  # sequence time span (s)
    runtime_s: float | None = None  # SLAM filter loop, wall (s)
    scans_per_s: float | None = None
    realtime_factor: float | None = None  # duration_s / runtime_s
    resample_count: int | None = None
    neff_mean: float | None = None
    neff_min: float | None = None
    trajectory_fill: str | None = None
    weighting_underflows: int | None = None
    weighting_overflows: int | None = None
    matcher_map_reads: int | None = None
    map_memory: dict[str, Any] | None = None  # MB and tile counts of the map(s)
    odometry_scale: float | None = None  # the best particle's learnt odometry scale at the end (motion.scale_gain_per_m > 0)
    odometry_jumps: list[dict[str, Any]] | None = None  # odometry increments taken as a reset of its frame, not motion (scan, t_s, m, deg; steps.odom_jump_m)
    thin_scans: dict[str, Any] | None = None  # processed steps whose scans had too few returns to match, when many (steps, share, min_returns, longest_m, from_s, to_s; slam/thin_scans.py)
    graph: dict[str, Any] | None = None  # filter=graph: nodes, submaps, loop searches and closures by status, optimisations and their time
    cpu_time_s: float | None = None  # SLAM filter loop, CPU (s)
    # --- accuracy sections (slamlab.eval); absent where the dataset cannot score them ---
    trajectory: dict[str, Any] | None = None
    map: dict[str, Any] | None = None
    relations: dict[str, Any] | None = None
    loop_truth: dict[str, Any] | None = None  # filter=graph on simulated data: accepted closures, how many wrong (slamlab.eval.closures)
    consistency: dict[str, Any] | None = None
    texture: dict[str, Any] | None = None
    # --- whole run ---
    total_runtime_s: float | None = None
    total_cpu_time_s: float | None = None
    peak_memory_mb: float | None = None
    peak_memory_scope: str | None = None  # "run" or "process"
    # --- failed or interrupted runs ---
    error: str | None = None
    traceback: str | None = None
    partial: bool | None = None  # interrupted after SLAM results were written
    interrupted_at_scan: int | None = None
    scans_total: int | None = None
    # keys this version does not know (older or newer files), kept as read
    extra: dict[str, Any] = field(default_factory=dict)
    # the key order of the file it was read from (reports list metrics in that order)
    _order: tuple[str, ...] = field(default=(), repr=False, compare=False)

    @property
    def ok(self) -> bool:
        return self.status == STATUS_OK

    def to_dict(self) -> dict[str, Any]:
        """The metrics.json mapping: present fields in file order, then unknown keys."""
        present = {f.name: getattr(self, f.name) for f in fields(self) if f.name not in ("extra", "_order")}
        present = {k: v for k, v in present.items() if v is not None}
        present.update(self.extra)
        if not self._order:
            return present
        ordered = {k: present[k] for k in self._order if k in present}
        ordered.update(present)  # fields set after reading go last
        return ordered

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RunMetrics:
        """Read a metrics.json mapping (any slamlab version): known keys become fields,
        `null` floats NaN, unknown keys `extra`. A file without `status` keeps None there."""
        known = {f.name for f in fields(cls)} - {"extra", "_order"}
        values: dict[str, Any] = {}
        extra: dict[str, Any] = {}
        for key, value in data.items():
            if key in known:
                values[key] = math.nan if value is None and key in _FLOAT_KEYS else value
            else:
                extra[key] = value
        values.setdefault("status", None)
        return cls(**values, extra=extra, _order=tuple(data))
