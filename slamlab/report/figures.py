"""Matplotlib figures for the reports, returned as `data:` URIs so pages are self-contained.

Why PNG and not SVG: step curves have thousands of points and maps are rasters, so PNG at a
low DPI is both smaller and faster than SVG. Maps are cropped to the explored area and
block-reduced before plotting: a 12-run sweep report must build in well under 30 s on two
cores, and a 4000x4000 grid drawn per run would not.
"""

from __future__ import annotations

import base64
import io
import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from slamlab.heap import release_freed_memory
from slamlab.io.png import grey_rgba
from slamlab.io.table import Table
from slamlab.report.byte_image import imshow_bytes
from slamlab.report.mpl import Figure, Text, colormaps  # headless, without docstring tables (mpl.py)
from slamlab.report.rundir import LogOddsMap, Trajectory
from slamlab.numeric import block_max

DPI = 90
# Fixed colours per trajectory kind, so every figure reads the same way.
KIND_STYLE = {
    "groundtruth": dict(color="#2ca02c", lw=1.6, label="ground truth"),
    "odometry": dict(color="#d62728", lw=1.0, ls="--", label="odometry"),
    "slam": dict(color="#1f77b4", lw=1.4, label="SLAM"),
}


@dataclass(frozen=True, slots=True)
class MapView:
    """A map prepared for display: `image` (h, w) grey levels in [0, 1] (1 = free/white,
    0 = occupied/black, 0.5 = unknown), and the metric extent it covers."""

    image: np.ndarray
    extent: tuple[float, float, float, float]


def subplots(nrows: int = 1, ncols: int = 1, figsize: tuple[float, float] | None = None, **kw: Any) -> tuple[Figure, Any]:
    """`pyplot.subplots` without pyplot: a Figure no global figure manager holds, as
    matplotlib advises for figures made off screen (nothing to close, no state shared between
    figures), and a report process that never imports pyplot (about 0.1 s of CPU)."""
    fig = Figure(figsize=figsize)
    return fig, fig.subplots(nrows, ncols, **kw)


def fig_to_data_uri(fig: Figure, dpi: int = DPI, fmt: str = "png") -> str:
    """Render a figure; return a base64 data URI for an <img src>. PNG for plots;
    `fmt="jpeg"` for figures made of photos (camera frames), where PNG would be 5x larger."""
    buf = io.BytesIO()
    fig.savefig(buf, format=fmt, dpi=dpi, bbox_inches="tight", **({"pil_kwargs": {"quality": 85}} if fmt == "jpeg" else {}))
    # The renderer savefig drew with (the whole figure's RGBA: 4-6 MB) stays referenced by the
    # figure's Text artists, which cache it for their layout, and those live in reference cycles
    # until the garbage collector's next full pass (~80 ms here, too dear per figure): a report
    # held every figure's renderer at once. Let go here, it goes with savefig's canvas
    for text in fig.findobj(Text):
        text._renderer = None
    # rendering makes arrays of the output's size (a map: 10-15 MB each) that glibc keeps
    # resident once freed; given back here, the next figure does not add to them (slamlab.heap)
    release_freed_memory()
    return f"data:image/{fmt};base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def content_box(path: Path) -> tuple[int, int, int, int] | None:
    """(x0, y0, x1, y1) pixels of a PNG's content: where it differs from the colour of its
    top-left pixel (transparent or unknown-grey) by more than a little; None if nowhere."""
    from PIL import Image, ImageChops  # pillow ships with matplotlib

    with Image.open(path) as src:
        im = src.convert("RGBA")
    bg = Image.new("RGBA", im.size, im.getpixel((0, 0)))
    # Tolerance: anti-aliased edges and near-grey pixels must not defeat the crop.
    return ImageChops.difference(im, bg).convert("L").point(lambda v: 255 if v > 12 else 0).getbbox()


def common_content_box(paths: Sequence[Path]) -> tuple[int, int, int, int] | None:
    """The union of the content boxes of images of one size (the texture rasters of one map
    grid): cutting each to it keeps them the same size, cell under cell. None when the sizes
    differ or nothing has content (each is then cut to its own)."""
    from PIL import Image

    sizes = set()
    for p in paths:
        with Image.open(p) as im:
            sizes.add(im.size)
    boxes = [b for p in paths if (b := content_box(p)) is not None]
    if len(sizes) != 1 or not boxes:
        return None
    return (min(b[0] for b in boxes), min(b[1] for b in boxes), max(b[2] for b in boxes), max(b[3] for b in boxes))


def png_file_to_data_uri(path: Path, max_px: int = 900, min_px: int = 420, crop: bool = True,
                         margin_px: int = 12, box: tuple[int, int, int, int] | None = None) -> str:
    """Embed an existing PNG (e.g. texture.png): cropped to its content (texture rasters span
    the whole map grid and are mostly empty background), or to `box` when given (images to be
    compared side by side: `common_content_box`), plus a margin, and shrunk so the longest side
    is <= max_px. Background = the colour of the top-left pixel (transparent or unknown-grey)."""
    from PIL import Image

    with Image.open(path) as src:
        im = src.convert("RGBA")
    if crop:
        bbox = box if box is not None else content_box(path)
        if bbox is not None:
            x0, y0, x1, y1 = bbox
            im = im.crop((max(0, x0 - margin_px), max(0, y0 - margin_px),
                          min(im.width, x1 + margin_px), min(im.height, y1 + margin_px)))
    if max(im.size) > max_px:
        im.thumbnail((max_px, max_px))
    elif max(im.size) < min_px:
        # A small textured patch would show as a thumbnail: enlarge by an integer factor
        # with nearest-neighbour so cells stay crisp and nothing is invented.
        k = max(1, min_px // max(im.size))
        im = im.resize((im.width * k, im.height * k), Image.NEAREST)
    buf = io.BytesIO()
    im.save(buf, format="PNG")
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def png_size(uri: str) -> tuple[int, int]:
    """(width, height) of a PNG data URI, from its IHDR chunk (no decoding)."""
    head = base64.b64decode(uri.split(",", 1)[1][:44])
    return int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")


def prepare_map(m: LogOddsMap, max_px: int, trajectories: Sequence[Trajectory] = (), margin_m: float = 1.0) -> MapView:
    """Crop a log-odds grid to its observed cells (plus the trajectories and a margin) and
    reduce it by blocks so the longest side is <= max_px. Reduction keeps the most
    occupied cell of each block so thin walls survive downsampling. The grid is read a band
    of rows at a time (`LogOddsMap.bands`): a run's map is not held whole."""
    h, w = m.shape
    res = m.resolution_m
    ox, oy = m.origin_xy
    if "rows_cols" not in m.known:  # one pass over the grid, for every view of it
        m.known["rows_cols"] = _known_rows_cols(m)
    rows, cols = m.known["rows_cols"]
    if rows.size and cols.size:
        r0, r1, c0, c1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    else:
        r0, r1, c0, c1 = 0, h, 0, w
    for tr in trajectories:
        if tr is None or len(tr) == 0:
            continue
        cx = np.floor((tr.xy[:, 0] - ox) / res)
        cy = np.floor((tr.xy[:, 1] - oy) / res)
        c0, c1 = min(c0, int(cx.min())), max(c1, int(cx.max()) + 1)
        r0, r1 = min(r0, int(cy.min())), max(r1, int(cy.max()) + 1)
    pad = int(math.ceil(margin_m / res))
    r0, c0 = max(0, r0 - pad), max(0, c0 - pad)
    r1, c1 = min(h, r1 + pad), min(w, c1 + pad)
    k = max(1, int(math.ceil(max(r1 - r0, c1 - c0) / max_px)))
    # A block that saw only free cells has max < 0; unknown-only blocks stay 0. Bands of whole
    # blocks: reduced one by one and stacked, they are the whole crop reduced
    step = max(k, KNOWN_BAND_ROWS // k * k)
    parts = [block_max(band[:, c0:c1], k) for band in m.bands(r0, r1, step)]
    image = np.empty((sum(len(p) for p in parts), parts[0].shape[1] if parts else -(-max(c1 - c0, 0) // k)))
    r = 0
    for part in parts:
        # 1 - P(occupied) = 1 - 1 / (1 + exp(-clip(l))), in place a band at a time: the same operations
        # on the whole crop made four float64 temporaries of its size (Intel's report: ~30 MB at its peak)
        out = image[r : r + len(part)]
        out[...] = part
        np.clip(out, -30, 30, out=out)
        np.negative(out, out=out)
        np.exp(out, out=out)
        np.add(1.0, out, out=out)
        np.divide(1.0, out, out=out)
        np.subtract(1.0, out, out=out)
        r += len(part)
    extent = (ox + c0 * res, ox + (c0 + image.shape[1] * k) * res, oy + r0 * res, oy + (r0 + image.shape[0] * k) * res)
    return MapView(image=image, extent=extent)


KNOWN_BAND_ROWS = 256  # map rows checked at a time (a whole building's map is 160 MB of float32)


def _known_rows_cols(m: LogOddsMap) -> tuple[np.ndarray, np.ndarray]:
    """The rows and the columns of a log-odds grid holding an observed cell (|log-odds| >
    1e-6), checked band by band (the whole grid's |.| and mask would be 200 MB on a building)."""
    h, w = m.shape
    rows = np.zeros(h, dtype=bool)
    cols = np.zeros(w, dtype=bool)
    for j, band in enumerate(m.bands(0, h, KNOWN_BAND_ROWS)):  # to its end: the file is closed
        r = j * KNOWN_BAND_ROWS
        known = np.abs(band) > 1e-6
        rows[r:r + KNOWN_BAND_ROWS] = known.any(axis=1)
        cols |= known.any(axis=0)
    return np.flatnonzero(rows), np.flatnonzero(cols)


def rgba_bytes(rgba: np.ndarray) -> np.ndarray:
    """Float RGBA in [0, 1] as the uint8 RGBA matplotlib makes of it when it draws it
    ((x * 255) truncated). Handed to `imshow` as bytes, it is resampled as bytes, where float
    RGBA is resampled in float64 copies at the output's size (a 500 px overlay in a 13 in
    figure: 90 -> 55 MB while the figure is saved). The same pixels with nearest sampling."""
    return (np.asarray(rgba, dtype=np.float64) * 255).astype(np.uint8)


def draw_map(ax, view: MapView | None) -> None:
    if view is not None:
        # Grey levels as uint8 RGBA (the "gray" colormap, slamlab.io.png), sampled as bytes at the
        # output's size (`byte_image`): matplotlib's imshow takes float copies of the image at that
        # size while the figure is saved (a whole-Intel report peaked 40 MB higher with a float
        # image, still ~20 MB with bytes)
        imshow_bytes(ax, grey_rgba(view.image), view.extent)
    ax.set_aspect("equal")


def map_with_trajectories(
    m: LogOddsMap | None,
    trajectories: dict[str, Trajectory | None],
    max_px: int = 1200,
    width_in: float = 15.0,
    title: str | None = None,
) -> tuple[str, bool]:
    """The map with the SLAM, odometry and ground-truth paths (keys of KIND_STYLE; None
    entries skipped), drawn thin and translucent so walls stay visible. The window is the
    mapped area plus the SLAM and true paths; odometry is clipped to it (on real logs it
    drifts far outside). Returns (data URI, whether the odometry was clipped)."""
    trs = {k: v for k, v in trajectories.items() if v is not None and len(v)}
    framing = [tr for k, tr in trs.items() if k != "odometry" or m is None]
    view = prepare_map(m, max_px, framing) if m is not None else None
    if view is not None:
        x0, x1, y0, y1 = view.extent
    else:
        xy = np.concatenate([tr.xy for tr in framing]) if framing else np.zeros((1, 2))
        x0, y0 = xy.min(axis=0) - 1.0
        x1, y1 = xy.max(axis=0) + 1.0
    aspect = (y1 - y0) / max(x1 - x0, 1e-9)
    fig, ax = subplots(figsize=(width_in, float(np.clip(width_in * 0.82 * aspect, 4.0, 14.0))))
    draw_map(ax, view)
    clipped = False
    for kind in ("groundtruth", "odometry", "slam"):
        tr = trs.get(kind)
        if tr is None:
            continue
        style = {**KIND_STYLE[kind], "lw": 0.9, "alpha": 0.75}
        ax.plot(tr.xy[:, 0], tr.xy[:, 1], **style)
        ax.plot(tr.xy[-1, 0], tr.xy[-1, 1], "s", color=style["color"], ms=5)
        if kind == "odometry":
            clipped = bool((tr.xy[:, 0] < x0).any() or (tr.xy[:, 0] > x1).any() or (tr.xy[:, 1] < y0).any() or (tr.xy[:, 1] > y1).any())
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    if trs:
        first = next(iter(trs.values()))
        ax.plot(first.xy[0, 0], first.xy[0, 1], "o", color="black", mfc="none", ms=8, label="start")
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=9)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    if title:
        ax.set_title(title)
    return fig_to_data_uri(fig), clipped


def rolling_median(y: np.ndarray, window: int) -> np.ndarray:
    """Median of each centred window of `window` values (fewer at the ends; NaNs skipped):
    pandas' `Series.rolling(window, center=True, min_periods=1).median()` without pandas
    (the run report then loads none: 0.2 s of CPU and ~25 MB)."""
    y = np.asarray(y, dtype=np.float64)
    if window <= 1 or y.size == 0:
        return y.copy()
    after = (window - 1) // 2  # as pandas centres a window: an even one has its larger half before
    padded = np.concatenate([np.full(window - 1 - after, np.nan), y, np.full(after, np.nan)])
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a window of NaNs alone gives NaN
        return np.nanmedian(np.lib.stride_tricks.sliding_window_view(padded, window), axis=1)


def step_times(steps: Table) -> np.ndarray:
    """Step times (s) relative to the first step: log times are often Unix epochs (1.4e9 s),
    which make an unreadable axis. Falls back to the step number when there is no `t`."""
    if "t" not in steps:
        return np.arange(len(steps), dtype=float)
    t = np.asarray(steps["t"], dtype=float)
    return t - t[0] if t.size else t


def neff_plot(steps: Table, particles: int | None, threshold: float | None) -> str:
    return fig_to_data_uri(neff_figure(steps, particles, threshold))


def neff_figure(steps: Table, particles: int | None, threshold: float | None) -> Figure:
    """N_eff per step over time, the resampling threshold, and the resampling events as a
    thin strip of ticks below (readable whether the filter resampled 3 or 3000 times). When
    most steps resample, the strip marks the steps that did not (a tick at 95 % of the steps
    would be a solid bar)."""
    fig, (ax, strip) = subplots(2, 1, figsize=(13.0, 3.6), sharex=True, gridspec_kw={"height_ratios": [1, 0.14], "hspace": 0.08})
    t = step_times(steps)
    ax.plot(t, np.asarray(steps["neff"], dtype=float), lw=0.8, color="#1f77b4", label="N_eff")
    if threshold is not None:
        ax.axhline(threshold, color="#d62728", ls="--", lw=1.0, label=f"threshold {threshold:g}")
    if particles:
        ax.axhline(particles, color="grey", ls=":", lw=0.8, label=f"N = {particles}")
        ax.set_ylim(0, particles * 1.05)
    ax.set_ylabel("N_eff")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", bbox_to_anchor=(1.005, 1.0), fontsize=8)
    mask = np.asarray(steps["resampled"], dtype=bool) if "resampled" in steps else np.zeros(len(t), bool)
    share = 100.0 * mask.mean() if len(t) else 0.0
    mostly = share > 50.0
    marked = ~mask if mostly else mask
    if marked.any():
        strip.eventplot(t[marked], colors="#7f7f7f" if mostly else "#ff7f0e", linelengths=0.8, linewidths=0.6)
    strip.set_yticks([])
    strip.set_ylabel("not resampled" if mostly else "resampled", rotation=0, ha="right", va="center", fontsize=8)
    strip.text(1.005, 0.5, f"resampled at {int(mask.sum())} of {len(t)} steps ({share:.0f} %)"
               + ("; ticks: the steps that did not" if mostly else ""),
               transform=strip.transAxes, fontsize=8, va="center")
    strip.set_xlabel("time since first step (s)")
    return fig


# A first step this many times the others' median is the one-off start (numba compiling or
# loading the kernels): left out of the step-time axis and said in a note.
WARMUP_RATIO = 10.0


def weight_and_time_plot(steps: Table, with_weight: bool = True) -> str:
    return fig_to_data_uri(weight_and_time_figure(steps, with_weight))


def weight_and_time_figure(steps: Table, with_weight: bool = True) -> Figure:
    """Best particle weight and filter step time over time, stacked with a shared time axis
    (the step time alone without `with_weight`: a filter of one trajectory has no weights).
    Step times on a log axis: the typical few-ms step would otherwise be a line at zero. The
    first step pays for compiling or loading the kernels (seconds): when it is WARMUP_RATIO
    times the others' median it is left out of the axis, the median and the percentile, and a
    note gives its time."""
    if with_weight:
        fig, (a1, a2) = subplots(2, 1, figsize=(13.0, 4.6), sharex=True)
    else:
        fig, a2 = subplots(1, 1, figsize=(13.0, 2.6))
    t = step_times(steps)
    if with_weight:
        if "best_weight" in steps:
            a1.plot(t, np.asarray(steps["best_weight"], dtype=float), lw=0.8, color="#9467bd")
        a1.set_ylabel("best weight")
        a1.grid(alpha=0.3)
    if "step_time_s" in steps:
        st = np.asarray(steps["step_time_s"], dtype=float) * 1000.0
        warmup = st.size > 2 and st[0] > WARMUP_RATIO * float(np.median(st[1:]))
        tt, shown = (t[1:], st[1:]) if warmup else (t, st)
        st_pos = np.maximum(shown, 1e-3)  # a log axis cannot show 0 ms
        a2.plot(tt, st_pos, lw=0.5, color="#8c564b", alpha=0.8)
        if shown.size:
            med, p99 = float(np.median(shown)), float(np.percentile(shown, 99))
            a2.axhline(med, color="black", ls=":", lw=0.9, label=f"median {med:.1f} ms")
            a2.axhline(p99, color="#d62728", ls="--", lw=0.8, label=f"99th percentile {p99:.1f} ms")
            worst = int(np.argmax(shown))
            a2.plot(tt[worst], st_pos[worst], "o", mfc="none", color="#d62728", ms=7, label=f"slowest {shown[worst]:.0f} ms")
            a2.legend(loc="upper left", bbox_to_anchor=(1.005, 1.0), fontsize=8)
        if warmup:
            a2.text(1.005, 0.0, f"first step {st[0]:.0f} ms\n(compiling or loading\nthe kernels): left out",
                    transform=a2.transAxes, fontsize=8, va="bottom")
        a2.set_yscale("log")
    a2.set_ylabel("step time (ms, log)")
    a2.set_xlabel("time since first step (s)")
    a2.grid(alpha=0.3, which="both")
    fig.tight_layout()
    return fig


def trajectories_overlay(
    background: LogOddsMap | None,
    background_label: str,
    runs: Sequence[tuple[str, Trajectory]],
    groundtruth: Trajectory | None,
    odometry: Trajectory | None,
    max_px: int = 700,
) -> str:
    """Every run's SLAM path on one map (the background map is named in the title)."""
    fig, ax = subplots(figsize=(9.0, 7.5))
    all_tr = [tr for _, tr in runs] + [t for t in (groundtruth, odometry) if t is not None]
    draw_map(ax, prepare_map(background, max_px, all_tr) if background is not None else None)
    if groundtruth is not None:
        ax.plot(groundtruth.xy[:, 0], groundtruth.xy[:, 1], color="black", lw=2.2, alpha=0.6, label="ground truth")
    if odometry is not None:
        ax.plot(odometry.xy[:, 0], odometry.xy[:, 1], color="#d62728", lw=1.0, ls="--", label="odometry")
    colours = colormaps["tab10" if len(runs) <= 10 else "tab20"]
    for i, (label, tr) in enumerate(runs):
        ax.plot(tr.xy[:, 0], tr.xy[:, 1], lw=1.0, color=colours(i % colours.N), label=label)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"background: map of {background_label}" if background is not None else "no map", fontsize=9)
    ax.legend(loc="center left", bbox_to_anchor=(1.01, 0.5), fontsize=8, framealpha=0.85)
    return fig_to_data_uri(fig)


def neff_overlay(curves: Sequence[tuple[str, np.ndarray, np.ndarray]], ylabel: str,
                 xlabel: str = "time since first step (s)") -> str:
    return fig_to_data_uri(neff_overlay_figure(curves, ylabel, xlabel))


def neff_overlay_figure(curves: Sequence[tuple[str, np.ndarray, np.ndarray]], ylabel: str,
                        xlabel: str = "time since first step (s)") -> Figure:
    """N_eff (or N_eff / N) curves of several runs on one axis."""
    fig, ax = subplots(figsize=(10.0, 3.8))
    colours = colormaps["tab10" if len(curves) <= 10 else "tab20"]
    for i, (label, t, y) in enumerate(curves):
        ax.plot(t, y, lw=0.8, color=colours(i % colours.N), label=label)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3)
    ax.legend(loc="center left", bbox_to_anchor=(1.01, 0.5), fontsize=8)
    return fig


@dataclass(frozen=True, slots=True)
class Series:
    """One line of a metric-versus-parameter plot: x values, per-x mean, spread (std across
    seeds, 0 for a single seed) and the individual points (x, y) behind them."""

    label: str
    x: np.ndarray
    mean: np.ndarray
    std: np.ndarray
    points_x: np.ndarray
    points_y: np.ndarray


def metric_vs_param(param: str, panels: Sequence[tuple[str, Sequence[Series]]], categorical: list[str] | None = None) -> str:
    """One row of panels (one per metric) of metric versus a swept parameter. When x is
    categorical (e.g. resampler names) `categorical` gives the tick labels for x = 0..k-1."""
    n = len(panels)
    fig, axes = subplots(1, n, figsize=(4.6 * n, 3.4), squeeze=False)
    colours = colormaps["tab10"]
    for ax, (metric_label, series) in zip(axes.flat, panels):
        for i, s in enumerate(series):
            c = colours(i % 10)
            ax.scatter(s.points_x, s.points_y, s=12, color=c, alpha=0.45, lw=0)
            ax.errorbar(s.x, s.mean, yerr=s.std, color=c, marker="o", ms=4, lw=1.2, capsize=3, label=s.label)
        ax.set_xlabel(param)
        ax.set_ylabel(metric_label)
        ax.grid(alpha=0.3)
        if categorical is not None:
            ax.set_xticks(range(len(categorical)), categorical, rotation=20, fontsize=8)
        if len(series) > 1 or (series and series[0].label):
            ax.legend(fontsize=7)
    fig.tight_layout()
    return fig_to_data_uri(fig)
