"""One-pass reductions of a whole log-odds grid for the replay's snapshots (numba).

A building's map is 10^8 cells and the engine reduces it at each of its 100 snapshots: numpy's
version (`replay.block_max` and an `abs > eps` mask) made whole-map temporaries and read the
grid k x k times with a stride (9.5 s of a 64 s run on the Freiburg hospital log). These give
the same values in one pass without temporaries."""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)
def block_max_1pass(data, k):
    """`replay.block_max(data, k)` (k >= 1): each k x k block's largest value, blocks that
    reach past the grid padded with 0."""
    H, W = data.shape
    h = (H + k - 1) // k
    w = (W + k - 1) // k
    out = np.empty((h, w), dtype=data.dtype)
    for r in range(H):
        R = r // k
        for C in range(w):
            # a block's first row starts from its first cell (any dtype: integer codes too)
            m = data[r, C * k] if r % k == 0 else out[R, C]
            for c in range(C * k, min((C + 1) * k, W)):
                if data[r, c] > m:
                    m = data[r, c]
            out[R, C] = m
    if H % k:
        for C in range(w):
            out[h - 1, C] = max(out[h - 1, C], 0.0)
    if W % k:
        for R in range(h):
            out[R, w - 1] = max(out[R, w - 1], 0.0)
    return out


@numba.njit(cache=True)
def known_bounds(data, eps):
    """(r0, r1, c0, c1): the rows [r0, r1) and columns [c0, c1) that hold every cell with
    |value| > eps (`eps` of the grid's dtype); r1 == 0 when there is none."""
    H, W = data.shape
    r0, r1, c0, c1 = H, 0, W, 0
    for r in range(H):
        first = -1
        for c in range(W):
            if abs(data[r, c]) > eps:
                first = c
                break
        if first < 0:
            continue
        last = first
        for c in range(W - 1, first, -1):
            if abs(data[r, c]) > eps:
                last = c
                break
        r0 = min(r0, r)
        r1 = r + 1
        c0 = min(c0, first)
        c1 = max(c1, last + 1)
    return r0, r1, c0, c1


@numba.njit(cache=True, parallel=True)
def tiled_known_bounds(tab, pool, tile, eps):
    """`known_bounds` of the map a particle's tile table `tab` (TH, TW) of `pool` (cap, tile,
    tile) tiles describes, in the table's cells, reading only its written tiles (index 0 is
    the all-zero empty tile). Rows of tiles run in parallel, each into its own bounds. Within
    a tile, which of its rows and columns hold a known cell is gathered first (one flag per
    row, one per column: loops over a tile row the compiler vectorises), and the bounds are
    taken from those."""
    TH, TW = tab.shape
    rows0 = np.full(TH, TH * tile, dtype=np.int64)
    rows1 = np.zeros(TH, dtype=np.int64)
    cols0 = np.full(TH, TW * tile, dtype=np.int64)
    cols1 = np.zeros(TH, dtype=np.int64)
    for tr in numba.prange(TH):
        r0, r1, c0, c1 = TH * tile, 0, TW * tile, 0
        col_known = np.zeros(tile, dtype=np.bool_)
        for tc in range(TW):
            t = tab[tr, tc]
            if t == 0:
                continue
            col_known[:] = False
            first_row = -1
            last_row = -1
            for i in range(tile):
                row_known = False
                for j in range(tile):
                    known = abs(pool[t, i, j]) > eps
                    row_known |= known
                    col_known[j] |= known
                if row_known:
                    if first_row < 0:
                        first_row = i
                    last_row = i
            if first_row < 0:
                continue
            first_col = 0
            while not col_known[first_col]:
                first_col += 1
            last_col = tile - 1
            while not col_known[last_col]:
                last_col -= 1
            r0 = min(r0, tr * tile + first_row)
            r1 = max(r1, tr * tile + last_row + 1)
            c0 = min(c0, tc * tile + first_col)
            c1 = max(c1, tc * tile + last_col + 1)
        rows0[tr], rows1[tr], cols0[tr], cols1[tr] = r0, r1, c0, c1
    return rows0.min(), rows1.max(), cols0.min(), cols1.max()


def lowest_value(dtype: np.dtype) -> np.generic:
    """The least value of `dtype` (-inf for floats), as a scalar of that type: where a
    running max starts."""
    dtype = np.dtype(dtype)
    return dtype.type(-np.inf if dtype.kind == "f" else np.iinfo(dtype).min)


@numba.njit(cache=True, parallel=True)
def tiled_block_max(tab, pool, tile, r0, r1, c0, c1, k, lowest):
    """`block_max_1pass` of the table's cells [r0, r1) x [c0, c1) (as a dense image of the
    table, empty tiles reading 0), without gathering them. Per row of blocks, the k cell
    rows are first folded into one row of maxima (`line`: tile runs of each cell row, a loop
    the compiler vectorises; an empty tile's run takes 0), then each block's k columns of it
    are reduced once (a block is k x k cells: k times fewer short loops than reducing each
    cell row block by block). Rows of blocks run in parallel (each is one thread's alone; a
    max is order-free, so the result does not depend on the thread count). `lowest`: the pool
    dtype's least value (`lowest_value`), where each max starts."""
    h = (r1 - r0 + k - 1) // k
    w = (c1 - c0 + k - 1) // k
    out = np.empty((h, w), dtype=pool.dtype)
    for R in numba.prange(h):
        line = np.full(c1 - c0, lowest, dtype=pool.dtype)  # every cell of it gets a real value
        for r in range(r0 + R * k, min(r0 + (R + 1) * k, r1)):
            tr = r // tile
            i = r - tr * tile
            for tc in range(c0 // tile, (c1 - 1) // tile + 1):
                ca = max(c0, tc * tile)
                cb = min(c1, (tc + 1) * tile)
                t = tab[tr, tc]
                dst = line[ca - c0:cb - c0]
                if t == 0:
                    for q in range(cb - ca):
                        if dst[q] < 0:  # as block_max_1pass pads: a -0.0 stays as it is
                            dst[q] = 0
                else:
                    src = pool[t, i, ca - tc * tile:cb - tc * tile]
                    for q in range(cb - ca):
                        dst[q] = max(dst[q], src[q])
        for C in range(w):
            m = lowest
            for q in range(C * k, min((C + 1) * k, c1 - c0)):
                m = max(m, line[q])
            out[R, C] = m
    # blocks reaching past the box are padded with 0, as block_max_1pass
    if (r1 - r0) % k:
        for C in range(w):
            out[h - 1, C] = max(out[h - 1, C], 0)
    if (c1 - c0) % k:
        for R in range(h):
            out[R, w - 1] = max(out[R, w - 1], 0)
    return out
