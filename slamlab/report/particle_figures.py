"""Figures of individual particles and scans, for the preparation-ladder reports: the first
scan on its map, every particle's path (prediction only), the cloud's spread against the
configured noise, and each particle's weight per step (a few particles).

Each `*_figure` function returns the matplotlib Figure (tests count what it draws);
`figures.fig_to_data_uri` turns it into an <img> source.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from slamlab.io.table import Table
from slamlab.report.figures import KIND_STYLE, draw_map, prepare_map, step_times, subplots
from slamlab.report.mpl import Figure, LineCollection, colormaps
from slamlab.report.rundir import FirstScan, LogOddsMap, ParticleRecord, Trajectory

PARTICLE_COLOUR = "#1f77b4"
RESAMPLE_COLOUR = "#ff7f0e"


def first_scan_figure(m: LogOddsMap | None, scan: FirstScan, figsize: tuple[float, float] = (8.0, 7.0)) -> Figure:
    """The map built from one scan, with that scan's points (world frame) and the lidar."""
    fig, ax = subplots(figsize=figsize)
    pts = Trajectory(t=np.zeros(len(scan.points_xy)), xy=scan.points_xy, yaw=np.zeros(len(scan.points_xy)))
    draw_map(ax, prepare_map(m, 800, [pts], margin_m=0.5) if m is not None else None)
    ax.plot(scan.points_xy[:, 0], scan.points_xy[:, 1], ".", ms=2.5, color="#d62728",
            label=f"scan points ({len(scan.points_xy)})")
    ax.plot(*scan.sensor_xy, "o", color="#1f77b4", ms=7, label="lidar")
    x, y, th = scan.pose
    ax.annotate("", xy=(x + 0.6 * np.cos(th), y + 0.6 * np.sin(th)), xytext=(x, y),
                arrowprops=dict(arrowstyle="->", color="#1f77b4", lw=1.6))
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.legend(loc="best", fontsize=9, framealpha=0.85)
    return fig


def particle_paths_figure(
    m: LogOddsMap | None,
    rec: ParticleRecord,
    odometry: Trajectory | None,
    groundtruth: Trajectory | None,
    figsize: tuple[float, float] = (9.5, 8.0),
    margin_m: float = 1.0,
) -> Figure:
    """Every particle's path (one thin line each, step by step) over the map, with the
    odometry and the true path. Meaningful when particles are never resampled (predict
    mode): particle j at step k is then the same particle as at step k-1."""
    paths = np.transpose(rec.poses[:, :, :2], (1, 0, 2))  # (N, K, 2)
    fig, ax = subplots(figsize=figsize)
    others = [t for t in (odometry, groundtruth) if t is not None]
    flat = Trajectory(t=np.zeros(paths.shape[0] * paths.shape[1]), xy=paths.reshape(-1, 2), yaw=np.zeros(0))
    draw_map(ax, prepare_map(m, 800, [flat, *others]) if m is not None else None)
    lines = LineCollection(list(paths), colors=PARTICLE_COLOUR, linewidths=0.5, alpha=0.35,
                           label=f"particles ({paths.shape[0]} paths)")
    ax.add_collection(lines)
    if groundtruth is not None:
        ax.plot(groundtruth.xy[:, 0], groundtruth.xy[:, 1], **KIND_STYLE["groundtruth"])
    if odometry is not None:
        ax.plot(odometry.xy[:, 0], odometry.xy[:, 1], **KIND_STYLE["odometry"])
    ax.plot(paths[:, -1, 0], paths[:, -1, 1], ".", color="black", ms=2.5, label="particles at the end")
    # zoom on the paths (the map can be far larger than a short run's cloud)
    xy = np.concatenate([flat.xy, *[t.xy for t in others]])
    lo, hi = xy.min(axis=0) - margin_m, xy.max(axis=0) + margin_m
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.legend(loc="best", fontsize=9, framealpha=0.85)
    return fig


def spread_figure(steps: Table) -> Figure:
    """Measured spread of the particle cloud against the spread the configured motion noise
    predicts (steps columns of a predict run), position (m) and heading (degrees)."""
    fig, (a1, a2) = subplots(2, 1, figsize=(9.0, 5.0), sharex=True)
    t = step_times(steps)
    for ax, col, scale, unit in ((a1, "xy_m", 1.0, "position spread (m)"), (a2, "theta_rad", 180.0 / np.pi, "heading spread (°)")):
        ax.plot(t, np.asarray(steps[f"spread_{col}"], float) * scale, lw=1.1, color=PARTICLE_COLOUR, label="measured (particles)")
        ax.plot(t, np.asarray(steps[f"expected_spread_{col}"], float) * scale, lw=1.1, ls="--", color="black",
                label="expected from the configured noise")
        ax.set_ylabel(unit)
        ax.grid(alpha=0.3)
        ax.legend(loc="upper left", fontsize=8)
    if "distance_m" in steps:
        top = a1.secondary_xaxis("top", functions=_time_to_distance(t, np.asarray(steps["distance_m"], float)))
        top.set_xlabel("odometry distance travelled (m)")
    a2.set_xlabel("time since first step (s)")
    return fig


def _time_to_distance(t: np.ndarray, d: np.ndarray) -> tuple[Callable, Callable]:
    """Forward/inverse maps between time and distance for a secondary axis (monotone
    interpolation; the inverse uses unique distances since a standing robot repeats them)."""
    du, idx = np.unique(d, return_index=True)
    return (lambda x: np.interp(x, t, d), lambda y: np.interp(y, du, t[idx]))


def weights_figure(rec: ParticleRecord, first_steps: int = 100) -> Figure:
    """Each particle's normalised weight at every step, stacked (they sum to 1), with the
    steps that resampled marked; a second panel zooms on the first `first_steps` steps
    when the run is longer (the report's table shows those)."""
    k, n = rec.weights.shape
    windows = [(0, k)] + ([(0, first_steps)] if k > first_steps else [])
    fig, axes = subplots(len(windows), 1, figsize=(9.0, 3.2 * len(windows)), squeeze=False)
    colours = colormaps["tab10"]
    for ax, (a, b) in zip(axes[:, 0], windows):
        steps = np.arange(a, b)
        ax.stackplot(steps, rec.weights[a:b].T, colors=[colours(i % 10) for i in range(n)],
                     labels=[f"particle {i}" for i in range(n)], step="post", alpha=0.9, lw=0)
        res = np.flatnonzero(rec.resampled[a:b]) + a
        if res.size:
            ax.plot(res, np.full(res.size, 1.03), "v", color="black", ms=4, clip_on=False,
                    label=f"resampled ({res.size}x)")
        ax.set_xlim(a, max(b - 1, a + 1))
        ax.set_ylim(0, 1)
        ax.set_ylabel("normalised weight")
        ax.set_title(f"steps {a}-{b - 1}" + (" (all)" if (a, b) == (0, k) else ""), fontsize=9, pad=12)
        ax.legend(loc="center left", bbox_to_anchor=(1.01, 0.5), fontsize=8)
    axes[-1, 0].set_xlabel("filter step")
    fig.tight_layout()
    return fig
