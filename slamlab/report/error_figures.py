"""Error over time for the run report: where a run went wrong, not only how much.

- `ate_over_time`: per-pose distance to ground truth (simulated data), SLAM and odometry;
- `relation_error_over_time`: per-relation errors (relations.csv, CARMEN/rosbag logs with a
  `.relations` file) against the relation's start time, SLAM and odometry, with the
  rotation error on a second panel.

On a real log the odometry drifts by tens of metres and half a turn while SLAM stays within
centimetres: on one shared axis SLAM's curve would be a flat line at zero. So each panel is
scaled to SLAM's errors when the odometry's are far larger (`SCALE_RATIO`), the odometry runs
off the top, and its legend entry says how far it goes.

Each `*_figure` function returns the matplotlib Figure (tests read its axes and lines); the
functions without the suffix return the `data:` URI the page embeds.
"""

from __future__ import annotations

import numpy as np

from slamlab.io.table import Table
from slamlab.report.figures import KIND_STYLE, fig_to_data_uri, rolling_median, subplots
from slamlab.report.error_series import pose_errors
from slamlab.report.mpl import Figure
from slamlab.report.rundir import Trajectory

# An axis is scaled to SLAM's errors when the odometry's reach this many times SLAM's top.
SCALE_RATIO = 5.0
HEADROOM = 1.25  # the axis top over the largest value it is scaled to


def ate_over_time(truth: Trajectory, estimates: dict[str, Trajectory | None]) -> str:
    return fig_to_data_uri(ate_over_time_figure(truth, estimates))


def ate_over_time_figure(truth: Trajectory, estimates: dict[str, Trajectory | None]) -> Figure:
    """Translation and heading error versus time since the first scan, one line per
    estimate (keys of KIND_STYLE: "slam", "odometry")."""
    fig, (a1, a2) = subplots(2, 1, figsize=(13.0, 4.6), sharex=True)
    t = truth.t - truth.t[0]
    errors = {kind: pose_errors(est, truth) for kind, est in estimates.items() if est is not None}
    for kind, (d, r) in errors.items():
        style = KIND_STYLE[kind]
        a1.plot(t[: len(d)], d, color=style["color"], lw=1.0, ls=style.get("ls", "-"),
                label=f"{style['label']} (RMSE {np.sqrt(np.mean(d**2)):.3f} m)")
        a2.plot(t[: len(r)], r, color=style["color"], lw=0.8, ls=style.get("ls", "-"))
    notes = [_scale_to_slam(a1, {k: v[0] for k, v in errors.items()}, "m"),
             _scale_to_slam(a2, {k: v[1] for k, v in errors.items()}, "°")]
    _finish(fig, a1, a2, "position error (m)", "heading error (°)", "time since first scan (s)")
    _note_off_scale(a1, notes)
    return fig


def relation_error_over_time(table: Table) -> str:
    return fig_to_data_uri(relation_error_over_time_figure(table))


def relation_error_over_time_figure(table: Table) -> Figure:
    """Per-relation translation and rotation error versus the relation's start time:
    points per relation and a rolling median, for SLAM and odometry."""
    t1 = np.asarray(table["t1"], float)
    order = np.argsort(t1, kind="stable")
    t1 = t1[order]
    t = t1 - float(np.nanmin(t1))
    fig, (a1, a2) = subplots(2, 1, figsize=(13.0, 4.6), sharex=True)
    win = max(5, len(table) // 15)  # relations are noisy: smooth over several
    trans_of, rot_of = {}, {}
    for kind in ("odometry", "slam"):
        if f"{kind}_trans_m" not in table:
            continue
        style = KIND_STYLE[kind]
        trans, rot = np.asarray(table[f"{kind}_trans_m"], float)[order], np.asarray(table[f"{kind}_rot_deg"], float)[order]
        trans_of[kind], rot_of[kind] = trans, rot
        label = f"{style['label']}: mean {np.mean(trans):.3g} m / {np.mean(rot):.3g}°"
        for ax, y, lab in ((a1, trans, label), (a2, rot, None)):
            ax.scatter(t, y, s=6, color=style["color"], alpha=0.35, lw=0)
            smooth = rolling_median(y, win)
            ax.plot(t, smooth, color=style["color"], lw=1.3, label=lab)
    a2.text(1.005, 0.95, f"lines: rolling median\nof {win} relations", transform=a2.transAxes, fontsize=8, va="top")
    notes = [_scale_to_slam(a1, trans_of, "m"), _scale_to_slam(a2, rot_of, "°")]
    _finish(fig, a1, a2, "translation error (m)", "rotation error (°)", "start of the relation, time since the first one (s)")
    _note_off_scale(a1, notes)
    return fig


def _scale_to_slam(ax, values: dict[str, np.ndarray], unit: str) -> str | None:
    """Fit the axis to SLAM's values when the odometry's are SCALE_RATIO times larger (a
    relation's outliers aside: the 99.5th percentile); returns the note for the odometry
    that then leaves the axis, else None. Errors start at 0 either way."""
    slam, odo = values.get("slam"), values.get("odometry")
    if slam is None or odo is None or not len(slam) or not len(odo):
        return None
    top = float(np.nanpercentile(slam, 99.5)) * HEADROOM
    odo_max = float(np.nanmax(odo))
    if not np.isfinite(top) or top <= 0 or odo_max < SCALE_RATIO * top:
        return None
    ax.set_ylim(0.0, top)
    return f"{odo_max:.3g}{'' if unit == '°' else ' '}{unit}"


def _note_off_scale(ax, notes: list[str | None]) -> None:
    """Say on the figure, beside the legend, that the odometry runs off the SLAM-scaled axes."""
    trans, rot = notes
    if trans is None and rot is None:
        return
    parts = [p for p in (f"translation up to {trans}" if trans else None, f"rotation up to {rot}" if rot else None) if p]
    ax.text(1.005, 0.0, "axes scaled to SLAM:\nodometry (red) runs\noff the top: " + ",\n".join(parts),
            transform=ax.transAxes, fontsize=8, va="bottom", color=KIND_STYLE["odometry"]["color"])


def _finish(fig, a1, a2, y1: str, y2: str, xlabel: str) -> None:
    """Labels, grid, errors from 0 and the legend outside the data, for both error figures."""
    a1.set_ylabel(y1)
    a2.set_ylabel(y2)
    a2.set_xlabel(xlabel)
    for a in (a1, a2):
        a.grid(alpha=0.3)
        a.set_ylim(bottom=0)
    a1.legend(loc="upper left", bbox_to_anchor=(1.005, 1.0), fontsize=8)
    fig.tight_layout()
