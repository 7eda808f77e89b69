"""Error over time for the run report: where a run went wrong, not only how much.

- `ate_over_time`: per-pose distance to ground truth (simulated data), SLAM and odometry;
- `relation_error_over_time`: per-relation errors (relations.csv, CARMEN/rosbag logs with a
  `.relations` file) against the relation's start time, SLAM and odometry, with the
  rotation error on a second panel.
"""

from __future__ import annotations

import numpy as np

from slamlab.io.table import Table
from slamlab.report.figures import KIND_STYLE, fig_to_data_uri, rolling_median, subplots
from slamlab.report.error_series import pose_errors
from slamlab.report.rundir import Trajectory


def ate_over_time(truth: Trajectory, estimates: dict[str, Trajectory | None]) -> str:
    """Translation and heading error versus time since the first scan, one line per
    estimate (keys of KIND_STYLE: "slam", "odometry")."""
    fig, (a1, a2) = subplots(2, 1, figsize=(13.0, 4.6), sharex=True)
    t = truth.t - truth.t[0]
    for kind, est in estimates.items():
        if est is None:
            continue
        d, r = pose_errors(est, truth)
        style = KIND_STYLE[kind]
        a1.plot(t[: len(d)], d, color=style["color"], lw=1.0, ls=style.get("ls", "-"),
                label=f"{style['label']} (RMSE {np.sqrt(np.mean(d**2)):.3f} m)")
        a2.plot(t[: len(r)], r, color=style["color"], lw=0.8, ls=style.get("ls", "-"))
    return _finish(fig, a1, a2, "position error (m)", "heading error (°)", "time since first scan (s)")


def relation_error_over_time(table: Table) -> str:
    """Per-relation translation and rotation error versus the relation's start time:
    points per relation and a rolling median, for SLAM and odometry."""
    t1 = np.asarray(table["t1"], float)
    order = np.argsort(t1, kind="stable")
    t1 = t1[order]
    t = t1 - float(np.nanmin(t1))
    fig, (a1, a2) = subplots(2, 1, figsize=(13.0, 4.6), sharex=True)
    win = max(5, len(table) // 15)  # relations are noisy: smooth over several
    for kind in ("odometry", "slam"):
        if f"{kind}_trans_m" not in table:
            continue
        style = KIND_STYLE[kind]
        trans, rot = np.asarray(table[f"{kind}_trans_m"], float)[order], np.asarray(table[f"{kind}_rot_deg"], float)[order]
        label = f"{style['label']}: mean {np.mean(trans):.3g} m / {np.mean(rot):.3g}°"
        for ax, y, lab in ((a1, trans, label), (a2, rot, None)):
            ax.scatter(t, y, s=6, color=style["color"], alpha=0.35, lw=0)
            smooth = rolling_median(y, win)
            ax.plot(t, smooth, color=style["color"], lw=1.3, label=lab)
    a2.text(1.005, 0.95, f"lines: rolling median\nof {win} relations", transform=a2.transAxes, fontsize=8, va="top")
    return _finish(fig, a1, a2, "translation error (m)", "rotation error (°)", "start of the relation, time since the first one (s)")


def _finish(fig, a1, a2, y1: str, y2: str, xlabel: str) -> str:
    """Labels, grid, errors from 0 and the legend outside the data, for both error figures."""
    a1.set_ylabel(y1)
    a2.set_ylabel(y2)
    a2.set_xlabel(xlabel)
    for a in (a1, a2):
        a.grid(alpha=0.3)
        a.set_ylim(bottom=0)
    a1.legend(loc="upper left", bbox_to_anchor=(1.005, 1.0), fontsize=8)
    fig.tight_layout()
    return fig_to_data_uri(fig)
