"""Ray casting into the log-odds grid (numba): cells along each beam down, end cells up.

Grid arrays are indexed [row, col] with row = y and col = x (row 0 = lowest y).
All free-space updates of a scan are applied before its hits, so a wall cell crossed by a
neighbouring beam of the same scan is not erased by it.
"""

from __future__ import annotations

import numba
import numpy as np


def bresenham(r0: int, c0: int, r1: int, c1: int) -> list[tuple[int, int]]:
    """Reference (pure Python) list of cells from (r0, c0) to (r1, c1), both included.
    Used by tests to check the compiled kernel, which walks the same cells."""
    cells = []
    dr, dc = abs(r1 - r0), abs(c1 - c0)
    sr = 1 if r1 > r0 else -1
    sc = 1 if c1 > c0 else -1
    err = dc - dr
    r, c = r0, c0
    while True:
        cells.append((r, c))
        if r == r1 and c == c1:
            return cells
        e2 = 2 * err
        if e2 > -dr:
            err -= dr
            c += sc
        if e2 < dc:
            err += dc
            r += sr


@numba.njit(cache=True, inline="always")
def line_start(r0, c0, r1, c1):
    """The kernels' Bresenham walk from cell (r0, c0) toward (r1, c1) (`line_step` takes it
    on): (dr, dc, sr, sc, err, major_c, n), the beam's deltas |dr|, |dc|, their signs, the
    error term's start, whether columns are the major axis, and n, the number of cells the
    walk visits before the end cell."""
    dr = abs(r1 - r0)
    dc = abs(c1 - c0)
    sr = 1 if r1 > r0 else -1
    sc = 1 if c1 > c0 else -1
    major_c = dc >= dr
    return dr, dc, sr, sc, dc - dr, major_c, dc if major_c else dr


@numba.njit(cache=True, inline="always")
def line_step(r, c, err, dr, dc, sr, sc, major_c):
    """One step of the kernels' Bresenham walk from (r, c) (beam deltas |dr|, |dc|, signs sr,
    sc, error term `err`, started at dc - dr): a line takes max(dr, dc) steps, each one along
    the major axis (`major_c`: dc >= dr) and, when the error says so, one along the minor.
    The minor step is computed (0 or 1), not branched on: its pattern along a slanted beam
    defeats branch prediction (1.5 instead of 2.3 ns a cell on a plain grid). Visits the
    cells `bresenham` lists. Returns the next (r, c, err)."""
    if major_c:
        m = 1 if 2 * err < dc else 0
        return r + m * sr, c + sc, err + m * dc - dr
    m = 1 if 2 * err > -dr else 0
    return r + sr, c + m * sc, err + dc - m * dr


@numba.njit(cache=True, inline="always")
def _clamped_sum(old, delta, lmin, lmax):
    """old + delta, clamped to [lmin, lmax]."""
    new = old + delta
    if new < lmin:
        new = lmin
    elif new > lmax:
        new = lmax
    return new


@numba.njit(cache=True, inline="always")
def _add(lo, r, c, delta, lmin, lmax, thresh, flip):
    old = lo[r, c]
    new = _clamped_sum(old, delta, lmin, lmax)
    lo[r, c] = new
    if (old > thresh) != (new > thresh):
        # remember the bounding box of cells whose occupied/free state changed
        if r < flip[0]:
            flip[0] = r
        if r > flip[1]:
            flip[1] = r
        if c < flip[2]:
            flip[2] = c
        if c > flip[3]:
            flip[3] = c


@numba.njit(cache=True)
def raycast_update(lo, r0, c0, rows, cols, l_occ, l_free, lmin, lmax, thresh, flip):
    """Update log-odds `lo` (float32 [H, W]) for beams from cell (r0, c0) to each (rows[k],
    cols[k]): every cell strictly before the end gets `l_free` (< 0), the end cell `l_occ`;
    values are clamped to [lmin, lmax]. Cells whose `lo > thresh` state flips extend the
    int64 box `flip` = [rmin, rmax, cmin, cmax] (in/out). All cells must lie inside `lo`."""
    for k in range(rows.shape[0]):
        dr, dc, sr, sc, err, major_c, n = line_start(r0, c0, rows[k], cols[k])
        r = r0
        c = c0
        for _ in range(n):  # the line's cells without its end
            _add(lo, r, c, l_free, lmin, lmax, thresh, flip)
            r, c, err = line_step(r, c, err, dr, dc, sr, sc, major_c)
    for k in range(rows.shape[0]):
        _add(lo, rows[k], cols[k], l_occ, lmin, lmax, thresh, flip)


@numba.njit(cache=True, parallel=True)
def raycast_many_bands(lo, sensor_rows, sensor_cols, rows, cols, starts, l_occ, l_free, lmin, lmax, band_rows):
    """`raycast_update` scan after scan (scan s: from cell (sensor_rows[s], sensor_cols[s]) to
    its beams' ends rows / cols[starts[s]:starts[s + 1]]), with the grid's rows cut into bands
    of `band_rows` updated on all cores. Each band walks the beams crossing its rows in the
    scans' order and changes only its own cells, so every cell gets the same additions in the
    same order as one thread gives it: the same values, bit for bit (a building's map drawn
    again from its ~2,000 scans after a loop closes). All cells must lie inside `lo`."""
    H = lo.shape[0]
    for b in numba.prange((H + band_rows - 1) // band_rows):
        top = b * band_rows
        bottom = min(top + band_rows, H)
        for s in range(starts.shape[0] - 1):
            r0 = sensor_rows[s]
            c0 = sensor_cols[s]
            for k in range(starts[s], starts[s + 1]):
                if max(r0, rows[k]) < top or min(r0, rows[k]) >= bottom:
                    continue  # the beam misses the band
                dr, dc, sr, sc, err, major_c, n = line_start(r0, c0, rows[k], cols[k])
                r = r0
                c = c0
                for _ in range(n):
                    if top <= r < bottom:
                        lo[r, c] = _clamped_sum(lo[r, c], l_free, lmin, lmax)
                    r, c, err = line_step(r, c, err, dr, dc, sr, sc, major_c)
            for k in range(starts[s], starts[s + 1]):
                if top <= rows[k] < bottom:
                    lo[rows[k], cols[k]] = _clamped_sum(lo[rows[k], cols[k]], l_occ, lmin, lmax)


@numba.njit(cache=True, inline="always")
def _add_noting(lo, r, c, delta, lmin, lmax, thresh, flips, n):
    """`_add`, appending the cell to `flips` (K, 2: row, col) when its occupied state changes
    (while there is room; `n` counts every change, so n > K says some were not kept)."""
    old = lo[r, c]
    new = _clamped_sum(old, delta, lmin, lmax)
    lo[r, c] = new
    if (old > thresh) != (new > thresh):
        if n < flips.shape[0]:
            flips[n, 0] = r
            flips[n, 1] = c
        n += 1
    return n


@numba.njit(cache=True)
def raycast_update_noting(lo, r0, c0, rows, cols, l_occ, l_free, lmin, lmax, thresh, flips):
    """`raycast_update` (the same cells, the same order, the same values), listing the cells
    whose occupied state changed in `flips` (K, 2) instead of their bounding box: those
    that turned free first, then those that turned occupied. Returns (turned free, turned
    occupied) counts; a count larger than the room left says the list is incomplete."""
    n_free = 0
    for k in range(rows.shape[0]):
        dr, dc, sr, sc, err, major_c, n = line_start(r0, c0, rows[k], cols[k])
        r = r0
        c = c0
        for _ in range(n):
            n_free = _add_noting(lo, r, c, l_free, lmin, lmax, thresh, flips, n_free)
            r, c, err = line_step(r, c, err, dr, dc, sr, sc, major_c)
    kept = min(n_free, flips.shape[0])
    n_occ = 0
    rest = flips[kept:]
    for k in range(rows.shape[0]):
        n_occ = _add_noting(lo, rows[k], cols[k], l_occ, lmin, lmax, thresh, rest, n_occ)
    return n_free, n_occ


# Walls at their hits (`OccupancyGrid(walls_at_hits=True)`): each cell keeps the running mean of
# where in it the scan hits fell, in 1/HIT_UNITS of a cell from its centre (int8 x, y) and how many
# (uint8, counted up to HIT_COUNT_CAP: then each hit weighs 1/(cap + 1), a moving average). The
# mean is rounded to whole units after each hit, so a hit moves it only when it lies more than
# about n/2 units away: the cap keeps that dead band (8 units, 1/32 of a cell) below half a place.
# Its field kernel is centred there, at the nearest of WALL_STEPS x WALL_STEPS places in the cell
# (`kernel_bank`). Walls at cell centres sit up to half a cell inside the surface they stand for,
# so a corridor maps half a cell to a cell too narrow, and a scan seeing a few metres of wall at an
# angle matches turned by a fraction of a degree (benchmarks/RESULTS.md, 2026-11-29).
HIT_UNITS = 256
HIT_COUNT_CAP = 16
WALL_STEPS = 9  # odd: the middle place is the centre


@numba.njit(cache=True, inline="always")
def _place(hit_dx, hit_dy, r, c, steps):
    """The place (qy, qx) in a bank of steps x steps kernels of a wall at (r, c): the one nearest
    its mean hit offset, or the middle one when no hit offsets are kept (`hit_dx` empty: walls
    at cell centres)."""
    if hit_dx.shape[0] == 0:
        return steps // 2, steps // 2
    qx = ((np.int64(hit_dx[r, c]) + HIT_UNITS // 2) * steps) // HIT_UNITS
    qy = ((np.int64(hit_dy[r, c]) + HIT_UNITS // 2) * steps) // HIT_UNITS
    return qy, qx


@numba.njit(cache=True)
def raise_field(field, bank, hit_dx, hit_dy, cells):
    """Raise the field to each cell's kernel (`bank`, at the cell's place: `_place`) around each
    cell of `cells` (K, 2: row, col): what a cell turning occupied adds to the field (values
    only rise, so the order does not matter)."""
    H, W = field.shape
    R = bank.shape[2] // 2
    for i in range(cells.shape[0]):
        r = cells[i, 0]
        c = cells[i, 1]
        qy, qx = _place(hit_dx, hit_dy, r, c, bank.shape[0])
        kernel = bank[qy, qx]
        for rr in range(max(r - R, 0), min(r + R + 1, H)):
            for cc in range(max(c - R, 0), min(c + R + 1, W)):
                v = kernel[rr - r + R, cc - c + R]
                if v > field[rr, cc]:
                    field[rr, cc] = v


@numba.njit(cache=True)
def refresh_cells(lo, field, thresh, bank, hit_dx, hit_dy, cells):
    """`update_field` over the (2R+1)^2 neighbourhood of each cell of `cells` (K, 2: row,
    col), one after the other: the field around cells that turned free or whose wall moved
    (their value may have come from them), without recomputing the box spanning all of them."""
    H, W = lo.shape
    R = bank.shape[2] // 2
    for i in range(cells.shape[0]):
        r = cells[i, 0]
        c = cells[i, 1]
        update_field(lo, field, thresh, bank, hit_dx, hit_dy, max(r - R, 0), min(r + R + 1, H), max(c - R, 0), min(c + R + 1, W))


@numba.njit(cache=True)
def update_field(lo, field, thresh, bank, hit_dx, hit_dy, r0, r1, c0, c1):
    """Recompute the likelihood field `field` ([H, W]) in rows [r0, r1), cols [c0, c1):
    each cell gets the max over occupied cells (`lo > thresh`) within R cells of their kernel
    (`bank` [S, S, 2R+1, 2R+1], e.g. a Gaussian of the distance, at the wall's place:
    `_place`; S = 1: at cell centres). Field and bank hold values or their order-keeping codes
    (`field_cells.value_codes`) alike: only their order is used. Cells outside the box are
    unchanged, so a caller recomputes only where the occupancy changed (plus R).
    A cell already 0 is not written: a zero page of a building's map (far from any wall) then
    stays a page the system never backs, where a write would make it resident."""
    H, W = lo.shape
    R = bank.shape[2] // 2
    for r in range(r0, r1):
        for c in range(c0, c1):
            if field[r, c] != 0:
                field[r, c] = 0
    for r in range(max(r0 - R, 0), min(r1 + R, H)):
        for c in range(max(c0 - R, 0), min(c1 + R, W)):
            if lo[r, c] > thresh:
                qy, qx = _place(hit_dx, hit_dy, r, c, bank.shape[0])
                kernel = bank[qy, qx]
                for rr in range(max(r - R, r0), min(r + R + 1, r1)):
                    for cc in range(max(c - R, c0), min(c + R + 1, c1)):
                        v = kernel[rr - r + R, cc - c + R]
                        if v > field[rr, cc]:
                            field[rr, cc] = v


@numba.njit(cache=True, parallel=True)
def update_field_bands(lo, field, thresh, bank, hit_dx, hit_dy, r0, r1, c0, c1, band_rows):
    """`update_field` over the box, in bands of `band_rows` rows on all cores: a band's cells
    take their values from the walls within R rows of it, as the whole box's would, and each
    band writes only its own rows, so the field is the same whatever the thread count (a
    whole building's map, redrawn after a loop closes: ~0.3 s a time on one core)."""
    n = (r1 - r0 + band_rows - 1) // band_rows
    for i in numba.prange(n):
        a = r0 + i * band_rows
        update_field(lo, field, thresh, bank, hit_dx, hit_dy, a, min(a + band_rows, r1), c0, c1)


@numba.njit(cache=True, inline="always")
def _mean_step(old, offset, n):
    """The running mean `old` (int8 units) after one more hit at `offset` (float units), the
    `n`-th (n >= 1), rounded half up."""
    new = np.int64(np.floor(old + (offset - old) / n + 0.5))
    return min(max(new, -(HIT_UNITS // 2)), HIT_UNITS // 2 - 1)


@numba.njit(cache=True)
def note_hits(lo, thresh, hit_dx, hit_dy, hit_n, pts, x0, y0, inv_res, rows, cols, steps, moved):
    """Take each hit (world points (M, 2) m; in cell rows, cols of a grid with origin x0, y0 and 1 / res
    `inv_res`) into its cell's mean hit offset (`hit_dx`, `hit_dy` int8 in 1/HIT_UNITS of a cell,
    `hit_n` the count). Cells that are walls (`lo > thresh`) and whose place among steps x steps
    (`_place`) changed are listed in `moved` (K, 2) while there is room; returns how many (a count
    over K says some were not kept; an empty `moved` lists none: no field to keep)."""
    m = 0
    for k in range(rows.shape[0]):
        r = rows[k]
        c = cols[k]
        u = ((pts[k, 0] - x0) * inv_res - c - 0.5) * HIT_UNITS
        v = ((pts[k, 1] - y0) * inv_res - r - 0.5) * HIT_UNITS
        before = _place(hit_dx, hit_dy, r, c, steps)
        n = np.int64(hit_n[r, c]) + 1
        hit_dx[r, c] = _mean_step(np.int64(hit_dx[r, c]), u, n)
        hit_dy[r, c] = _mean_step(np.int64(hit_dy[r, c]), v, n)
        if n <= HIT_COUNT_CAP:
            hit_n[r, c] = n
        if moved.shape[0] > 0 and lo[r, c] > thresh and _place(hit_dx, hit_dy, r, c, steps) != before:
            if m < moved.shape[0]:
                moved[m, 0] = r
                moved[m, 1] = c
            m += 1
    return m


@numba.njit(cache=True, parallel=True)
def copy_nonzero(src, dst, r0, c0):
    """dst[r0 + r, c0 + c] = src[r, c] wherever src[r, c] != 0, for a zeroed `dst` (a grown
    grid): the same array as a plain copy, but a page of `dst` where src holds only zeros
    (unmapped space around a building) is never written, so the system never backs it.
    Rows on all cores (each cell written once, whatever the thread count): a building's map
    grows ~100 times, and the copies took 5.6 s of the hospital run on one core."""
    for r in numba.prange(src.shape[0]):
        for c in range(src.shape[1]):
            v = src[r, c]
            if v != 0:
                dst[r0 + r, c0 + c] = v


@numba.njit(cache=True, inline="always")
def field_place(x, y, c, s, px, py, ox, oy, inv_res):
    """A body point (px, py, m) with the body at (x, y) and yaw (c, s) = (cos, sin): its world
    position (wx, wy) and its place (u, v) on a map of origin (ox, oy), in cells with the
    cell centres at integers (where a bilinear field read starts). Every field reader places
    points this one way, so their sums agree to the bit."""
    wx = x + c * px - s * py
    wy = y + s * px + c * py
    return wx, wy, (wx - ox) * inv_res - 0.5, (wy - oy) * inv_res - 0.5


def field_radius_cells(sigma_m: float, radius_m: float, res_m: float) -> int:
    """The likelihood field's kernel radius in cells: radius_m (at least sigma_m and one cell)."""
    return max(int(np.ceil(max(radius_m, sigma_m) / res_m)), 1)


def gaussian_kernel(sigma_cells: float, radius_cells: int, offset_xy: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """float32 [2R+1, 2R+1] with exp(-d^2 / (2 sigma^2)), d the distance in cells from the
    centre cell's centre moved by `offset_xy` (cells)."""
    ax = np.arange(-radius_cells, radius_cells + 1, dtype=np.float64)
    d2 = (ax[:, None] - offset_xy[1]) ** 2 + (ax[None, :] - offset_xy[0]) ** 2
    k = np.exp(-d2 / (2.0 * sigma_cells**2))
    k[d2 > (radius_cells + 0.5) ** 2] = 0.0
    return k.astype(np.float32)


def kernel_bank(sigma_cells: float, radius_cells: int, steps: int) -> np.ndarray:
    """float32 [steps, steps, 2R+1, 2R+1]: [qy, qx] is `gaussian_kernel` centred at offset
    ((qx + 0.5) / steps - 0.5, (qy + 0.5) / steps - 0.5) cells from the cell's centre (`_place`
    picks one). steps=1: the one kernel at the centre."""
    offsets = (np.arange(steps) + 0.5) / steps - 0.5
    return np.stack([np.stack([gaussian_kernel(sigma_cells, radius_cells, (float(dx), float(dy))) for dx in offsets]) for dy in offsets])
