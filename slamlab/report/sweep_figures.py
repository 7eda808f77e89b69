"""Figures only the sweep report draws: headline metrics versus a swept parameter (one line
per value of the other parameters), error over time of every configuration on one axis,
and one map per run large enough to compare. All return `data:` PNG URIs.

Speed matters (a 12-run sweep report must build in < 10 s on two shared cores): the panel
figures use fixed margins instead of tight bounding boxes (each costs a full extra draw),
and maps are drawn as pixels with Pillow, not through matplotlib.
"""

from __future__ import annotations

import base64
import io
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd
from PIL import Image, ImageDraw

from slamlab.report.figures import DPI, Series, prepare_map, subplots
from slamlab.report.mpl import Figure, Line2D, colormaps
from slamlab.report.rundir import LogOddsMap, Trajectory

PANELS_PER_ROW = 3
MIN_MAP_PX = 420  # a small map is enlarged by whole pixels up to this longest side


def _colour(i: int, n: int = 10):
    """The i-th of n distinct colours (tab10, tab20 beyond ten)."""
    return colormaps["tab10"](i % 10) if n <= 10 else colormaps["tab20"](i % 20)


def _png_uri(data: bytes) -> str:
    return "data:image/png;base64," + base64.b64encode(data).decode("ascii")


def _fixed_layout_uri(fig: Figure) -> str:
    """Save a figure whose margins were set by hand (no tight bounding box: one draw, not three)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    return _png_uri(buf.getvalue())


MAX_TICK_CHARS = 18  # a category's tick label is cut to this many characters


def tick_label(value: str) -> str:
    """A category as a tick label: a path by its file name, anything long cut with an ellipsis
    (the table beside the figure has the full value)."""
    text = str(value)
    if "/" in text:
        text = text.rstrip("/").rsplit("/", 1)[-1] or text
    return text if len(text) <= MAX_TICK_CHARS else text[: MAX_TICK_CHARS - 1] + "…"


def metric_panels(param: str, panels: Sequence[tuple[str, Sequence[Series]]],
                  categorical: Sequence[str] | None = None) -> str:
    return _png_uri(_render(metric_panels_figure(param, panels, categorical)))


def _render(fig: Figure) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    return buf.getvalue()


def metric_panels_figure(param: str, panels: Sequence[tuple[str, Sequence[Series]]],
                         categorical: Sequence[str] | None = None) -> Figure:
    """One panel per headline metric against swept parameter `param`; each Series is one
    value of the other swept parameters (same colour in every panel, one legend on top).
    Bars: standard deviation across seeds; faint points: the single runs. Every value axis
    starts at 0 (all headline metrics are errors, times or sizes): a 0.015 degree difference
    must not fill a panel. Category names are cut to fit (`tick_label`), and matplotlib's
    constrained layout keeps tick labels, axis titles and the legend clear of each other."""
    labels: dict[str, int] = {}
    for panel in panels:
        for s in panel[1]:
            labels.setdefault(s.label, len(labels))
    legend = len(labels) > 1 or bool(labels and next(iter(labels)))
    n = len(panels)
    ncols = min(PANELS_PER_ROW, n)
    nrows = int(math.ceil(n / ncols))
    longest = max((len(label) for label in labels), default=1)
    per_row = max(1, min(4, len(labels), int(4.6 * ncols * 12 // max(longest, 1))))  # ~12 characters an inch at 9 pt
    height_in = 3.1 * nrows + (0.3 * math.ceil(len(labels) / per_row) if legend else 0.0)
    fig = Figure(figsize=(4.6 * ncols, height_in), layout="constrained")
    axes = np.atleast_2d(fig.subplots(nrows, ncols, squeeze=False))
    ticks = [tick_label(c) for c in categorical] if categorical is not None else None
    rotate = ticks is not None and (sum(len(t) for t in ticks) > 30 or max(map(len, ticks)) > 10)
    for ax, (metric_label, series) in zip(axes.flat, panels):
        for s in series:
            c = _colour(labels[s.label])
            # Categories (resampler names) have no order: no connecting line, and each series
            # shifted a little sideways so bars at the same category do not hide each other.
            dx = 0.06 * (labels[s.label] - (len(labels) - 1) / 2) if categorical is not None else 0.0
            ax.scatter(s.points_x + dx, s.points_y, s=12, color=c, alpha=0.4, lw=0)
            ax.errorbar(s.x + dx, s.mean, yerr=s.std, color=c, marker="o", ms=4, lw=1.3, capsize=3, label=s.label,
                        ls="none" if categorical is not None else "-")
        ax.set_xlabel(param)
        ax.set_ylabel(metric_label)
        ax.grid(alpha=0.3)
        ax.set_ylim(bottom=0.0)
        if ticks is not None:
            ax.set_xticks(range(len(ticks)), ticks, rotation=30 if rotate else 0, ha="right" if rotate else "center",
                          rotation_mode="anchor", fontsize=8)
            ax.set_xlim(-0.5, len(ticks) - 0.5)
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    if legend:
        handles = [Line2D([], [], color=_colour(i), marker="o", lw=1.3) for i in labels.values()]
        fig.legend(handles, list(labels), loc="outside upper center", ncol=per_row, fontsize=9, frameon=False)
    return fig


@dataclass(frozen=True, slots=True)
class ErrorCurve:
    """One run's error over time; runs of one configuration share `group` (and colour)."""

    group: str
    t: np.ndarray
    error_m: np.ndarray


def error_over_time(curves: Sequence[ErrorCurve], ylabel: str, smooth: bool) -> str:
    """Every run's error against time on one axis, one colour per configuration (its seeds
    are lines of the same colour). `smooth`: draw a rolling median (~1/40 of the points),
    for per-relation errors that scatter widely around their trend."""
    fig, ax = subplots(figsize=(12.0, 4.0))
    fig.subplots_adjust(left=0.06, right=0.74, bottom=0.13, top=0.96)  # legend right of the axes
    groups = list(dict.fromkeys(c.group for c in curves))
    for c in curves:
        y = c.error_m
        if smooth and y.size > 40:
            y = pd.Series(y).rolling(max(1, y.size // 40), center=True, min_periods=1).median().to_numpy()
        ax.plot(c.t, y, lw=1.0, alpha=0.85, color=_colour(groups.index(c.group), len(groups)))
    handles = [Line2D([], [], color=_colour(i, len(groups)), lw=1.6) for i in range(len(groups))]
    ax.legend(handles, groups, loc="center left", bbox_to_anchor=(1.01, 0.5), fontsize=8, frameon=False)
    ax.set_xlabel("time since the first scan (s)")
    ax.set_ylabel(ylabel)
    ax.set_ylim(bottom=0.0)
    ax.grid(alpha=0.3)
    return _fixed_layout_uri(fig)


def _to_pixels(xy: np.ndarray, extent: tuple[float, float, float, float], size: tuple[int, int]) -> list[tuple[float, float]]:
    """Metric (x, y) to image (column, row) for an image of `size` (w, h) covering `extent`,
    row 0 at the top."""
    x0, x1, y0, y1 = extent
    w, h = size
    cols = (xy[:, 0] - x0) / (x1 - x0) * w
    rows = (y1 - xy[:, 1]) / (y1 - y0) * h
    return list(zip(cols.tolist(), rows.tolist()))


def run_map(m: LogOddsMap, slam: Trajectory | None, groundtruth: Trajectory | None,
            max_px: int = 560) -> tuple[str, tuple[float, float]]:
    """One run's own map (free white, walls black, unknown grey; cropped to what it saw and the
    paths) with its SLAM path in blue and, when known, the ground truth in thin black. At most
    `max_px` per side, at least MIN_MAP_PX (enlarged by whole pixels), so maps placed side by side
    can be compared wall by wall. Drawn with Pillow: a dozen maps in well under a second.
    Returns the URI and the (width, height) in metres that the image covers."""
    trs = [t for t in (slam, groundtruth) if t is not None and len(t)]
    view = prepare_map(m, max_px, trs)
    grey = np.clip(np.flipud(view.image) * 255.0, 0, 255).astype(np.uint8)
    im = Image.fromarray(grey, mode="L").convert("RGB")
    k = math.ceil(MIN_MAP_PX / max(im.size))
    if k > 1:
        im = im.resize((im.width * k, im.height * k), Image.NEAREST)
    draw = ImageDraw.Draw(im)
    # Truth last and thin: where the paths agree, a black line runs inside the blue one.
    for tr, colour, width in ((slam, (31, 119, 180), 3), (groundtruth, (0, 0, 0), 1)):
        if tr is not None and len(tr) > 1:
            draw.line(_to_pixels(tr.xy, view.extent, im.size), fill=colour, width=width)
    buf = io.BytesIO()
    im.save(buf, format="PNG")
    x0, x1, y0, y1 = view.extent
    return _png_uri(buf.getvalue()), (x1 - x0, y1 - y0)
