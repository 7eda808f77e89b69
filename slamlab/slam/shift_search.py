"""The grid matcher's search when its x/y offsets are whole cells (`matcher.cell_shifts`; the
course's 5 cm offsets on a 5 cm map): on one shared map (`grid_search_shifts`, filter=course)
and on a map per particle in tiles (`tiled_grid_search_shifts`, filter=rbpf).

For each yaw offset a particle's points are placed (rotated, floored) once, and each point
then reads the block of cells its x/y shifts reach, a row at a time, adding a hit to every
shift at once: the reads of one point are neighbours in memory, where scoring one offset
after another walks all the points again per offset. Points within `_BORDER_CELLS` of a cell
border are placed anew at every offset, exactly as `score_hits` places them, so rounding can
never put one in another cell. A score is a whole count, so the order the hits are added in
does not matter: counts, chosen offsets and trajectories are those of scoring every offset
with `score_hits` (`matcher.grid_search_hits`, `tiled_match.tiled_grid_search`).

Particles run on all cores; each particle's result depends only on its own inputs (not on
the thread count).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from slamlab.slam.tiled_match import tiled_score_hits
from slamlab.slam.tiles import TILE_MASK, TILE_SHIFT

# a point this close (in cells) to a cell border is placed anew for every offset
_BORDER_CELLS = 1e-6


@numba.njit(cache=True)
def score_hits(lo, thresh, ox, oy, inv_res, x, y, th, pts):
    """Number of points (M, 2, body-yaw frame) that fall on cells with `lo > thresh` when
    the body is at (x, y, th)."""
    H, W = lo.shape
    c = math.cos(th)
    s = math.sin(th)
    total = 0.0
    for i in range(pts.shape[0]):
        wx = x + c * pts[i, 0] - s * pts[i, 1]
        wy = y + s * pts[i, 0] + c * pts[i, 1]
        col = int(math.floor((wx - ox) * inv_res))
        row = int(math.floor((wy - oy) * inv_res))
        if 0 <= row < H and 0 <= col < W and lo[row, col] > thresh:
            total += 1.0
    return total


@numba.njit(cache=True, parallel=True)
def grid_search_shifts(lo, thresh, ox, oy, inv_res, poses, pts, offsets, shifts, by_yaw, yaws, out_poses, out_scores):
    """For each particle, the offset (K, 3: dx m, dy m, dyaw rad) with the most points on
    cells of `lo` above `thresh` (ties to the earlier offset), as `matcher.grid_search_hits`
    finds it. `shifts`, `by_yaw`, `yaws`: `matcher.cell_shifts(offsets, res)`."""
    r_lo, c_lo, nr, nc = _shift_box(shifts)
    m = pts.shape[0]
    for i in numba.prange(poses.shape[0]):
        score = np.zeros(offsets.shape[0])
        block = np.zeros(nr * nc, dtype=np.int64)  # hits by (row, col) shift
        cells = np.empty((m, 2), dtype=np.int64)
        exact = np.empty((m, 2))
        for a in range(yaws.shape[0]):
            th = poses[i, 2] + yaws[a]
            n, n_exact = place_cells(poses[i, 0], poses[i, 1], th, pts, ox, oy, inv_res, cells, exact)
            block[:] = 0
            for q in range(n):
                count_block(lo, thresh, cells[q, 0] + r_lo, cells[q, 1] + c_lo, nr, nc, block)
            for j in range(by_yaw.shape[1]):
                k = by_yaw[a, j]
                total = float(block[(shifts[k, 0] - r_lo) * nc + shifts[k, 1] - c_lo])
                if n_exact > 0:
                    total += score_hits(lo, thresh, ox, oy, inv_res, poses[i, 0] + offsets[k, 0], poses[i, 1] + offsets[k, 1], th, exact[:n_exact])
                score[k] = total
        _take_best(i, poses, offsets, score, out_poses, out_scores)


@numba.njit(cache=True, parallel=True)
def tiled_grid_search_shifts(pool_lo, table, thresh, ox, oy, inv_res, poses, pts, offsets, shifts, by_yaw, yaws, out_poses, out_scores):
    """`grid_search_shifts` where particle i has its own map `table[i]` (tiles of `pool_lo`),
    as `tiled_match.tiled_grid_search` finds it."""
    r_lo, c_lo, nr, nc = _shift_box(shifts)
    m = pts.shape[0]
    for i in numba.prange(poses.shape[0]):
        tab = table[i]
        score = np.zeros(offsets.shape[0])
        block = np.zeros(nr * nc, dtype=np.int64)
        cells = np.empty((m, 2), dtype=np.int64)
        exact = np.empty((m, 2))
        for a in range(yaws.shape[0]):
            th = poses[i, 2] + yaws[a]
            n, n_exact = place_cells(poses[i, 0], poses[i, 1], th, pts, ox, oy, inv_res, cells, exact)
            block[:] = 0
            for q in range(n):
                count_block_tiled(pool_lo, tab, thresh, cells[q, 0] + r_lo, cells[q, 1] + c_lo, nr, nc, block)
            for j in range(by_yaw.shape[1]):
                k = by_yaw[a, j]
                total = float(block[(shifts[k, 0] - r_lo) * nc + shifts[k, 1] - c_lo])
                if n_exact > 0:
                    total += tiled_score_hits(pool_lo, tab, thresh, ox, oy, inv_res, poses[i, 0] + offsets[k, 0], poses[i, 1] + offsets[k, 1], th, exact[:n_exact])
                score[k] = total
        _take_best(i, poses, offsets, score, out_poses, out_scores)


@numba.njit(cache=True)
def _shift_box(shifts):
    """(first row shift, first column shift, rows, columns) of the box the shifts span."""
    r_lo = shifts[:, 0].min()
    c_lo = shifts[:, 1].min()
    return r_lo, c_lo, shifts[:, 0].max() - r_lo + 1, shifts[:, 1].max() - c_lo + 1


@numba.njit(cache=True)
def place_cells(x, y, th, pts, ox, oy, inv_res, cells, exact):
    """Where the points (M, 2, body-yaw frame) fall with the body at (x, y, th), as
    `score_hits` places them: (row, col) of each point clear of cell borders in cells[:n],
    the body coordinates of the others in exact[:n_exact]. Returns (n, n_exact)."""
    c = math.cos(th)
    s = math.sin(th)
    n = 0
    n_exact = 0
    for q in range(pts.shape[0]):
        u = (x + c * pts[q, 0] - s * pts[q, 1] - ox) * inv_res
        v = (y + s * pts[q, 0] + c * pts[q, 1] - oy) * inv_res
        col = math.floor(u)
        row = math.floor(v)
        fu = u - col
        fv = v - row
        # written so that NaN (a NaN point or pose) is placed exactly too: its cell would be
        # floor(NaN), and the bounds checks of `count_block` could overflow on it
        if not (_BORDER_CELLS <= fu <= 1.0 - _BORDER_CELLS and _BORDER_CELLS <= fv <= 1.0 - _BORDER_CELLS):
            exact[n_exact, 0] = pts[q, 0]
            exact[n_exact, 1] = pts[q, 1]
            n_exact += 1
        else:
            cells[n, 0] = int(row)
            cells[n, 1] = int(col)
            n += 1
    return n, n_exact


@numba.njit(cache=True, inline="always")
def count_block(lo, thresh, r0, c0, nr, nc, block):
    """Add 1 to block[a * nc + b] for every cell (r0 + a, c0 + b) of `lo` above `thresh`
    (a < nr, b < nc); cells off the map count nothing."""
    H, W = lo.shape
    if r0 >= 0 and c0 >= 0 and r0 <= H - nr and c0 <= W - nc:  # inside: no bounds to check (no overflow either)
        for a in range(nr):
            row = lo[r0 + a]
            for b in range(nc):
                block[a * nc + b] += 1 if row[c0 + b] > thresh else 0
        return
    for a in range(max(0, -r0), min(nr, H - r0)):
        row = lo[r0 + a]
        for b in range(max(0, -c0), min(nc, W - c0)):
            block[a * nc + b] += 1 if row[c0 + b] > thresh else 0


@numba.njit(cache=True, inline="always")
def count_block_tiled(pool, tab, thresh, r0, c0, nr, nc, block):
    """`count_block` on the tiled map `tab` (one particle's tile table into `pool`): a
    block row within one tile (nearly always) looks its tile up once."""
    H = tab.shape[0] << TILE_SHIFT
    W = tab.shape[1] << TILE_SHIFT
    b0 = max(0, -c0)
    b1 = min(nc, W - c0)
    if b0 >= b1:
        return
    first = c0 + b0
    last = c0 + b1 - 1
    for a in range(max(0, -r0), min(nr, H - r0)):
        r = r0 + a
        ir = r & TILE_MASK
        tiles = tab[r >> TILE_SHIFT]
        if first >> TILE_SHIFT == last >> TILE_SHIFT:
            row = pool[tiles[first >> TILE_SHIFT], ir]
            at = (first & TILE_MASK) - b0
            for b in range(b0, b1):
                block[a * nc + b] += 1 if row[at + b] > thresh else 0
        else:
            for b in range(b0, b1):
                col = c0 + b
                block[a * nc + b] += 1 if pool[tiles[col >> TILE_SHIFT], ir, col & TILE_MASK] > thresh else 0


@numba.njit(cache=True, inline="always")
def _take_best(i, poses, offsets, score, out_poses, out_scores):
    """Particle i moved by its best-scoring offset (the earliest of equal scores)."""
    best = -1.0
    bk = 0
    for k in range(offsets.shape[0]):
        if score[k] > best:
            best = score[k]
            bk = k
    out_poses[i, 0] = poses[i, 0] + offsets[bk, 0]
    out_poses[i, 1] = poses[i, 1] + offsets[bk, 1]
    out_poses[i, 2] = poses[i, 2] + offsets[bk, 2]
    out_scores[i] = best
