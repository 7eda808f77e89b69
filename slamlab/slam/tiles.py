"""Sparse, copy-on-write occupancy maps: one log-odds grid (and likelihood field) per particle.

Why: a Rao-Blackwellised filter gives every particle its own map. Copying N full grids on
every resample is too slow and too big, so cells live in fixed square tiles of
`TILE` x `TILE` cells (32 x 32 = 1.6 m at 5 cm) held in one shared pool:

- `table[p, tr, tc]` is the pool index of particle p's tile at tile row tr, tile column tc;
  index 0 is the *empty tile* (all zeros, never written), so unexplored space costs nothing
  and a read never branches on "allocated?".
- A tile may be shared by many particles (after resampling, children share their parent's
  tiles). `refcount[t]` counts the table entries that point at tile t. A particle's first
  write into a tile it shares (or into the empty tile) copies that tile to a fresh one from
  the free list (copy on write); its siblings and parent keep the old tile. An update that
  leaves a cell's value as it is (free space already at the lower clamp, a wall at the
  upper one) is no write: well-mapped open space stays shared between particles.
- Resampling copies the small tables (N x tiles), never cells, and recounts references;
  tiles no particle points at any more go back to the free list.
- A matching read is two flat array lookups, `pool[table[p, r >> 5, c >> 5], r & 31, c & 31]`,
  inside the numba kernels (see `tiled_match.py`).

Memory therefore grows with the tiles the particles have actually changed (held once,
whatever the number of particles sharing them), not with particles x map area.

Cell (row r, col c) covers x in [origin_x + c*res, +res), y in [origin_y + r*res, +res); the
table grows by whole tiles when a scan would leave it (origin moves by whole tiles).

The likelihood field (a Gaussian of the distance to the nearest occupied cell, as
`grid.OccupancyGrid`) is kept per particle too, updated incrementally: a cell that becomes
occupied raises the field around it (max with the kernel); a cell that stops being occupied
has the field recomputed within the kernel radius. The result equals a full recomputation.
Field cells are one byte: every field value is one of the kernel's values (the kernel at the
nearest occupied cell, or 0), so a cell holds that value's rank among them (`field_codes`)
and readers decode it through `field_lut`; the ranks keep the values' order, so the
incremental max works on the codes, and a decoded read is the float32 a float field would
hold, bit for bit (a field tile is 1 KB instead of 4).

Log-odds cells are small integers too when the map's settings allow it (`log_odds_codes`):
with the default +0.85 / -0.4 updates and +-5 clamps every reachable value is a multiple of
0.05, so a cell holds that multiple in one signed byte (-100..100) and the updates add exact
integers (a log-odds tile is 1 KB instead of 4; float32 sums carried rounding errors instead).
Settings with no such common unit keep float32 tiles.
"""

from __future__ import annotations

import math
import mmap

import numba
import numpy as np

from slamlab.errors import ConfigError
from slamlab.frames import GridImage
from slamlab.geometry import FloatArray
from slamlab.slam.field_cells import value_codes
from slamlab.slam.grid import MapSettings
from slamlab.slam.raycast import field_radius_cells, gaussian_kernel, line_start, line_step

TILE_SHIFT = 5
TILE = 1 << TILE_SHIFT  # cells per tile side
TILE_MASK = TILE - 1
EMPTY = 0  # pool index of the shared all-zero tile


@numba.njit(cache=True, inline="always")
def tile_cell(pool, tab, r, c):
    """Cell (r, c) of the map whose tile table is `tab` (one particle's): a read through
    the table into `pool` (tiles, TILE, TILE)."""
    return pool[tab[r >> TILE_SHIFT, c >> TILE_SHIFT], r & TILE_MASK, c & TILE_MASK]


@numba.njit(cache=True, inline="always")
def _owned(ref, t):
    """Whether pool tile t belongs to one particle alone (writable in place): never the
    shared empty tile."""
    return t != EMPTY and ref[t] == 1


@numba.njit(cache=True, inline="always")
def _writable(table, p, tr, tc, pool_lo, pool_f, has_field, ref, free, rel, used):
    """Pool index of particle p's tile (tr, tc), made private to p (copied on write).

    A tile is p's own when `ref[t] == 1`; otherwise p takes the next tile of its own slice
    `free` of the free list (`used[0]` of them taken so far; the caller hands out enough) and
    copies the old tile into it, noting the old tile in `rel` at the same position. The old
    tiles' counts drop in the caller after the batch (`TiledMaps._release`), so particles
    updated in parallel never write the same counter."""
    t = table[p, tr, tc]
    if _owned(ref, t):
        return t
    if used[0] >= free.shape[0]:
        raise RuntimeError("tile budget of count_fresh_tiles exceeded (a bug)")
    nt = free[used[0]]
    rel[used[0]] = t  # the tile p let go of (EMPTY for a new one): its count drops after the batch
    used[0] += 1
    pool_lo[nt, :, :] = pool_lo[t, :, :]
    if has_field:
        pool_f[nt, :, :] = pool_f[t, :, :]
    ref[nt] = 1
    table[p, tr, tc] = nt
    return nt


@numba.njit(cache=True)
def tiled_raycast(table, p, pool_lo, pool_f, has_field, ref, free, rel, used,
                  r0, c0, rows, cols, l_occ, l_free, lmin, lmax, thresh, flips):
    """Ray-cast one scan into particle p's map: cells strictly before each end get `l_free`,
    end cells `l_occ` (all free updates first, as `raycast.raycast_update`), clamped to
    [lmin, lmax]. In a shared tile a cell the update leaves as it is (at a clamp) is not
    written, so the tile is copied only when one of its cells really changes (the particle's
    own tiles are written without looking). Cells whose `lo > thresh` state
    changes are appended to `flips` (K, 3: row, col, 1 = became occupied / 0 = became free);
    returns their count. Cells are given in table coordinates and must lie inside the table."""
    nflip = 0
    last_tr = -1
    last_tc = -1
    t = EMPTY
    own = False  # tile t is p's alone (writable in place)
    for k in range(rows.shape[0]):
        dr, dc, sr, sc, err, major_c, n = line_start(r0, c0, rows[k], cols[k])
        r = r0
        c = c0
        for _ in range(n):  # the line's cells without its end (`line_step`)
            tr = r >> TILE_SHIFT
            tc = c >> TILE_SHIFT
            if tr != last_tr or tc != last_tc:
                t = table[p, tr, tc]
                own = _owned(ref, t)
                last_tr = tr
                last_tc = tc
            ir = r & TILE_MASK
            ic = c & TILE_MASK
            old = pool_lo[t, ir, ic]
            new = max(old + l_free, lmin)
            if own:  # written even when unchanged: no branch on the cell's value (most cells)
                pool_lo[t, ir, ic] = new
            elif new != old:  # a cell already at the clamp changes nothing: its tile stays shared
                t = _writable(table, p, tr, tc, pool_lo, pool_f, has_field, ref, free, rel, used)
                own = True
                pool_lo[t, ir, ic] = new
            if old > thresh and not new > thresh:
                flips[nflip, 0] = r
                flips[nflip, 1] = c
                flips[nflip, 2] = 0
                nflip += 1
            r, c, err = line_step(r, c, err, dr, dc, sr, sc, major_c)
    for k in range(rows.shape[0]):
        r = rows[k]
        c = cols[k]
        t = table[p, r >> TILE_SHIFT, c >> TILE_SHIFT]
        ir = r & TILE_MASK
        ic = c & TILE_MASK
        old = pool_lo[t, ir, ic]
        new = old + l_occ
        if new > lmax:
            new = lmax
        if new != old:
            t = _writable(table, p, r >> TILE_SHIFT, c >> TILE_SHIFT, pool_lo, pool_f, has_field, ref, free, rel, used)
            pool_lo[t, ir, ic] = new
        if new > thresh and not old > thresh:
            flips[nflip, 0] = r
            flips[nflip, 1] = c
            flips[nflip, 2] = 1
            nflip += 1
    return nflip


@numba.njit(cache=True, inline="always")
def _max_into(dst, src):
    """dst = max(dst, src) element by element, over one row run (contiguous in both: a loop
    the compiler vectorises)."""
    for q in range(dst.shape[0]):
        dst[q] = max(dst[q], src[q])


@numba.njit(cache=True)
def _splat(table, p, pool_lo, pool_f, ref, free, rel, used, kernel, r, c, b0, b1, d0, d1):
    """Raise particle p's field to the kernel centred on cell (r, c), within rows [b0, b1)
    and cols [d0, d1). Tile by tile, so the copy-on-write check runs once per tile."""
    R = kernel.shape[0] // 2
    r_lo = max(r - R, b0)
    r_hi = min(r + R + 1, b1)
    c_lo = max(c - R, d0)
    c_hi = min(c + R + 1, d1)
    if r_lo >= r_hi or c_lo >= c_hi:
        return
    for tr in range(r_lo >> TILE_SHIFT, ((r_hi - 1) >> TILE_SHIFT) + 1):
        ra = max(r_lo, tr << TILE_SHIFT)
        rb = min(r_hi, (tr + 1) << TILE_SHIFT)
        for tc in range(c_lo >> TILE_SHIFT, ((c_hi - 1) >> TILE_SHIFT) + 1):
            ca = max(c_lo, tc << TILE_SHIFT)
            cb = min(c_hi, (tc + 1) << TILE_SHIFT)
            t = table[p, tr, tc]
            # the tile's rows [ra, rb) and cols [ca, cb), one contiguous run per row in both
            # the tile and the kernel (loops the compiler vectorises)
            i0 = ca & TILE_MASK
            k0 = ca - c + R
            n_c = cb - ca
            if not _owned(ref, t):
                # a shared tile is copied only when one of its values rises; the particle's
                # own tiles (the centre's always: its cell just changed) are raised unlooked
                raise_needed = False
                for rr in range(ra, rb):
                    dst = pool_f[t, rr & TILE_MASK, i0:i0 + n_c]
                    src = kernel[rr - r + R, k0:k0 + n_c]
                    for q in range(n_c):
                        if src[q] > dst[q]:
                            raise_needed = True
                    if raise_needed:
                        break
                if not raise_needed:
                    continue
                t = _writable(table, p, tr, tc, pool_lo, pool_f, True, ref, free, rel, used)
            for rr in range(ra, rb):
                _max_into(pool_f[t, rr & TILE_MASK, i0:i0 + n_c], kernel[rr - r + R, k0:k0 + n_c])


@numba.njit(cache=True)
def _recompute(table, p, pool_lo, pool_f, ref, free, rel, used, thresh, kernel, b0, b1, d0, d1):
    """Recompute particle p's field in rows [b0, b1), cols [d0, d1) from the occupied cells
    within the kernel radius of that box. A shared tile is copied (and written) only where a
    value changes, so tiles are copied only where the field really moved (near the freed
    cells); the particle's own tiles are written without looking."""
    H = table.shape[1] * TILE
    W = table.shape[2] * TILE
    R = kernel.shape[0] // 2
    new = np.zeros((b1 - b0, d1 - d0), dtype=kernel.dtype)
    w_lo = max(d0 - R, 0)
    w_hi = min(d1 + R, W)
    for r in range(max(b0 - R, 0), min(b1 + R, H)):
        # the window's row, one tile's run at a time (one table read per run, not per cell)
        a = w_lo
        while a < w_hi:
            e = min(w_hi, ((a >> TILE_SHIFT) + 1) << TILE_SHIFT)
            cells = pool_lo[table[p, r >> TILE_SHIFT, a >> TILE_SHIFT], r & TILE_MASK, a & TILE_MASK:((e - 1) & TILE_MASK) + 1]
            for q0 in range(e - a):
                if cells[q0] > thresh:
                    c = a + q0
                    c_lo = max(c - R, d0)
                    n_c = min(c + R + 1, d1) - c_lo
                    for rr in range(max(r - R, b0), min(r + R + 1, b1)):
                        _max_into(new[rr - b0, c_lo - d0:c_lo - d0 + n_c], kernel[rr - r + R, c_lo - c + R:c_lo - c + R + n_c])
            a = e
    for tr in range(b0 >> TILE_SHIFT, ((b1 - 1) >> TILE_SHIFT) + 1):
        for tc in range(d0 >> TILE_SHIFT, ((d1 - 1) >> TILE_SHIFT) + 1):
            t = table[p, tr, tc]
            ra = max(b0, tr << TILE_SHIFT)
            rb = min(b1, (tr + 1) << TILE_SHIFT)
            ca = max(d0, tc << TILE_SHIFT)
            cb = min(d1, (tc + 1) << TILE_SHIFT)
            i0 = ca & TILE_MASK
            n_c = cb - ca
            if not _owned(ref, t):
                # a shared tile is copied only when one of its values changes
                same = True
                for rr in range(ra, rb):
                    src = new[rr - b0, ca - d0:ca - d0 + n_c]
                    dst = pool_f[t, rr & TILE_MASK, i0:i0 + n_c]
                    for q in range(n_c):
                        if src[q] != dst[q]:
                            same = False
                    if not same:
                        break
                if same:
                    continue
                t = _writable(table, p, tr, tc, pool_lo, pool_f, True, ref, free, rel, used)
            for rr in range(ra, rb):  # the particle's own tile: written without looking
                src = new[rr - b0, ca - d0:ca - d0 + n_c]
                dst = pool_f[t, rr & TILE_MASK, i0:i0 + n_c]
                for q in range(n_c):
                    dst[q] = src[q]


@numba.njit(cache=True)
def tiled_field_update(table, p, pool_lo, pool_f, ref, free, rel, used, thresh, kernel, flips, nflip):
    """Bring particle p's likelihood field up to date after `tiled_raycast` changed the
    occupancy of the cells in `flips[:nflip]`. Around cells that became free the field is
    recomputed (neighbouring ones in one box) from the occupied cells within the kernel
    radius R; around a cell that became occupied it is raised to the kernel (max). Field
    values only exist inside the table."""
    H = table.shape[1] * TILE
    W = table.shape[2] * TILE
    R = kernel.shape[0] // 2
    # boxes of the cells that became free, merged while a flip lies within R of the box
    have = False
    b0 = 0
    b1 = 0
    d0 = 0
    d1 = 0
    for f in range(nflip + 1):
        if f < nflip:
            if flips[f, 2] != 0:
                continue
            r = flips[f, 0]
            c = flips[f, 1]
            if pool_lo[table[p, r >> TILE_SHIFT, c >> TILE_SHIFT], r & TILE_MASK, c & TILE_MASK] > thresh:
                # freed by one beam and hit again by another of this scan: the occupied set
                # did not change here, so the field around it stays as it is
                continue
            if have and b0 - R <= r < b1 + R and d0 - R <= c < d1 + R:
                b0 = min(b0, max(r - R, 0))
                b1 = max(b1, min(r + R + 1, H))
                d0 = min(d0, max(c - R, 0))
                d1 = max(d1, min(c + R + 1, W))
                continue
        if have:
            _recompute(table, p, pool_lo, pool_f, ref, free, rel, used, thresh, kernel, b0, b1, d0, d1)
            have = False
        if f < nflip:
            b0 = max(r - R, 0)
            b1 = min(r + R + 1, H)
            d0 = max(c - R, 0)
            d1 = min(c + R + 1, W)
            have = True
    for f in range(nflip):
        if flips[f, 2] == 0:
            continue
        r = flips[f, 0]
        c = flips[f, 1]
        # a cell may have flipped down and up in the same scan: only occupied ones raise
        if pool_lo[table[p, r >> TILE_SHIFT, c >> TILE_SHIFT], r & TILE_MASK, c & TILE_MASK] > thresh:
            _splat(table, p, pool_lo, pool_f, ref, free, rel, used, kernel, r, c, 0, H, 0, W)


@numba.njit(cache=True, parallel=True)
def count_fresh_tiles(table, ref, which, poses, pts, origin, ox, oy, inv_res, radius, out, marks, listed):
    """Upper bound of the fresh tiles each particle of `which` can take when the scan is
    ray-cast from its pose (written to `out[j]`): the tiles it does not own alone (empty or
    shared) among those within one tile of its beams, for a field kernel of `radius` cells
    (0: no field; at most 3/4 TILE - 2, as `TiledMaps` checks).

    Why that bounds every write: the cells the ray cast walks are within 1.5 cells of the
    beam (per axis), and field writes within `radius` cells of those. Each beam is sampled
    every 2 (TILE - 2 - radius) cells, so any point of it is within TILE - 2 - radius of a
    sample and every written cell within TILE - 0.5 cells of one: in the sample's tile or
    one of its 8 neighbours. Sparser samples could miss tiles; denser ones only cost time (at
    radius 6 they are 48 cells apart, a third of the samples half a tile apart took)."""
    TH = table.shape[1]
    TW = table.shape[2]
    spacing = 2.0 * (TILE - 2 - radius) / inv_res  # between samples (m)
    for j in numba.prange(which.shape[0]):
        i = which[j]
        # marks[j] (TH, TW) is all zero on entry and left so (only listed tiles are marked),
        # so a step costs its beams' samples, not a table-sized fill per particle
        mark = marks[j]
        x = poses[i, 0]
        y = poses[i, 1]
        c = math.cos(poses[i, 2])
        s = math.sin(poses[i, 2])
        sx = x + c * origin[0] - s * origin[1]
        sy = y + s * origin[0] + c * origin[1]
        # 1. list the tiles the beams' samples fall in, each once (mark 1) ...
        lst = listed[j]  # tile row * TW + tile column
        nl = 0
        for k in range(pts.shape[0]):
            ex = x + c * pts[k, 0] - s * pts[k, 1]
            ey = y + s * pts[k, 0] + c * pts[k, 1]
            length = math.sqrt((ex - sx) ** 2 + (ey - sy) ** 2)
            steps = int(math.ceil(length / spacing))
            for q in range(steps + 1):
                f = q / steps if steps > 0 else 0.0
                px = sx + f * (ex - sx)
                py = sy + f * (ey - sy)
                tr = min(max(int(math.floor((py - oy) * inv_res)) >> TILE_SHIFT, 0), TH - 1)
                tc = min(max(int(math.floor((px - ox) * inv_res)) >> TILE_SHIFT, 0), TW - 1)
                if mark[tr, tc] == 0:
                    mark[tr, tc] = 1
                    lst[nl] = tr * TW + tc
                    nl += 1
        # ... 2. then count each tile of their 3 x 3 blocks once (mark 2) that p does not own
        # alone: one mark read per sample and nine per listed tile, not nine per sample
        n = 0
        for h in range(nl):
            tr = lst[h] // TW
            tc = lst[h] % TW
            for a in range(max(tr - 1, 0), min(tr + 2, TH)):
                for b in range(max(tc - 1, 0), min(tc + 2, TW)):
                    if mark[a, b] != 2:
                        mark[a, b] = 2
                        t = table[i, a, b]
                        if t == EMPTY or ref[t] != 1:
                            n += 1
        out[j] = n
        # 3. clear what was marked: the listed tiles' 3 x 3 blocks
        for h in range(nl):
            tr = lst[h] // TW
            tc = lst[h] % TW
            for a in range(max(tr - 1, 0), min(tr + 2, TH)):
                for b in range(max(tc - 1, 0), min(tc + 2, TW)):
                    mark[a, b] = 0


@numba.njit(cache=True, parallel=True)
def insert_scans(table, pool_lo, pool_f, has_field, ref, free, released, starts, used, which, poses, pts, origin,
                 ox, oy, inv_res, l_occ, l_free, lmin, lmax, thresh, kernel, rows, cols, flips):
    """Ray-cast one scan (`pts` (M, 2) and lidar `origin` (2,), body-yaw frame, m) into the
    maps of particles `which`, each from its own pose `poses[i]`, and update their fields.
    Particles run in parallel; particle j of `which` takes fresh tiles only from its slice
    `free[starts[j]:starts[j + 1]]`, counts them in `used[j]` and notes the tiles they replace
    at the same positions of `released`. `rows`, `cols` (len(which), M) and `flips`
    (len(which), K, 3) are scratch space."""
    for j in numba.prange(which.shape[0]):
        i = which[j]
        x = poses[i, 0]
        y = poses[i, 1]
        c = math.cos(poses[i, 2])
        s = math.sin(poses[i, 2])
        for k in range(pts.shape[0]):
            wx = x + c * pts[k, 0] - s * pts[k, 1]
            wy = y + s * pts[k, 0] + c * pts[k, 1]
            cols[j, k] = int(math.floor((wx - ox) * inv_res))
            rows[j, k] = int(math.floor((wy - oy) * inv_res))
        sx = x + c * origin[0] - s * origin[1]
        sy = y + s * origin[0] + c * origin[1]
        sc = int(math.floor((sx - ox) * inv_res))
        sr = int(math.floor((sy - oy) * inv_res))
        mine = free[starts[j]:starts[j + 1]]
        mine_rel = released[starts[j]:starts[j + 1]]
        nflip = tiled_raycast(table, i, pool_lo, pool_f, has_field, ref, mine, mine_rel, used[j:j + 1],
                              sr, sc, rows[j], cols[j], l_occ, l_free, lmin, lmax, thresh, flips[j])
        if has_field and nflip > 0:
            tiled_field_update(table, i, pool_lo, pool_f, ref, mine, mine_rel, used[j:j + 1], thresh, kernel, flips[j], nflip)


@numba.njit(cache=True)
def release_taken_tiles(starts, used, released, ref, free_buf, lo):
    """The free list's bookkeeping after `insert_scans` (`TiledMaps._release`); returns the
    list's new start. Particle j was handed `free_buf[lo + starts[j]:lo + starts[j + 1]]`,
    took the first `used[j]` of them and let go of the tiles noted at the same positions of
    `released`. Each let-go tile loses a reference; the list becomes [freed, untaken, rest]:
    the tiles whose count reached zero (ascending) first, so they are reused before pool
    memory never touched yet and the pool's resident pages stay close to the tiles in use,
    then the handed-out tiles nobody took, in their order. Both fit in the handed-out prefix
    (each taken tile lets go of at most one), so only that prefix is rewritten."""
    total = starts[-1]
    freed = np.empty(total, dtype=np.int32)
    untaken = np.empty(total, dtype=np.int32)
    n_freed = 0
    n_untaken = 0
    for j in range(used.shape[0]):
        for q in range(starts[j], starts[j + 1]):
            if q - starts[j] < used[j]:
                t = released[q]
                if t != EMPTY:
                    ref[t] -= 1
                    if ref[t] == 0:  # reaches zero once: listed once
                        freed[n_freed] = t
                        n_freed += 1
            else:
                untaken[n_untaken] = free_buf[lo + q]
                n_untaken += 1
    freed = np.sort(freed[:n_freed])
    new_lo = lo + total - n_freed - n_untaken
    free_buf[new_lo:new_lo + n_freed] = freed
    free_buf[new_lo + n_freed:lo + total] = untaken[:n_untaken]
    return new_lo


def _anonymous_map(nbytes: int) -> mmap.mmap:
    """Private anonymous memory (zero-filled; private, because a shared anonymous map cannot
    grow: pages past its first size raise SIGBUS)."""
    private = getattr(mmap, "MAP_PRIVATE", None)
    if private is None:  # Windows: no flags (its maps are not resized in place anyway)
        return mmap.mmap(-1, nbytes)
    return mmap.mmap(-1, nbytes, flags=private | mmap.MAP_ANONYMOUS)


def log_odds_codes(settings: MapSettings) -> tuple[np.dtype, float]:
    """(dtype, unit of log-odds) of the log-odds tiles: the smallest signed integer type whose codes,
    in units of the largest `unit` that divides the updates, clamps and threshold exactly,
    cover the clamps; (float32, 1.0) when no such unit fits in 16 bits (values then stored
    as they are)."""
    s = settings
    values = np.array([s.log_odds_occupied, s.log_odds_free, s.clamp_min, s.clamp_max, s.occupied_threshold], dtype=np.float64)
    bound = max(-s.clamp_min, s.clamp_max)
    for dtype in (np.int8, np.int16):
        n = np.arange(1, int(np.iinfo(dtype).max) + 1, dtype=np.float64)[:, None]
        q = values * (n / bound)  # row n-1: the values in units of bound / n
        # exact up to float64 rounding of decimal settings (0.85 / 0.05 = 16.999999999999996)
        whole = np.all(np.abs(q - np.round(q)) < 1e-9 * np.maximum(1.0, np.abs(q)), axis=1)
        if whole.any():
            return np.dtype(dtype), bound / float(n[np.argmax(whole), 0])
    return np.dtype(np.float32), 1.0


def field_codes(kernel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One-byte codes for a float32 field kernel: (codes uint8 like `kernel`, lut float32)
    with lut[codes] == kernel, lut sorted ascending and lut[0] == 0 (the empty tile)."""
    codes, lut = value_codes(kernel)
    if codes.dtype != np.uint8:
        raise ConfigError("matcher.radius_m", f"the field kernel has {len(lut)} distinct values; at most 256 fit the one-byte field tiles")
    return codes, lut


def decode_codes(codes: np.ndarray, unit: float) -> np.ndarray:
    """Log-odds (float32) of log-odds cell codes in units of `unit` (float32 codes with unit
    1.0 are log-odds already and come back as they are)."""
    if codes.dtype == np.float32 and unit == 1.0:
        return codes
    return (codes * unit).astype(np.float32)


def decode_image(image: GridImage, unit: float, band_rows: int = 1024) -> GridImage:
    """`image` of log-odds codes (`TiledMaps.to_image(p, decoded=False)`) as float32
    log-odds, decoded a band of rows at a time (a whole-map float64 product of a building's
    map would take 0.5 GB)."""
    if image.data.dtype == np.float32 and unit == 1.0:
        return image
    data = np.empty(image.data.shape, dtype=np.float32)
    for r in range(0, data.shape[0], band_rows):
        data[r:r + band_rows] = decode_codes(image.data[r:r + band_rows], unit)
    return GridImage(data=data, resolution_m=image.resolution_m, origin_xy=image.origin_xy)


class _TilePool:
    """`array` (capacity, TILE, TILE) tiles of `dtype` in an anonymous memory map (zero-filled).

    Why a map: `grow` resizes it in place (mremap on Linux moves page tables, not bytes), so a
    growing pool is never held twice; a pool of 2 GB of tiles used to peak at 4 GB while a
    doubled copy was filled. Where a map cannot be resized (other platforms, or a view of the
    array still held elsewhere) it falls back to a copy into a new map."""

    def __init__(self, capacity: int, dtype: type = np.float32) -> None:
        self.dtype = np.dtype(dtype)
        self.tile_bytes = TILE * TILE * self.dtype.itemsize
        self._mm = _anonymous_map(capacity * self.tile_bytes)
        self.array = self._view()
        self.copies = 0  # growths that had to copy (tests; 0 on Linux in a run)

    def _view(self) -> np.ndarray:
        return np.frombuffer(self._mm, dtype=self.dtype).reshape(-1, TILE, TILE)

    def grow(self, capacity: int) -> None:
        old_tiles = self.array.shape[0]
        self.array = None  # our own view of the map must go before it can be resized
        try:
            self._mm.resize(capacity * self.tile_bytes)
        except (BufferError, OSError, SystemError, ValueError):
            old = np.frombuffer(self._mm, dtype=self.dtype).reshape(-1, TILE, TILE)
            mm = _anonymous_map(capacity * self.tile_bytes)
            np.frombuffer(mm, dtype=self.dtype).reshape(-1, TILE, TILE)[:old_tiles] = old
            self._mm = mm
            self.copies += 1
        self.array = self._view()


class TiledMaps:
    """N particle maps in shared copy-on-write tiles (see module doc).

    `field_sigma_m` > 0 keeps a likelihood field per particle (values in [0, 1], as
    `grid.OccupancyGrid`; stored as one-byte codes, read as `field_lut[code]`). All maps
    start empty, centred at `center_xy` (m)."""

    def __init__(
        self,
        settings: MapSettings,
        n_maps: int,
        center_xy: tuple[float, float] = (0.0, 0.0),
        field_sigma_m: float = 0.0,
        field_radius_m: float = 0.0,
        initial_tiles: int = 256,
    ) -> None:
        self.s = settings
        if settings.occupied_threshold < 0:
            # unknown cells (log-odds 0, the empty tile) must read as free: the shared empty
            # tile and the incremental field rely on it
            raise ConfigError("map.occupied_threshold", f"must be >= 0 with filter=rbpf, got {settings.occupied_threshold:g}")
        self.res = settings.resolution_m
        self.n = int(n_maps)
        side = max(int(np.ceil(settings.initial_size_m / (self.res * TILE))), 1)
        self.origin = np.array([center_xy[0] - side * TILE * self.res / 2.0, center_xy[1] - side * TILE * self.res / 2.0])
        self.table = np.zeros((self.n, side, side), dtype=np.int32)
        self.has_field = field_sigma_m > 0
        # the field kernel as codes (what the update kernels write) and the codes' values
        self.kernel = np.zeros((1, 1), dtype=np.uint8)
        self.field_lut = np.zeros(1, dtype=np.float32)
        if self.has_field:
            radius = field_radius_cells(field_sigma_m, field_radius_m, self.res)
            if radius + 1 >= (3 * TILE) // 4:
                raise ConfigError("matcher.radius_m (or sigma_m)", f"must stay below {(3 * TILE) // 4 - 1} cells ({((3 * TILE) // 4 - 1) * self.res:g} m) at this resolution")
            self.kernel, self.field_lut = field_codes(gaussian_kernel(field_sigma_m / self.res, radius))
        # log-odds cells as integer codes of `lo_unit` where the settings allow (module doc)
        self.lo_dtype, self.lo_unit = log_odds_codes(settings)
        cap = max(int(initial_tiles), 2)
        self._pools = {"lo": _TilePool(cap, self.lo_dtype), "f": _TilePool(cap if self.has_field else 1, np.uint8)}
        self.ref = np.zeros(cap, dtype=np.int32)
        # the free list (tile ids no table refers to, not 0) is `_free_buf[_free_lo:]`: taking
        # tiles from its front and putting some back moves `_free_lo`, not the whole list
        self._free_buf = np.arange(1, cap, dtype=np.int32)
        self._free_lo = 0
        self.peak_tiles = 0
        self.tiles_taken = 0  # fresh tiles taken: copies of shared tiles or new ones
        # scratch of insert_scan: cells (2, particles, points) and flips (particles, K, 3)
        self._rc = np.empty((2, 0, 0), dtype=np.int64)
        self._fl = np.empty((0, 0, 3), dtype=np.int64)
        self._mark = np.zeros((0, 0, 0), dtype=np.uint8)
        self._listed = np.empty((0, 0), dtype=np.int32)
        self.grow_count = 0

    # ---- geometry -----------------------------------------------------------------------
    @property
    def shape(self) -> tuple[int, int]:
        """Cells (rows, cols) covered by the table."""
        return self.table.shape[1] * TILE, self.table.shape[2] * TILE

    def ensure(self, xmin: float, ymin: float, xmax: float, ymax: float) -> None:
        """Grow every table by whole tiles (plus `growth_margin_m`) so the box (m) fits with
        one kernel radius to spare. Only the small tables are copied, never cells."""
        H, W = self.shape
        R = self.kernel.shape[0] // 2 + 1
        m = int(np.ceil(self.s.growth_margin_m / (self.res * TILE)))
        lo_c = int(np.floor((xmin - self.origin[0]) / self.res)) - R
        lo_r = int(np.floor((ymin - self.origin[1]) / self.res)) - R
        hi_c = int(np.floor((xmax - self.origin[0]) / self.res)) + R
        hi_r = int(np.floor((ymax - self.origin[1]) / self.res)) + R
        pad_l = (-lo_c + TILE - 1) // TILE + m if lo_c < 0 else 0
        pad_b = (-lo_r + TILE - 1) // TILE + m if lo_r < 0 else 0
        pad_r = (hi_c - W) // TILE + 1 + m if hi_c >= W else 0
        pad_t = (hi_r - H) // TILE + 1 + m if hi_r >= H else 0
        if pad_l == pad_b == pad_r == pad_t == 0:
            return
        self.table = np.pad(self.table, ((0, 0), (pad_b, pad_t), (pad_l, pad_r)))
        self.origin = self.origin - np.array([pad_l, pad_b]) * TILE * self.res
        self.grow_count += 1

    # ---- tile pool ----------------------------------------------------------------------
    @property
    def pool_lo(self) -> np.ndarray:
        """(capacity, TILE, TILE) log-odds tiles (index EMPTY: all zero), in codes of
        `lo_dtype`: a cell's log-odds is its code times `lo_unit`."""
        return self._pools["lo"].array

    def lo_code(self, value: float) -> np.generic:
        """A log-odds value (one of the settings') as a cell code of `lo_dtype`."""
        if self.lo_dtype == np.float32:
            return np.float32(value)
        return self.lo_dtype.type(round(value / self.lo_unit))

    def decode(self, codes: np.ndarray) -> np.ndarray:
        """Log-odds (float32) of cell codes."""
        return decode_codes(codes, self.lo_unit)

    @property
    def pool_f(self) -> np.ndarray:
        """Likelihood-field tiles, as `pool_lo` but uint8 codes of `field_lut` (one unused tile
        without a field)."""
        return self._pools["f"].array

    @property
    def free(self) -> np.ndarray:
        """The free list: tile ids no table refers to, the next one to take first."""
        return self._free_buf[self._free_lo:]

    def _set_free(self, ids: np.ndarray) -> None:
        self._free_buf = np.ascontiguousarray(ids, dtype=np.int32)
        self._free_lo = 0

    @property
    def tiles_in_use(self) -> int:
        """Distinct tiles held (shared tiles count once; the empty tile not at all)."""
        return int(len(self.ref) - 1 - len(self.free))

    def _reserve(self, n_tiles: int) -> None:
        """Make sure at least `n_tiles` tiles are free (the kernels cannot allocate)."""
        if len(self.free) >= n_tiles:
            return
        cap = len(self.ref)
        new_cap = max(2 * cap, cap + n_tiles - len(self.free))
        # the pools grow in place (`_TilePool`); new tiles are untouched memory until taken
        self._pools["lo"].grow(new_cap)
        if self.has_field:
            self._pools["f"].grow(new_cap)
        self.ref = np.concatenate([self.ref, np.zeros(new_cap - cap, dtype=np.int32)])
        self._set_free(np.concatenate([self.free, np.arange(cap, new_cap, dtype=np.int32)]))

    def insert_scan(self, poses: FloatArray, scan_xy: FloatArray, scan_origin: FloatArray, which: np.ndarray | None = None) -> None:
        """Ray-cast one scan into the maps of particles `which` (default: all), each from
        its own pose `poses[i]` (x m, y m, yaw rad). `scan_xy` (M, 2) are the scan points
        and `scan_origin` (2,) the lidar centre, in the body-yaw frame (m)."""
        if len(scan_xy) == 0:
            return
        if which is None:
            which = np.arange(self.n, dtype=np.int64)
        else:
            which = np.asarray(which, dtype=np.int64)
            # a particle listed twice would be written by two threads at once
            assert len(np.unique(which)) == len(which), "insert_scan: repeated particle index"
        poses = np.ascontiguousarray(poses, dtype=np.float64)
        pts = np.ascontiguousarray(scan_xy, dtype=np.float64)
        origin = np.ascontiguousarray(scan_origin, dtype=np.float64)
        # the scan's box in the body frame, rotated by any yaw, fits in a disc of radius rmax
        body = np.vstack([pts, origin])
        rmax = float(np.sqrt((body**2).sum(axis=1)).max())
        px, py = poses[which, 0], poses[which, 1]
        self.ensure(px.min() - rmax, py.min() - rmax, px.max() + rmax, py.max() + rmax)
        x0, y0, inv = float(self.origin[0]), float(self.origin[1]), 1.0 / self.res
        need = np.zeros(len(which), dtype=np.int64)
        marks, listed = self._marks(len(which))
        count_fresh_tiles(self.table, self.ref, which, poses, pts, origin, x0, y0, inv, self.kernel.shape[0] // 2, need, marks, listed)
        starts = np.concatenate([[0], np.cumsum(need)]).astype(np.int64)
        self._reserve(int(starts[-1]))
        used = np.zeros(len(which), dtype=np.int64)
        released = np.empty(int(starts[-1]), dtype=np.int32)  # the tiles each fresh one replaces
        # each cell flips at most once down (free pass) and once up (hit pass); a beam walks
        # at most its length in cells + 2 (rounding at both ends)
        n_flips = int(np.ceil(np.sqrt(((pts - origin) ** 2).sum(axis=1)) / self.res).sum()) + 3 * len(pts)
        rows, cols, flips = self._scratch(len(which), len(pts), n_flips)
        s = self.s
        insert_scans(
            self.table, self.pool_lo, self.pool_f, self.has_field, self.ref, self.free, released, starts, used, which, poses, pts, origin,
            x0, y0, inv,
            self.lo_code(s.log_odds_occupied), self.lo_code(s.log_odds_free), self.lo_code(s.clamp_min),
            self.lo_code(s.clamp_max), self.lo_code(s.occupied_threshold), self.kernel, rows, cols, flips,
        )
        # peak: before `_release` frees the tiles the copies replaced, both are held
        self.peak_tiles = max(self.peak_tiles, self.tiles_in_use + int(used.sum()))
        self.tiles_taken += int(used.sum())
        self._release(starts, used, released)

    def _release(self, starts: np.ndarray, used: np.ndarray, released: np.ndarray) -> None:
        """After `insert_scans`: the fresh tiles taken leave the free list, and the tiles they
        replaced lose one reference each (returning to the free list at zero). The same counts
        a full `_recount` over the tables gives, without reading the tables
        (`release_taken_tiles`, one kernel call: ~10 NumPy calls a step before)."""
        self._free_lo = int(release_taken_tiles(starts, used, released, self.ref, self._free_buf, self._free_lo))

    def _marks(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """`count_fresh_tiles`' per-particle tile marks (n, TH, TW), all zero between calls,
        and tile lists (n, TH * TW); remade when the table grows."""
        shape = (n,) + self.table.shape[1:]
        if self._mark.shape != shape:
            self._mark = np.zeros(shape, dtype=np.uint8)
            self._listed = np.empty((n, shape[1] * shape[2]), dtype=np.int32)
        return self._mark, self._listed

    def _scratch(self, n: int, m: int, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Reused work arrays for `insert_scans` (grown, never shrunk)."""
        if self._rc.shape[1] < n or self._rc.shape[2] < m:
            self._rc = np.empty((2, n, m), dtype=np.int64)
        if self._fl.shape[0] < n or self._fl.shape[1] < k:
            self._fl = np.empty((n, max(k, 2 * self._fl.shape[1]), 3), dtype=np.int64)
        return self._rc[0, :n, :m], self._rc[1, :n, :m], self._fl[:n]

    def share_all_from(self, p: int) -> None:
        """Every particle takes particle p's map (shared tiles, no cell copied)."""
        self.resample(np.full(self.n, p, dtype=np.int64))

    def resample(self, idx: np.ndarray) -> None:
        """Particle j takes the map of old particle idx[j]: tables are copied, tiles shared;
        tiles nobody refers to any more return to the free list."""
        self.table = np.ascontiguousarray(self.table[np.asarray(idx)])
        self._recount()

    def _recount(self) -> None:
        ref = np.bincount(self.table.ravel(), minlength=len(self.ref)).astype(np.int32)
        ref[EMPTY] = 0
        self.ref = ref
        self._set_free(np.flatnonzero(ref[1:] == 0).astype(np.int32) + 1)

    # ---- reading ------------------------------------------------------------------------
    def bytes_per_tile(self) -> int:
        """Bytes of one tile position: its log-odds tile plus, with a field, its field tile."""
        return self._pools["lo"].tile_bytes + (self._pools["f"].tile_bytes if self.has_field else 0)

    def memory_mb(self, tiles: int | None = None) -> float:
        """MB held by the maps: distinct tiles (shared ones once) plus the tables."""
        n = self.tiles_in_use if tiles is None else tiles
        return (n * self.bytes_per_tile() + self.table.nbytes) / 1e6

    def dense(self, p: int, which: str = "log_odds") -> np.ndarray:
        """Particle p's whole table area as one float32 array [H, W] (tests, small maps);
        `which="field"` decodes the field's codes."""
        pool = self.pool_lo if which == "log_odds" else self.pool_f
        cells = pool[self.table[p]].transpose(0, 2, 1, 3).reshape(self.shape)
        return self.decode(cells) if which == "log_odds" else self.field_lut[cells]

    def written_tiles(self, p: int) -> tuple[tuple[int, int, int, int], tuple[float, float]]:
        """The box of tiles particle p has written, (tile rows [r0, r1), cols [c0, c1)) (the
        first tile when none), and the world position (m) of its first cell's corner: the
        crop of `to_image` and of the replay's snapshots."""
        rr, cc = np.nonzero(self.table[p] != EMPTY)
        if len(rr) == 0:
            rr, cc = np.array([0]), np.array([0])
        r0, r1, c0, c1 = int(rr.min()), int(rr.max()) + 1, int(cc.min()), int(cc.max()) + 1
        origin = (float(self.origin[0] + c0 * TILE * self.res), float(self.origin[1] + r0 * TILE * self.res))
        return (r0, r1, c0, c1), origin

    def to_image(self, p: int, decoded: bool = True) -> GridImage:
        """Particle p's log-odds map, cropped to the tiles it has written (float32 GridImage;
        with `decoded=False` its cell codes, `lo_dtype`, a quarter of the size for int8)."""
        tab = self.table[p]
        (r0, r1, c0, c1), origin = self.written_tiles(p)
        tw = c1 - c0
        data = np.empty(((r1 - r0) * TILE, tw * TILE), dtype=np.float32 if decoded else self.lo_dtype)
        pool = self.pool_lo
        for i in range(r1 - r0):
            # one band of tiles at a time: a whole-map gather plus its transposed copy would
            # hold the map twice more (0.5 GB for a 570 x 290 m building at 5 cm)
            band = pool[tab[r0 + i, c0:c1]]  # (tw, T, T)
            if decoded:
                band = self.decode(band)
            data[i * TILE:(i + 1) * TILE] = band.transpose(1, 0, 2).reshape(TILE, tw * TILE)
        return GridImage(data=data, resolution_m=self.res, origin_xy=origin)
