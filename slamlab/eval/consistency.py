"""Map consistency without ground truth: do the scans agree with the map they built?

Most logs users bring have no ground truth and no relations, so every run is also scored
against itself. Scans are replayed at the estimated trajectory (a sample of up to
`max_scans`, spread evenly over the run) against the final map:

- **hit fraction** (per scan, 0-1): the fraction of the scan's endpoints that land on an
  occupied cell of the final map or one of its 8 neighbours (one cell of slack for the
  grid's rounding). Where tracking holds, nearly every endpoint on a wall lands on that
  wall (moving people and clutter seen once cost a few per cent). Where the map broke
  (a slipped match, a loop closed wrongly) the scans of one pass land beside the walls
  another pass drew, and the fraction drops for that stretch of the run.
- **conflict fraction** (whole map, 0-1): of the cells the sampled endpoints hit at least
  `MIN_HITS` times, the fraction that the sampled beams also cross (as free space) at
  least twice as often as they hit them. A doubled or smeared wall is crossed by the beams
  of the pass that put the wall elsewhere. Crossings within `NEAR_M` of a beam's own hit
  are not counted: a beam grazing a wall walks through that wall's cells before its hit.

What the values mean is measured in README (section "Is the map consistent?"): consistent runs on the
benchmark logs score a hit-fraction mean around 0.9 and a conflict fraction of a few per
cent; runs that lost a loop or have no scan matching score clearly lower / higher.
"""

from __future__ import annotations

import numba
import numpy as np

from slamlab.frames import GridImage, Sequence
from slamlab.geometry import FloatArray
from slamlab.slam.grid import MapSettings
from slamlab.slam.raycast import line_start, line_step
from slamlab.slam.scan import place, range_limits, scans_to_points

WINDOW = 25  # scored scans per rolling median: the worst stretch of the run
NEAR_M = 0.5  # crossings this close to a beam's own hit (m) are not counted as conflicts
MIN_HITS = 4  # a cell is a wall of the replay when the sampled scans hit it this often
CHUNK = 100  # scans placed at once (~18,000 points on Intel: a few MB of temporaries)


@numba.njit(cache=True)
def _near_wall(log_odds, threshold, rows, cols):
    """Whether cell (rows[k], cols[k]) or one of its 8 neighbours (on the map) is occupied:
    looked up at the endpoints only (a dilated copy of a building's map is 10^8 cells)."""
    H, W = log_odds.shape
    out = np.zeros(rows.shape[0], dtype=np.bool_)
    for k in range(rows.shape[0]):
        for r in range(max(rows[k] - 1, 0), min(rows[k] + 2, H)):
            for c in range(max(cols[k] - 1, 0), min(cols[k] + 2, W)):
                if log_odds[r, c] > threshold:
                    out[k] = True
    return out


@numba.njit(cache=True)
def _count_passes(passes, s_row, s_col, e_row, e_col, ends):
    """+1 on every cell each beam walks, its end included: scan j's beams run from cell
    (s_row[j], s_col[j]) to (e_row[k], e_col[k]) for k in ends[j]:ends[j + 1], along the
    cells the map's own ray cast walks (`raycast.line_step`). All cells lie in `passes`."""
    for j in range(s_row.shape[0]):
        r0 = s_row[j]
        c0 = s_col[j]
        for k in range(ends[j], ends[j + 1]):
            dr, dc, sr, sc, err, major_c, n = line_start(r0, c0, e_row[k], e_col[k])
            r = r0
            c = c0
            for _ in range(n):
                passes[r, c] += 1
                r, c, err = line_step(r, c, err, dr, dc, sr, sc, major_c)
            passes[e_row[k], e_col[k]] += 1


def consistency_metrics(
    sequence: Sequence,
    poses: FloatArray,
    log_odds: GridImage,
    settings: MapSettings,
    max_scans: int = 1000,
) -> tuple[dict, dict[str, np.ndarray]]:
    """Score the run's scans against its final map (see module doc).

    `poses` (N, 3): the estimated pose (x m, y m, theta rad) of the first N scans of
    `sequence`; `log_odds` the final map; `settings` the run's map settings (ranges, ground
    threshold, occupied threshold). Returns (summary for metrics.json, per-scan series
    {"t" s, "scan_index", "hit_fraction"} of the scored scans)."""
    n = len(poses)
    pick = np.unique(np.linspace(0, n - 1, min(n, max_scans)).round().astype(np.int64)) if n else np.zeros(0, np.int64)
    H, W = log_odds.data.shape
    passes = np.zeros((H, W), dtype=np.int32)  # beams through each cell, counted by the map's own ray walk
    inv = 1.0 / log_odds.resolution_m
    ox, oy = log_odds.origin_xy
    min_r, max_r = range_limits(settings, sequence)
    frac = np.full(len(pick), np.nan)

    def cells(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        c = np.floor((xy[:, 0] - ox) * inv).astype(np.int64)
        r = np.floor((xy[:, 1] - oy) * inv).astype(np.int64)
        return r, c, (r >= 0) & (r < H) & (c >= 0) & (c < W)

    # the scored scans' points are placed and looked up CHUNK scans at a time (per scan, NumPy's
    # call overhead was most of this function's 0.3 s on Intel; all 1,000 at once held 18 MB more)
    n_points = np.zeros(len(pick), dtype=np.int64)  # endpoints of each scored scan, on the map or not
    on_map_parts, hit_scan_parts = [], []
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
        world = place(np.concatenate([p.xy for p in scans]), pose[:, 0], pose[:, 1], cos[scan_of], sin[scan_of])
        rows, cols, inside = cells(world)
        # row * W + col of each sampled endpoint on the map (a building's map has 10^8 cells:
        # hits are counted from this list, not in another map-sized array)
        on_map_parts.append(rows[inside] * W + cols[inside])
        hit_scan_parts.append(lo + scan_of[inside])
        # crossings: each beam walked up to NEAR_M short of its hit (a beam grazing a wall
        # walks through that wall's own cells just before it, which is no conflict)
        sensor = place(np.array([p.origin for p in scans]).reshape(-1, 2), poses[chunk, 0], poses[chunk, 1], cos, sin)
        s_row, s_col, s_in = cells(sensor)
        ray = world - sensor[scan_of]
        length = np.hypot(ray[:, 0], ray[:, 1])
        far = (length > NEAR_M) & s_in[scan_of]
        short = sensor[scan_of[far]] + ray[far] * ((length[far] - NEAR_M) / length[far])[:, None]
        e_row, e_col, e_in = cells(short)
        ends = np.searchsorted(scan_of[far][e_in], np.arange(len(chunk) + 1))  # scan j walks ends[j]:ends[j + 1]
        _count_passes(passes, s_row, s_col, e_row[e_in], e_col[e_in], ends)
    on_map = np.concatenate(on_map_parts) if on_map_parts else np.zeros(0, np.int64)
    hit_scan = np.concatenate(hit_scan_parts) if hit_scan_parts else np.zeros(0, np.int64)
    # each scan's hit fraction: its endpoints near a wall over all its endpoints (looked up for
    # every scan at once: per scan, the nine lookups cost a third of this function)
    # the threshold in the map's own type: NumPy compares a float32 map with a Python float in
    # float32, and so does the kernel then (in float64 a map value equal to float32(0.1) would pass 0.1)
    threshold = log_odds.data.dtype.type(settings.occupied_threshold)
    near = _near_wall(log_odds.data, threshold, on_map // W, on_map % W)
    near_count = np.bincount(hit_scan, weights=near, minlength=len(pick))
    frac[n_points > 0] = near_count[n_points > 0] / n_points[n_points > 0]
    cell, hits = np.unique(on_map, return_counts=True)
    walls = hits >= MIN_HITS
    crossed = passes.ravel()[cell[walls]]
    conflict = float(np.mean(crossed >= 2 * hits[walls])) if walls.any() else float("nan")
    scored = frac[np.isfinite(frac)]
    summary: dict = {"scans_scored": int(len(scored)), "conflict_fraction": conflict}
    if len(scored):
        k = min(WINDOW, len(scored))
        rolling = np.median(np.lib.stride_tricks.sliding_window_view(scored, k), axis=1)
        summary.update(
            hit_fraction_mean=float(scored.mean()),
            hit_fraction_p10=float(np.percentile(scored, 10)),
            # the worst stretch: where the map broke, if anywhere
            hit_fraction_worst_window=float(rolling.min()),
        )
    series = {
        "t": np.array([sequence.scans[i].t for i in pick], dtype=np.float64),
        "scan_index": np.array([sequence.scans[i].index for i in pick], dtype=np.int64),
        "hit_fraction": frac,
    }
    return summary, series
