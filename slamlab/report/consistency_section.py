"""The run report's "Is the map consistent?" section, read from the run's files: the verdict
(metrics.json "consistency", made by `slamlab.eval.consistency`), the map with where its
scans contradict it (consistency_map.npz) and the contradiction share over time
(consistency.csv). Nothing is recomputed here.

Each `*_figure` function returns the matplotlib Figure (tests read what it draws);
`figures.fig_to_data_uri` turns it into an <img> source.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from slamlab.io.rundir import RunFile
from slamlab.io.table import Table
from slamlab.numeric import block_max
from slamlab.report.byte_image import imshow_bytes
from slamlab.report.figures import draw_map, fig_to_data_uri, prepare_map, rgba_bytes, rolling_median, step_times, subplots
from slamlab.report.mpl import Figure
from slamlab.report.rundir import LogOddsMap, RunDir, Trajectory
from slamlab.report.span_closures import closures_at, closures_note

SEE_THROUGH_RGB = (0.84, 0.15, 0.16)  # beams that saw through a wall of the map
IN_FREE_RGB = (0.12, 0.47, 0.71)  # beams that ended in the map's free space
SPAN_COLOUR = "#e36209"


@dataclass(frozen=True, slots=True)
class ConsistencySection:
    """What run.html shows: the verdict line (`ok`: consistent), the overlay and the curve,
    and one row per broken stretch."""

    verdict: str
    ok: bool | None  # None: too short to judge (or an older run without a verdict)
    overlay_img: str | None
    overlay_note: str
    curve_img: str | None
    spans: list[dict[str, str]]
    shares: str
    closures_note: str  # how to read the spans' "closures" lines (`span_closures.closures_note`)


def broken_spans(run: RunDir) -> list[dict[str, Any]]:
    """The stretches the verdict names likely broken, worst first (metrics.json
    consistency.broken_spans; none for a run without a verdict)."""
    cons = run.metrics.get("consistency")
    return [s for s in (cons.get("broken_spans") or [] if isinstance(cons, dict) else []) if isinstance(s, dict)]


def verdict_line(consistency: dict[str, Any] | None) -> tuple[str, bool | None] | None:
    """(the one line a reader sees first, whether it says consistent), from metrics.json's
    "consistency"; None for a run without one (older runs, or nothing replayed)."""
    if not isinstance(consistency, dict) or "verdict" not in consistency:
        return None
    verdict = str(consistency["verdict"])
    text = str(consistency.get("verdict_text") or verdict)
    return text[:1].upper() + text[1:], (True if verdict == "consistent" else False if verdict == "likely broken" else None)


def overlay_figure(m: LogOddsMap, layers: dict[str, np.ndarray], spans: list[dict[str, Any]],
                   path: Trajectory | None, max_px: int = 1000, width_in: float = 13.0) -> Figure:
    """The map in light grey with, over it, the cells where replayed beams saw through a wall
    (red) or ended in free space (blue) (`consistency_map.npz`: counts per cell of `bin_m`), the
    per-region contradiction share as orange shading (regions of `region_m`, 20 % and up), the
    SLAM path faintly, and each broken stretch circled and numbered (metrics.json)."""
    view = prepare_map(m, max_px, [path] if path is not None else [])
    x0, x1, y0, y1 = view.extent
    aspect = (y1 - y0) / max(x1 - x0, 1e-9)
    fig, ax = subplots(figsize=(width_in, float(np.clip(width_in * 0.8 * aspect, 4.0, 13.0))))
    light = view.image  # walls dark grey, free white: the overlay stays readable (0.55 + 0.45 v, in place: this view's own array)
    light *= 0.45
    light += 0.55
    draw_map(ax, type(view)(image=light, extent=view.extent))
    ox, oy = (float(v) for v in np.asarray(layers["origin_xy"]).reshape(2))
    share = np.asarray(layers.get("region_share", np.zeros((0, 0))), dtype=float)
    if share.size:
        g = float(layers["region_m"])
        rgba = np.zeros(share.shape + (4,))
        rgba[..., :3] = (0.89, 0.38, 0.04)
        rgba[..., 3] = np.where(np.isfinite(share) & (share >= 0.2), np.clip(np.nan_to_num(share), 0, 1) * 0.55, 0.0)
        imshow_bytes(ax, rgba_bytes(rgba), (ox, ox + share.shape[1] * g, oy, oy + share.shape[0] * g), zorder=2)
    # the cells with contradicting beams, pooled so that one shows as at least ~2 pixels of the
    # figure (a building's 0.25 m cells would vanish when the figure shrinks them)
    k = max(1, int(math.ceil(max(x1 - x0, y1 - y0) / float(layers["bin_m"]) / (max_px / 2))))
    b = float(layers["bin_m"]) * k
    names = ("in_free", "see_through", "broken_in_free", "broken_see_through")
    pooled = {name: block_max(np.asarray(layers[name]).astype(np.int32), k) for name in names if name in layers}
    h, w = pooled["see_through"].shape
    events = np.zeros((h, w, 4))
    # every contradicting beam faint (people, clutter and glass scatter them over any map), those of
    # the broken stretches strong: they are what the verdict names
    for name, rgb, alpha in (("in_free", IN_FREE_RGB, 0.3), ("see_through", SEE_THROUGH_RGB, 0.3),
                             ("broken_in_free", IN_FREE_RGB, 0.95), ("broken_see_through", SEE_THROUGH_RGB, 0.95)):
        if name in pooled:
            hit = pooled[name] > 0
            events[hit, :3] = rgb
            events[hit, 3] = alpha
    imshow_bytes(ax, rgba_bytes(events), (ox, ox + w * b, oy, oy + h * b), zorder=3)
    if path is not None and len(path):
        ax.plot(path.xy[:, 0], path.xy[:, 1], color="#1f77b4", lw=0.6, alpha=0.35, zorder=4)
    draw_spans(ax, spans)
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    handles = [_patch(SEE_THROUGH_RGB, "a beam saw through a wall of the map", 0.3),
               _patch(IN_FREE_RGB, "a beam ended where the map is free", 0.3)]
    if spans:
        handles += [_patch(SEE_THROUGH_RGB, "... in a stretch likely broken"), _patch(IN_FREE_RGB, "... in a stretch likely broken")]
    if share.size and np.nanmax(np.append(share.ravel(), 0.0)) >= 0.2:
        handles.append(_patch((0.89, 0.38, 0.04), f"region ({float(layers['region_m']):g} m) where 20 %+ of beams contradict", 0.45))
    if spans:
        handles.append(_line(SPAN_COLOUR, "likely broken here (numbered, worst first)"))
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=9)
    return fig


def draw_spans(ax, spans: list[dict[str, Any]]) -> None:
    """Each broken stretch (metrics.json consistency.broken_spans) circled where its
    contradicting beams gather and numbered, worst first: on this section's map and on the
    loop closures' (`loops_section`)."""
    for i, s in enumerate(spans, start=1):
        if not all(math.isfinite(float(s.get(k, math.nan))) for k in ("x_m", "y_m", "radius_m")):
            continue
        circle = _circle(float(s["x_m"]), float(s["y_m"]), float(s["radius_m"]))
        ax.plot(*circle, color=SPAN_COLOUR, lw=2.0, zorder=5)
        ax.text(float(s["x_m"]) + float(s["radius_m"]) * 0.75, float(s["y_m"]) + float(s["radius_m"]) * 0.75, str(i),
                color="white", fontsize=11, fontweight="bold", zorder=6, ha="center", va="center",
                bbox=dict(boxstyle="circle,pad=0.25", fc=SPAN_COLOUR, ec="none"))


def _circle(x: float, y: float, r: float) -> tuple[np.ndarray, np.ndarray]:
    a = np.linspace(0, 2 * np.pi, 90)
    return x + r * np.cos(a), y + r * np.sin(a)


def _patch(rgb, label: str, alpha: float = 0.9):
    from matplotlib.patches import Patch

    return Patch(facecolor=(*rgb, alpha), edgecolor="none", label=label)


def _line(colour: str, label: str):
    from slamlab.report.mpl import Line2D

    return Line2D([], [], color=colour, lw=2.0, label=label)


def curve_figure(series: Table, threshold: float, spans: list[dict[str, Any]]) -> Figure:
    """Each replayed scan's contradiction share (grey), the rolling median the verdict reads
    (black; consistency.csv `contradiction_window`), the threshold (dashed red) and the broken
    stretches shaded and numbered as on the map."""
    fig, ax = subplots(figsize=(13.0, 2.9))
    t = step_times(series)
    y = np.asarray(series["contradiction"], dtype=float)
    ax.plot(t, y, lw=0.5, color="#7f7f7f", alpha=0.6, label="per replayed scan")
    window = np.asarray(series["contradiction_window"], dtype=float) if "contradiction_window" in series else rolling_median(y, 25)
    ax.plot(t, window, lw=1.5, color="black", label="rolling median (the verdict's)")
    ax.axhline(threshold, color="#d62728", ls="--", lw=1.0, label=f"likely broken at {threshold:.0%}")
    for i, s in enumerate(spans, start=1):
        a, b = float(s["t1_s"]), float(s["t2_s"])
        ax.axvspan(a, max(b, a + 1e-6), color=SPAN_COLOUR, alpha=0.25, lw=0)
        ax.text((a + b) / 2, 0.97, str(i), transform=ax.get_xaxis_transform(), ha="center", va="top", fontsize=10,
                color=SPAN_COLOUR, fontweight="bold")
    ax.set_ylim(0.0, 1.0)
    ax.set_ylabel("beams contradicting\nthe map (share)")
    ax.set_xlabel("time since the first replayed scan (s)")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", bbox_to_anchor=(1.005, 1.0), fontsize=8)
    return fig


def consistency_section(run: RunDir) -> ConsistencySection | None:
    """The section for a run whose metrics.json has a consistency verdict, else None."""
    cons = run.metrics.get("consistency")
    line = verdict_line(cons)
    if line is None:
        return None
    text, ok = line
    spans = broken_spans(run)
    layers = run.files.read_arrays(RunFile.CONSISTENCY_MAP)
    m = run.load_map()
    path = run.load_trajectory("slam")
    overlay_img, note = None, ""
    if layers is not None and m is not None:
        overlay_img = fig_to_data_uri(overlay_figure(m, layers, spans, path))
        note = (f"Up to {cons.get('scans_scored', '?')} scans replayed at the estimated path against the final map. Red: a beam passed"
                " through a wall the map holds before its own end (more than 0.3 m short of it); blue: a beam ended where the map"
                " is confidently free; pale, any scan's; strong, a scan of a stretch likely broken. People walking, clutter and"
                " glass leave pale scattered dots on any map (a 0.25 m cell shows one beam of 1,000 scans); a loop closed wrongly"
                " leaves strong lines along the walls that two passes drew apart. Shading: each 5 m region's share of"
                " contradicting beams.")
    series = run.files.read_columns(RunFile.CONSISTENCY)
    curve_img = None
    if series is not None and len(series) > 1 and "contradiction" in series:
        curve_img = fig_to_data_uri(curve_figure(series, float(cons.get("broken_threshold", 0.4)), spans))
    rows = [{"n": str(i), "where": f"({float(s['x_m']):.1f}, {float(s['y_m']):.1f}) m, within {float(s['radius_m']):.1f} m",
             "when": f"{float(s['t1_s']):.0f}–{float(s['t2_s']):.0f} s", "share": f"{float(s['peak_share']):.0%}", "closures": ""}
            for i, s in enumerate(spans, start=1)]
    loops = run.load_loops()  # a graph run's loop candidates: what its loop search did at each stretch
    if loops is not None and rows:
        t0 = float(path.t[0]) if path is not None and len(path.t) else 0.0
        for row, s in zip(rows, spans):
            row["closures"] = closures_at(loops, s, t0, None if path is None else (path.t, path.xy))
    shares = ""
    if "contradiction_share" in cons:
        shares = (f"Over the whole run {_pct(cons.get('contradiction_share'))} of the classified beams contradict the map"
                  f" ({_pct(cons.get('see_through_share'))} saw through a wall, {_pct(cons.get('in_free_share'))} ended in"
                  f" free space); the worst stretch of {cons.get('window_scans', 25)} replayed scans {_pct(cons.get('contradiction_worst_window'))}.")
    return ConsistencySection(text, ok, overlay_img, note, curve_img, rows, shares, closures_note())


def _pct(v: Any) -> str:
    try:
        f = float(v)
    except (TypeError, ValueError):
        return "–"
    return "–" if math.isnan(f) else f"{f:.0%}"
