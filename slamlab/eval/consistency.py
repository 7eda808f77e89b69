"""Map consistency without ground truth: do the scans agree with the map they built, and
if not, where and when did the map break?

Most logs users bring have no ground truth and no relations, so every run is also scored
against itself. Up to `MAX_SCANS` scans, spread evenly over the run, are replayed at the
estimated trajectory against the final map. It uses nothing but the final map, the
trajectory and the scans, so it judges a map made by any filter (course, rbpf, a pose
graph) the same way. Each beam of a replayed scan is one of:

- **support**: its endpoint lands on a wall of the map (an occupied cell or one of its 8
  neighbours: one cell of slack for the grid's rounding);
- **see-through**: before its endpoint (more than `SEE_THROUGH_MARGIN_M` short of it) the
  beam crosses an occupied cell: the scan saw through a wall the map holds. A beam grazing
  the wall it ends on walks through that wall's own cells just before its end, which the
  margin leaves out;
- **lands in free space**: its endpoint and the 8 cells around it are confidently free
  (log-odds below `FREE_LOG_ODDS`): the scan saw a wall where the map says there is none;
- neither (the endpoint lies in unknown or uncertain cells): no evidence either way.

A scan's **contradiction share** is (see-through + in free space) / (support + see-through +
in free space). Where tracking holds, nearly every beam supports the map: moving people,
clutter and glass cost a few per cent (a person walking ahead of the robot for a few
seconds, a group standing around it at the start: up to 0.33 over a window on the
benchmark logs). Where the map broke (a loop closed wrongly, a match slipped) one pass drew
the walls where another pass sees free space or sees through them, and the share jumps for
every scan of that stretch: 0.43-0.99 on the maps broken on purpose
(`benchmarks/bench_consistency.py`; README "Is the map consistent?").

The **verdict**: the rolling median of the share over `WINDOW` consecutive replayed scans;
a stretch whose median reaches `BROKEN_SHARE` is likely broken, named by the time span of
that stretch and the place where its contradicting beams gather (the densest
`REGION_M`-wide square of them). The per-region scores (contradicting beams over all
classified beams in each `REGION_M` square) and the contradicting beams themselves are kept
for the report's overlay (consistency_map.npz).

The **hit fraction** (a scan's endpoints on a wall, over all its endpoints) is kept as it
was. The conflict fraction of runs before 2026-11-29 (replayed wall cells crossed as free at
least twice as often as hit) is gone: it did not tell broken maps from good ones (issue 45:
good 0.13-0.17, broken 0.17-0.21 on the same world) and took a map-sized array of counts
(164 MB on the hospital log's map).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numba
import numpy as np

from slamlab.frames import GridImage, Sequence
from slamlab.geometry import FloatArray
from slamlab.slam.grid import MapSettings
from slamlab.slam.raycast import line_start, line_step
from slamlab.slam.scan import place, range_limits, scans_to_points

MAX_SCANS = 1000  # replayed scans, spread evenly over the run
WINDOW = 25  # replayed scans per rolling median: the worst stretch of the run
CHUNK = 100  # scans placed at once (~18,000 points on Intel: a few MB of temporaries)

SEE_THROUGH_MARGIN_M = 0.3  # a wall crossed closer than this to the beam's end is the wall it grazes
FREE_LOG_ODDS = -1.0  # confidently free: below this log-odds (P(occupied) < 0.27; 2.5 net free passes)
BROKEN_SHARE = 0.4  # a stretch whose rolling median contradiction share reaches this is likely broken
MIN_BEAMS = 10  # a scan with fewer classified beams is not scored
REGION_M = 5.0  # side (m) of the square regions that are scored and named
EVENT_BIN_M = 0.25  # the overlay's cells (m): contradicting beams counted per cell
MAX_SPANS = 5  # broken stretches kept in metrics.json, worst first

REGISTER_XY_M = 0.15  # a replayed scan may be nudged this far (m) each way onto the map ...
REGISTER_DEG = 1.0  # ... and turned this much (degrees), before it is judged
REGISTER_POINTS = 45  # endpoints per scan that the nudge is chosen on (evenly spread)

SUPPORT, SEE_THROUGH, IN_FREE = 1, 2, 3  # beam classes (0: no evidence)


@numba.njit(cache=True)
def classify_beams(log_odds, occupied, free, s_row, s_col, e_row, e_col, ends, margin_cells):
    """Each beam against the map. Scan j's beams run from cell (s_row[j], s_col[j]) to
    (e_row[k], e_col[k]) for k in ends[j]:ends[j + 1], walked as the map's own ray cast walks
    them (`raycast.line_step`). Returns (class (M,) int8: 0 none, SUPPORT, SEE_THROUGH,
    IN_FREE; the row and column of the evidence: the wall cell crossed for SEE_THROUGH, the
    endpoint otherwise; near (M,) bool: the endpoint lies on the map within one cell of an
    occupied cell). A wall cell counts as crossed when more than `margin_cells` steps of the
    walk remain after it. Cells off the map are unknown."""
    H, W = log_odds.shape
    n = e_row.shape[0]
    cls = np.zeros(n, np.int8)
    ev_r = e_row.copy()
    ev_c = e_col.copy()
    near = np.zeros(n, np.bool_)
    for j in range(s_row.shape[0]):
        r0 = s_row[j]
        c0 = s_col[j]
        for k in range(ends[j], ends[j + 1]):
            r1 = e_row[k]
            c1 = e_col[k]
            # the endpoint's 3 x 3 block: a wall near it, or all of it confidently free
            all_free = True
            for r in range(r1 - 1, r1 + 2):
                for c in range(c1 - 1, c1 + 2):
                    if r < 0 or r >= H or c < 0 or c >= W:
                        all_free = False
                        continue
                    v = log_odds[r, c]
                    if v > occupied:
                        near[k] = True
                    if v >= free:
                        all_free = False
            if r1 < 0 or r1 >= H or c1 < 0 or c1 >= W:
                near[k] = False  # an endpoint off the map is on no wall (its block may reach in)
            dr, dc, sr, sc, err, major_c, steps = line_start(r0, c0, r1, c1)
            r = r0
            c = c0
            seen_through = False
            for i in range(steps - margin_cells):
                if 0 <= r < H and 0 <= c < W and log_odds[r, c] > occupied:
                    seen_through = True
                    ev_r[k] = r
                    ev_c[k] = c
                    break
                r, c, err = line_step(r, c, err, dr, dc, sr, sc, major_c)
            if seen_through:
                cls[k] = SEE_THROUGH
            elif near[k]:
                cls[k] = SUPPORT
            elif all_free:
                cls[k] = IN_FREE
    return cls, ev_r, ev_c, near


@numba.njit(cache=True)
def _scan_nudge_hits(log_odds, occupied, xy, a, b, step, px, py, angles, n):
    """hits[k, dy + n, dx + n]: of scan points xy[a:b:step] (in cells), turned by angles[k]
    about (px, py) and moved by (dx, dy) whole cells, how many land within one cell of an
    occupied cell. Per point and angle the (2n + 3)^2 cells around it are read once, as row
    bit masks, and every shift's 3 x 3 test is a few bit operations on them."""
    H, W = log_odds.shape
    span = 2 * n + 3  # the cells any shift's 3 x 3 block can reach
    hits = np.zeros((angles.shape[0], 2 * n + 1, 2 * n + 1), np.int64)
    rows = np.zeros(span, np.int64)
    for k in range(angles.shape[0]):
        co = np.cos(angles[k])
        si = np.sin(angles[k])
        for i in range(a, b, step):
            x = xy[i, 0] - px
            y = xy[i, 1] - py
            col = int(np.floor(px + co * x - si * y))
            row = int(np.floor(py + si * x + co * y))
            for j in range(span):  # row j holds cells col - n - 1 .. col + n + 1 as bits 0 .. span - 1
                r = row - n - 1 + j
                m = 0
                if 0 <= r < H:
                    for t in range(span):
                        c = col - n - 1 + t
                        if 0 <= c < W and log_odds[r, c] > occupied:
                            m |= 1 << t
                rows[j] = m | (m << 1) | (m >> 1)  # a bit set where the cell or a neighbour in the row is occupied
            for dy in range(2 * n + 1):
                v = rows[dy] | rows[dy + 1] | rows[dy + 2]  # rows around row + dy - n
                for dx in range(2 * n + 1):
                    if (v >> (dx + 1)) & 1:
                        hits[k, dy, dx] += 1
    return hits


@numba.njit(cache=True)
def register_scans(log_odds, occupied, xy, ends, pivots, angles, n, order, max_points):
    """Each scan's best small rigid correction against the map: scan j's world endpoints
    xy[ends[j]:ends[j + 1]] (in cells: cell = floor(xy)), turned by angles[k] about pivots[j]
    (its robot's position, cells) and moved by whole cells dx, dy in -n..n. The correction
    that puts the most endpoints (at most `max_points`, evenly spread) within one cell of an
    occupied cell wins; candidates are tried in `order` (rows k, dy + n, dx + n: the smallest
    first), so the earliest wins a tie. Returns each scan's winning row of `order`."""
    nscan = pivots.shape[0]
    best = np.zeros(nscan, np.int64)
    for j in range(nscan):
        m = ends[j + 1] - ends[j]
        if m == 0:
            continue
        step = max(1, m // max_points)
        hits = _scan_nudge_hits(log_odds, occupied, xy, ends[j], ends[j + 1], step, pivots[j, 0], pivots[j, 1], angles, n)
        top = -1
        for c in range(order.shape[0]):
            h = hits[order[c, 0], order[c, 1], order[c, 2]]
            if h > top:
                top = h
                best[j] = c
    return best


@dataclass(frozen=True, slots=True)
class BrokenSpan:
    """A stretch of the run whose scans contradict the map: replayed scans `first`..`last`
    (indices into the series), their times `t1_s`..`t2_s` (s since the run's first scan),
    the worst rolling median `peak` and the place where its contradicting beams gather:
    centre (`x_m`, `y_m`) and the radius `radius_m` holding half of them."""

    first: int
    last: int
    t1_s: float
    t2_s: float
    peak: float
    x_m: float
    y_m: float
    radius_m: float

    def to_dict(self) -> dict:
        return {"x_m": self.x_m, "y_m": self.y_m, "radius_m": self.radius_m, "t1_s": self.t1_s, "t2_s": self.t2_s,
                "peak_share": self.peak}


@dataclass(slots=True)
class Consistency:
    """What the replay found. `summary` is metrics.json's "consistency"; `series` the
    replayed scans (consistency.csv: "t" s, "scan_index", "hit_fraction", "contradiction",
    "contradiction_window"); `overlay` the report's map layers (consistency_map.npz:
    per-cell counts of contradicting beams and per-region scores, see `overlay_arrays`)."""

    summary: dict
    series: dict[str, np.ndarray]
    overlay: dict[str, np.ndarray] = field(default_factory=dict)
    spans: list[BrokenSpan] = field(default_factory=list)


def consistency_metrics(
    sequence: Sequence,
    poses: FloatArray,
    log_odds: GridImage,
    settings: MapSettings,
    max_scans: int = MAX_SCANS,
) -> Consistency:
    """Score the run's scans against its final map (see module doc).

    `poses` (N, 3): the estimated pose (x m, y m, theta rad) of the first N scans of
    `sequence`; `log_odds` the final map; `settings` the run's map settings (ranges, ground
    threshold, occupied threshold)."""
    n = len(poses)
    pick = np.unique(np.linspace(0, n - 1, min(n, max_scans)).round().astype(np.int64)) if n else np.zeros(0, np.int64)
    H, W = log_odds.data.shape
    inv = 1.0 / log_odds.resolution_m
    ox, oy = log_odds.origin_xy
    min_r, max_r = range_limits(settings, sequence)
    # thresholds in the map's own type: NumPy compares a float32 map with a Python float in
    # float32, and so does the kernel then (in float64 a map value equal to float32(0.1) would pass 0.1)
    occupied = log_odds.data.dtype.type(settings.occupied_threshold)
    free = log_odds.data.dtype.type(FREE_LOG_ODDS)
    margin = int(round(SEE_THROUGH_MARGIN_M * inv))
    angles, n_shift, order, offsets = correction_candidates(log_odds.resolution_m)
    corrections = np.zeros((len(pick), 3))  # each replayed scan's nudge (dx m, dy m, dtheta rad)

    def cells(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.floor((xy[:, 1] - oy) * inv).astype(np.int64), np.floor((xy[:, 0] - ox) * inv).astype(np.int64)

    # the scored scans' points are placed and looked up CHUNK scans at a time (per scan, NumPy's
    # call overhead was most of this function's 0.3 s on Intel; all 1,000 at once held 18 MB more)
    n_points = np.zeros(len(pick), dtype=np.int64)  # endpoints of each scored scan, on the map or not
    near_count = np.zeros(len(pick))
    counts = np.zeros((len(pick), 4))  # beams of each class per scan
    event_parts = []
    for lo in range(0, len(pick), CHUNK):
        chunk = pick[lo : lo + CHUNK]
        scans = scans_to_points([sequence.scans[i] for i in chunk], sequence.body_height_m, min_r, max_r, settings.ground_threshold_m)
        n_points[lo : lo + len(chunk)] = [len(p.xy) for p in scans]
        scan_of = np.repeat(np.arange(len(chunk)), n_points[lo : lo + len(chunk)])  # each point's scan in the chunk
        # each scan's rotation, one scalar np.cos / np.sin per scan as `points_to_world` takes it
        # (an array call may round another way in the last bit)
        cos = np.array([np.cos(poses[i, 2]) for i in chunk], dtype=np.float64)
        sin = np.array([np.sin(poses[i, 2]) for i in chunk], dtype=np.float64)
        pose = poses[chunk][scan_of]
        world = place(np.concatenate([p.xy for p in scans]).reshape(-1, 2), pose[:, 0], pose[:, 1], cos[scan_of], sin[scan_of])
        sensor = place(np.array([p.origin for p in scans]).reshape(-1, 2), poses[chunk, 0], poses[chunk, 1], cos, sin)
        ends = np.concatenate([[0], np.cumsum(n_points[lo : lo + len(chunk)])]).astype(np.int64)
        # each scan nudged onto the map (a few cells, a degree) before it is judged: the map may
        # have been drawn from other poses than the path replayed here (the course filter draws
        # at its online poses, the path is the smoothed one; scans between steps carry their
        # odometry), and a small offset is no contradiction; walls drawn twice further apart stay
        origin = np.array([ox, oy])
        pick_c = register_scans(log_odds.data, occupied, (world - origin) * inv, ends, (poses[chunk, :2] - origin) * inv,
                                angles, n_shift, order, REGISTER_POINTS)
        shift = offsets[pick_c]
        corrections[lo : lo + len(chunk)] = shift * [log_odds.resolution_m, log_odds.resolution_m, 1.0]
        world = _nudge(world, poses[chunk, :2][scan_of], shift[scan_of], log_odds.resolution_m)
        sensor = _nudge(sensor, poses[chunk, :2], shift, log_odds.resolution_m)
        rows, cols = cells(world)
        s_row, s_col = cells(sensor)
        cls, ev_r, ev_c, near = classify_beams(log_odds.data, occupied, free, s_row, s_col, rows, cols, ends, margin)
        near_count[lo : lo + len(chunk)] = np.bincount(scan_of, weights=near, minlength=len(chunk))
        counts[lo : lo + len(chunk)] = np.bincount(scan_of * 4 + cls, minlength=4 * len(chunk)).reshape(-1, 4)
        bad = cls >= SEE_THROUGH
        ok = cls == SUPPORT
        for keep in (bad, ok):  # int32: a THOR run keeps ~800,000 supporting beams
            event_parts.append(((lo + scan_of[keep]).astype(np.int32), cls[keep], ev_r[keep].astype(np.int32), ev_c[keep].astype(np.int32)))

    frac = np.full(len(pick), np.nan)
    has = n_points > 0
    frac[has] = near_count[has] / n_points[has]

    classified = counts[:, SUPPORT:].sum(axis=1)
    share = np.full(len(pick), np.nan)
    scored_share = classified >= MIN_BEAMS
    share[scored_share] = (counts[scored_share, SEE_THROUGH] + counts[scored_share, IN_FREE]) / classified[scored_share]
    window = rolling_median(share, WINDOW)
    t = np.array([sequence.scans[i].t for i in pick], dtype=np.float64)
    events = _concat_events(event_parts)
    spans = broken_spans(window, t - t[0] if len(t) else t, events, log_odds)

    summary: dict = {"scans_scored": int(np.isfinite(frac).sum())}
    scored = frac[np.isfinite(frac)]
    if len(scored):
        k = min(WINDOW, len(scored))
        rolling = np.median(np.lib.stride_tricks.sliding_window_view(scored, k), axis=1)
        summary.update(
            hit_fraction_mean=float(scored.mean()),
            hit_fraction_p10=float(np.percentile(scored, 10)),
            # the worst stretch: where the map broke, if anywhere
            hit_fraction_worst_window=float(rolling.min()),
        )
    summary.update(verdict_summary(share, window, spans, counts))
    series = {
        "t": t,
        "scan_index": np.array([sequence.scans[i].index for i in pick], dtype=np.int64),
        "hit_fraction": frac,
        "contradiction": share,
        "contradiction_window": window,
        "nudge_m": np.hypot(corrections[:, 0], corrections[:, 1]),
        "nudge_deg": np.degrees(corrections[:, 2]),
    }
    return Consistency(summary, series, overlay_arrays(events, log_odds, spans), spans)


def correction_candidates(resolution_m: float) -> tuple[np.ndarray, int, np.ndarray, np.ndarray]:
    """The nudges `register_scans` tries: (angles (rad), n, order, offsets). Whole cells up to
    REGISTER_XY_M each way (n of them, 1-6) and turns in half-degree steps up to REGISTER_DEG;
    `order` (C, 3) lists them as (angle index, dy + n, dx + n), the smallest first (no nudge
    leads, so it wins every tie), and `offsets` (C, 3) the same as (dx cells, dy cells, rad)."""
    n = min(6, max(1, int(round(REGISTER_XY_M / resolution_m))))  # 2n + 3 cells fit a mask of bits
    steps = int(round(REGISTER_DEG / 0.5))
    angles = np.radians(0.5 * np.arange(-steps, steps + 1))
    k, dy, dx = (g.ravel() for g in np.meshgrid(np.arange(len(angles)), np.arange(2 * n + 1), np.arange(2 * n + 1), indexing="ij"))
    offsets = np.column_stack([dx - n, dy - n, angles[k]]).astype(np.float64)
    size = np.hypot(offsets[:, 0], offsets[:, 1]) / n + np.abs(offsets[:, 2]) / max(np.radians(REGISTER_DEG), 1e-12)
    rank = np.argsort(size, kind="stable")
    return angles, n, np.ascontiguousarray(np.column_stack([k, dy, dx])[rank]), np.ascontiguousarray(offsets[rank])


def _nudge(xy: np.ndarray, pivot: np.ndarray, shift: np.ndarray, resolution_m: float) -> np.ndarray:
    """Points (m) turned by shift[:, 2] (rad) about their robot's position `pivot` and moved by
    shift[:, :2] cells, as `register_scans` tried them."""
    c, s = np.cos(shift[:, 2]), np.sin(shift[:, 2])
    rel = xy - pivot
    out = np.empty_like(xy)
    out[:, 0] = pivot[:, 0] + c * rel[:, 0] - s * rel[:, 1] + shift[:, 0] * resolution_m
    out[:, 1] = pivot[:, 1] + s * rel[:, 0] + c * rel[:, 1] + shift[:, 1] * resolution_m
    return out


def rolling_median(y: np.ndarray, window: int) -> np.ndarray:
    """Median of each centred window of `window` values of `y` (NaNs skipped; shorter at the
    ends, NaN where a window holds none), so each replayed scan has its stretch's value."""
    y = np.asarray(y, dtype=np.float64)
    out = np.full(len(y), np.nan)
    if not len(y):
        return out
    half = window // 2
    padded = np.concatenate([np.full(half, np.nan), y, np.full(window - 1 - half, np.nan)])
    views = np.lib.stride_tricks.sliding_window_view(padded, window)
    some = np.isfinite(views).any(axis=1)
    with np.errstate(all="ignore"):
        out[some] = np.nanmedian(views[some], axis=1)
    return out


@dataclass(frozen=True, slots=True)
class _Events:
    """Classified beams: `scan` (index into the replayed scans), `cls`, and the evidence cell."""

    scan: np.ndarray
    cls: np.ndarray
    row: np.ndarray
    col: np.ndarray


def _concat_events(parts: list[tuple[np.ndarray, ...]]) -> _Events:
    if not parts:
        z = np.zeros(0, np.int64)
        return _Events(z, z.astype(np.int8), z, z)
    return _Events(*(np.concatenate([p[i] for p in parts]) for i in range(4)))


def broken_spans(window: np.ndarray, t: np.ndarray, events: _Events, grid: GridImage) -> list[BrokenSpan]:
    """The stretches whose rolling median reaches BROKEN_SHARE, worst first (at most
    MAX_SPANS), each placed where its contradicting beams gather."""
    above = np.nan_to_num(window, nan=0.0) >= BROKEN_SHARE
    if not above.any():
        return []
    edges = np.flatnonzero(np.diff(np.concatenate([[0], above.astype(np.int8), [0]])))
    spans = []
    res = grid.resolution_m
    ox, oy = grid.origin_xy
    bad = events.cls >= SEE_THROUGH
    for first, stop in zip(edges[0::2], edges[1::2]):
        last = stop - 1
        mine = bad & (events.scan >= first) & (events.scan <= last)
        x = ox + (events.col[mine] + 0.5) * res
        y = oy + (events.row[mine] + 0.5) * res
        cx, cy, radius = _gathering(x, y)
        spans.append(BrokenSpan(int(first), int(last), float(t[first]), float(t[last]), float(np.nanmax(window[first : last + 1])),
                                cx, cy, radius))
    spans.sort(key=lambda s: -s.peak)
    return spans[:MAX_SPANS]


def _gathering(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """The centre of the densest REGION_M-wide square of points (x, y) (m; 1 m bins summed
    over the square), and the radius (m) around it that holds half of the points (at least
    REGION_M / 2)."""
    if not len(x):
        return float("nan"), float("nan"), float("nan")
    x0, y0 = np.floor(x.min()), np.floor(y.min())
    bx, by = (x - x0).astype(np.int64), (y - y0).astype(np.int64)
    hist = np.zeros((by.max() + 1, bx.max() + 1))
    np.add.at(hist, (by, bx), 1.0)
    k = int(REGION_M)
    box = _box_sum(hist, k)
    r, c = np.unravel_index(int(np.argmax(box)), box.shape)
    # the box sum at (r, c) covers bins r - k//2 .. r + (k-1)//2: its centre in metres
    cy, cx = y0 + r + 0.5 - (k % 2 == 0) * 0.5, x0 + c + 0.5 - (k % 2 == 0) * 0.5
    inside = np.abs(x - cx) <= k / 2
    inside &= np.abs(y - cy) <= k / 2
    if inside.any():  # the mean of the points in the square: finer than the 1 m bins
        cx, cy = float(x[inside].mean()), float(y[inside].mean())
    radius = float(np.median(np.hypot(x - cx, y - cy)))
    return float(cx), float(cy), max(radius, REGION_M / 2)


def _box_sum(a: np.ndarray, k: int) -> np.ndarray:
    """Sum of each k x k window of `a`, centred (zero outside), same shape: summed-area table."""
    before, after = k // 2, (k - 1) // 2
    p = np.pad(a, ((before + 1, after), (before + 1, after)))
    s = p.cumsum(0).cumsum(1)
    return s[k:, k:] - s[:-k, k:] - s[k:, :-k] + s[:-k, :-k]


def verdict_summary(share: np.ndarray, window: np.ndarray, spans: list[BrokenSpan], counts: np.ndarray) -> dict:
    """metrics.json's verdict keys: `verdict` ("consistent" | "likely broken" | "too short to
    judge"), `verdict_text` (the report's line), the shares and the broken stretches."""
    scored = np.isfinite(share)
    total = counts[:, SUPPORT:].sum()
    out: dict = {
        "contradiction_share": float((counts[:, SEE_THROUGH].sum() + counts[:, IN_FREE].sum()) / total) if total else float("nan"),
        "see_through_share": float(counts[:, SEE_THROUGH].sum() / total) if total else float("nan"),
        "in_free_share": float(counts[:, IN_FREE].sum() / total) if total else float("nan"),
        "contradiction_worst_window": float(np.nanmax(window)) if np.isfinite(window).any() else float("nan"),
        "broken_threshold": BROKEN_SHARE,
        "window_scans": WINDOW,
    }
    if scored.sum() < WINDOW:
        out["verdict"] = "too short to judge"
        out["verdict_text"] = (f"too short to judge: {int(scored.sum())} replayed scans with enough beams, "
                               f"the verdict needs {WINDOW}")
        out["broken_spans"] = []
        return out
    if not spans:
        out["verdict"] = "consistent"
        out["verdict_text"] = (f"consistent: no stretch of {WINDOW} replayed scans contradicts the map in "
                               f"{BROKEN_SHARE:.0%} of its beams or more (worst {out['contradiction_worst_window']:.0%})")
    else:
        s = spans[0]
        out["verdict"] = "likely broken"
        out["verdict_text"] = (f"likely broken near ({s.x_m:.1f}, {s.y_m:.1f}) m, between {s.t1_s:.0f} s and {s.t2_s:.0f} s: "
                               f"the scans then contradict the map in {s.peak:.0%} of their beams"
                               + (f" ({len(spans) - 1} more stretch{'es' if len(spans) > 2 else ''})" if len(spans) > 1 else ""))
    out["broken_spans"] = [s.to_dict() for s in spans]
    return out


def overlay_arrays(events: _Events, grid: GridImage, spans: list[BrokenSpan]) -> dict[str, np.ndarray]:
    """consistency_map.npz (docs/RUN_DIRECTORY.md): on EVENT_BIN_M cells over the map's
    extent (`origin_xy`, `bin_m`), the beams that saw through a wall (`see_through`, counted
    at the wall crossed), that landed in free space (`in_free`) and that landed on a wall
    (`support`), uint16, and the same two contradictions of the scans in broken stretches alone
    (`broken_see_through`, `broken_in_free`: the report draws those strong, the rest faint);
    and on REGION_M squares (`region_m`) each square's contradiction share (`region_share`,
    float32, NaN where fewer than 30 beams)."""
    H, W = grid.data.shape
    res = grid.resolution_m
    k = max(1, int(round(EVENT_BIN_M / res)))
    hb, wb = -(-H // k), -(-W // k)
    out: dict[str, np.ndarray] = {"origin_xy": np.asarray(grid.origin_xy, np.float64), "bin_m": np.float64(k * res)}
    on = (events.row >= 0) & (events.row < H) & (events.col >= 0) & (events.col < W)
    in_span = np.zeros(len(events.scan), bool)
    for sp in spans:
        in_span |= (events.scan >= sp.first) & (events.scan <= sp.last)
    for name, which, only in (("see_through", SEE_THROUGH, None), ("in_free", IN_FREE, None), ("support", SUPPORT, None),
                              ("broken_see_through", SEE_THROUGH, in_span), ("broken_in_free", IN_FREE, in_span)):
        m = on & (events.cls == which)
        if only is not None:
            m &= only
        counts = np.bincount((events.row[m] // k) * wb + events.col[m] // k, minlength=hb * wb)
        out[name] = np.minimum(counts, np.iinfo(np.uint16).max).astype(np.uint16).reshape(hb, wb)
    g = max(1, int(round(REGION_M / res)))
    rh, rw = -(-H // g), -(-W // g)
    bad = np.bincount((events.row[on & (events.cls >= SEE_THROUGH)] // g) * rw + events.col[on & (events.cls >= SEE_THROUGH)] // g,
                      minlength=rh * rw)
    allc = np.bincount((events.row[on] // g) * rw + events.col[on] // g, minlength=rh * rw)
    share = np.full(rh * rw, np.nan, np.float32)
    enough = allc >= 30
    share[enough] = bad[enough] / allc[enough]
    out["region_share"] = share.reshape(rh, rw)
    out["region_m"] = np.float64(g * res)
    return out
