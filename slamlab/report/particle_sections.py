"""The run report's sections about single scans and single particles (the course's
preparation ladder): the first scan on its map, every particle's path and spread in a
prediction-only run, each particle's weight per step with a few particles, and a notice when
a linear-space weighting under- or overflowed.

Each function takes a loaded run and returns what the template shows, or None to omit the
section; all of it is read from the run's files (`record.*`, steps, metrics).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from slamlab.io.table import Table
from slamlab.report import particle_figures
from slamlab.report.figures import fig_to_data_uri
from slamlab.report.html import fmt_number
from slamlab.report.rundir import RunDir
from slamlab.numeric import OVERFLOW_SCORE

# The weights section is for a handful of particles: a column each.
WEIGHTS_MAX_PARTICLES = 10
# Rows of the per-step weight table; the plot shows every step, particles.npz holds them all.
WEIGHT_TABLE_ROWS = 100
WEIGHT_DIGITS = 6


def first_scan_section(run: RunDir) -> dict[str, Any] | None:
    """The map with the first scan's points in the world frame (record.first_scan)."""
    scan = run.load_first_scan()
    if scan is None:
        return None
    m = run.load_map()
    steps = run.metrics.get("processed_steps")
    only = steps == 1
    return {
        "img": fig_to_data_uri(particle_figures.first_scan_figure(m, scan)),
        "note": (
            f"The first processed scan's {len(scan.points_xy)} points (red) in the world frame, seen from the start "
            f"pose ({fmt_number(float(scan.pose[0]))}, {fmt_number(float(scan.pose[1]))}) m, heading "
            f"{fmt_number(float(np.degrees(scan.pose[2])))}° (arrow). "
            + ("The map holds this scan only: each point's cell is occupied (black), the cells along each beam "
               "are free (white), everything else is unknown (grey)." if only else
               f"The map behind it is the final map of all {fmt_number(steps)} steps.")
        ),
    }


def predict_section(run: RunDir) -> dict[str, Any] | None:
    """Every particle's path and the cloud's spread against the configured noise (mode=predict)."""
    if run.metrics.get("mode") != "predict":
        return None
    rec = run.load_particles()
    steps = run.load_steps()
    out: dict[str, Any] = {"paths_img": None, "spread_img": None, "rows": [], "note": ""}
    if rec is not None:
        fig = particle_figures.particle_paths_figure(run.load_map(), rec, run.load_trajectory("odometry"),
                                                     run.load_trajectory("groundtruth"))
        out["paths_img"] = fig_to_data_uri(fig)
    if steps is not None and "expected_spread_xy_m" in steps:
        out["spread_img"] = fig_to_data_uri(particle_figures.spread_figure(steps))
        out["rows"] = spread_rows(steps)
    if rec is None and out["spread_img"] is None:
        out["note"] = "This run kept no particle history (record.particles=false) and no spread columns."
    return out


def spread_rows(steps: Table, marks_m: tuple[float, ...] = (0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0)) -> list[list[str]]:
    """Measured against expected spread at the first step past each distance mark (and the
    last step): [distance m, time s, measured m, expected m, ratio, measured °, expected °]."""
    d = np.asarray(steps["distance_m"], float)
    picks = [int(np.argmax(d >= mark)) for mark in marks_m if d[-1] >= mark] + [len(d) - 1]
    rows = []
    t = np.asarray(steps["t"], float) - float(steps["t"][0])
    for k in dict.fromkeys(picks):
        sx, ex = float(steps["spread_xy_m"][k]), float(steps["expected_spread_xy_m"][k])
        st, et = float(steps["spread_theta_rad"][k]), float(steps["expected_spread_theta_rad"][k])
        rows.append([fmt_number(d[k]), fmt_number(t[k]), fmt_number(sx), fmt_number(ex),
                     fmt_number(sx / ex) if ex > 0 else "–", fmt_number(np.degrees(st)), fmt_number(np.degrees(et))])
    return rows


def weights_section(run: RunDir) -> dict[str, Any] | None:
    """Each particle's weight at every step, stacked, and as a table (a few particles)."""
    if run.metrics.get("mode", "slam") != "slam":
        return None
    rec = run.load_particles()
    if rec is None or rec.particles > WEIGHTS_MAX_PARTICLES:
        return None
    k = len(rec.t)
    t = rec.t - rec.t[0] if k else rec.t
    w = rec.weights
    neff = 1.0 / np.sum(w * w, axis=1)
    rows = []
    for i in range(min(k, WEIGHT_TABLE_ROWS)):
        after = ""
        if rec.resampled[i]:
            after = "yes: " + ", ".join(f"{j}←{int(p)}" for j, p in enumerate(rec.parents[i + 1])) if i + 1 < k else "yes"
        rows.append({
            "step": i,
            "t": fmt_number(float(t[i])),
            "weights": [fmt_number(float(v), WEIGHT_DIGITS) for v in w[i]],
            "neff": fmt_number(float(neff[i])),
            "resampled": after,
        })
    return {
        "img": fig_to_data_uri(particle_figures.weights_figure(rec, WEIGHT_TABLE_ROWS)),
        "particles": rec.particles,
        "rows": rows,
        "shown": len(rows),
        "steps": k,
        "resamples": int(np.sum(rec.resampled)),
    }


def weighting_notice(run: RunDir) -> str | None:
    """Say so when a linear-space weighting fell back to uniform weights."""
    m = run.metrics
    over = int(m.get("weighting_overflows") or 0)
    under = int(m.get("weighting_underflows") or 0)
    if not (over or under):
        return None
    steps = m.get("processed_steps")
    weighting = run.config.get("weighting", {})
    target = str(weighting.get("_target_", "")).rsplit(".", 1)[-1] if isinstance(weighting, dict) else ""
    parts = []
    if over:
        parts.append(f"overflowed at {over} updates (exp(correlation) is infinite in float64 for correlations above "
                     f"{OVERFLOW_SCORE:.1f}, so the weights were inf / inf)")
    if under:
        parts.append(f"underflowed at {under} updates (every weight became 0 in float64)")
    return (
        f"The weighting{f' ({target})' if target else ''} " + " and ".join(parts)
        + f", out of {fmt_number(steps)} steps. Those updates fell back to uniform weights: the scan said nothing about "
        "which particle is better. weighting=logsumexp computes the same exp(correlation) model in log space, which "
        "neither overflows nor underflows."
    )
