"""Scan matching against per-particle tiled maps (`tiles.TiledMaps`), for the RBPF.

The same two searches as `matcher.py` (hit counting over an offset grid; likelihood field
with a coarse grid and hill climbing), but pose i reads its own map through its tile table
(a filter step: particle i's map; the scans between steps: all the best particle's): a cell
read is `pool[table[i, r >> 5, c >> 5], r & 31, c & 31]` (a field cell is a one-byte code,
decoded as `lut[code]`: see `tiles.py`). Particles are
independent, so the outer loop runs on all cores (`numba.prange`); each particle's result
depends only on its own inputs, so results do not depend on the number of threads.

Point layouts: the likelihood-field scores take a scan's points as two rows, x and y
(`pts_t`, 2 x M; `place_points` says why), and `tiled_field_search` transposes each pose's
(M, 2) points once; hit counting (`tiled_score_hits`) and Gauss-Newton (`gauss_newton`) read
(M, 2) rows.

The dense kernels in `matcher.py` stay for the shared-map (course) filter, whose trajectories
must not change bit for bit.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from slamlab.slam.gauss_newton import NO_FIELD, refine_pose
from slamlab.slam.raycast import field_place
from slamlab.slam.tiles import TILE_MASK, TILE_SHIFT, tile_cell


@numba.njit(cache=True)
def tiled_score_hits(pool_lo, tab, thresh, ox, oy, inv_res, x, y, th, pts):
    """Number of points (M, 2, body-yaw frame) on occupied cells of the map `tab` (one
    particle's table) when the body is at (x, y, th)."""
    H = tab.shape[0] << TILE_SHIFT
    W = tab.shape[1] << TILE_SHIFT
    c = math.cos(th)
    s = math.sin(th)
    total = 0.0
    for i in range(pts.shape[0]):
        wx = x + c * pts[i, 0] - s * pts[i, 1]
        wy = y + s * pts[i, 0] + c * pts[i, 1]
        col = int(math.floor((wx - ox) * inv_res))
        row = int(math.floor((wy - oy) * inv_res))
        if 0 <= row < H and 0 <= col < W and tile_cell(pool_lo, tab, row, col) > thresh:
            total += 1.0
    return total


@numba.njit(cache=True)
def tiled_score_field(pool_f, lut, tab, ox, oy, inv_res, x, y, th, pts_t, work):
    """Sum of the likelihood field (bilinear between cell centres) at the points `pts_t`
    (2, M: their x and y as two rows, body-yaw frame; see `place_points`).

    Two passes: the points' places first (`place_points`, arithmetic alone, which the
    compiler vectorises), then the reads, summed in the points' order. `work` (4, >= M) is
    scratch. About 8 % off the field search (dumped Intel steps) against placing and reading
    each point in turn, with the same sum to the bit."""
    H = tab.shape[0] << TILE_SHIFT
    W = tab.shape[1] << TILE_SHIFT
    m = pts_t.shape[1]
    if pts_t.shape[0] != 2 or work.shape[0] < 4 or work.shape[1] < m:  # numba does not check bounds
        raise ValueError("tiled_score_field: pts_t must be (2, M) and work (4, >= M)")
    place_points(x, y, th, pts_t, ox, oy, inv_res, work)
    total = 0.0
    for i in range(m):
        c0 = int(work[0, i])
        r0 = int(work[1, i])
        if c0 < 0 or r0 < 0 or c0 + 1 >= W or r0 + 1 >= H:
            continue
        fu = work[2, i]
        fv = work[3, i]
        ir = r0 & TILE_MASK
        ic = c0 & TILE_MASK
        if ir != TILE_MASK and ic != TILE_MASK:  # the 2 x 2 cells lie in one tile (31 times in 32)
            t = tab[r0 >> TILE_SHIFT, c0 >> TILE_SHIFT]
            f00 = lut[pool_f[t, ir, ic]]
            f01 = lut[pool_f[t, ir, ic + 1]]
            f10 = lut[pool_f[t, ir + 1, ic]]
            f11 = lut[pool_f[t, ir + 1, ic + 1]]
        else:
            f00 = lut[tile_cell(pool_f, tab, r0, c0)]
            f01 = lut[tile_cell(pool_f, tab, r0, c0 + 1)]
            f10 = lut[tile_cell(pool_f, tab, r0 + 1, c0)]
            f11 = lut[tile_cell(pool_f, tab, r0 + 1, c0 + 1)]
        total += (1.0 - fv) * ((1.0 - fu) * f00 + fu * f01) + fv * ((1.0 - fu) * f10 + fu * f11)
    return total


@numba.njit(cache=True)
def place_points(x, y, th, pts_t, ox, oy, inv_res, work):
    """Where the points fall with the body at (x, y, th), as `field_place` puts them:
    work[0] / work[1] the cell column / row of the bilinear read's first cell (floor of u / v,
    as floats), work[2] / work[3] the fractions u - floor(u) and v - floor(v).

    The points come as two rows, x and y (`pts_t`, 2 x M, body-yaw frame), not as M rows of
    (x, y): from rows the compiler vectorises this loop, from (M, 2) it does not (one point's x
    and y sit side by side). 3.3 -> 0.7-0.9 ns a point, the same bits (the same operations)."""
    c = math.cos(th)
    s = math.sin(th)
    for i in range(pts_t.shape[1]):
        _, _, u, v = field_place(x, y, c, s, pts_t[0, i], pts_t[1, i], ox, oy, inv_res)
        fc = math.floor(u)
        fr = math.floor(v)
        work[0, i] = fc
        work[1, i] = fr
        work[2, i] = u - fc
        work[3, i] = v - fr


@numba.njit(cache=True, inline="always")
def _field_at(pool_f, lut, tab, H, W, u, v):
    """The field bilinear at (u, v) (cells, centres at integers); 0 off the map."""
    c0 = int(math.floor(u))
    r0 = int(math.floor(v))
    if c0 < 0 or r0 < 0 or c0 + 1 >= W or r0 + 1 >= H:
        return 0.0
    fu = u - c0
    fv = v - r0
    f00 = lut[tile_cell(pool_f, tab, r0, c0)]
    f01 = lut[tile_cell(pool_f, tab, r0, c0 + 1)]
    f10 = lut[tile_cell(pool_f, tab, r0 + 1, c0)]
    f11 = lut[tile_cell(pool_f, tab, r0 + 1, c0 + 1)]
    return (1.0 - fv) * ((1.0 - fu) * f00 + fu * f01) + fv * ((1.0 - fu) * f10 + fu * f11)


@numba.njit(cache=True)
def tiled_score_stretches(pool_f, lut, tab, ox, oy, inv_res, x, y, th, pts_t, ext):
    """`tiled_score_field` (points `pts_t` as two rows, x and y), except that a point with a
    stretch (`matcher.surface_stretches`: ext[i] = (ux, uy, n_before, n_after, step_before,
    step_after)) scores the largest field value at samples along its stretch of surface."""
    H = tab.shape[0] << TILE_SHIFT
    W = tab.shape[1] << TILE_SHIFT
    c = math.cos(th)
    s = math.sin(th)
    total = 0.0
    for i in range(pts_t.shape[1]):
        u = (x + c * pts_t[0, i] - s * pts_t[1, i] - ox) * inv_res - 0.5
        v = (y + s * pts_t[0, i] + c * pts_t[1, i] - oy) * inv_res - 0.5
        best = _field_at(pool_f, lut, tab, H, W, u, v)
        if ext[i, 2] > 0 or ext[i, 3] > 0:
            du = (c * ext[i, 0] - s * ext[i, 1]) * inv_res  # the stretch's direction in cells
            dv = (s * ext[i, 0] + c * ext[i, 1]) * inv_res
            for j in range(1, int(ext[i, 2]) + 1):
                best = max(best, _field_at(pool_f, lut, tab, H, W, u - j * ext[i, 4] * du, v - j * ext[i, 4] * dv))
            for j in range(1, int(ext[i, 3]) + 1):
                best = max(best, _field_at(pool_f, lut, tab, H, W, u + j * ext[i, 5] * du, v + j * ext[i, 5] * dv))
        total += best
    return total


@numba.njit(cache=True)
def _score_fine(pool_f, lut, tab, ox, oy, inv_res, x, y, th, pts_t, ext, work):
    """The hill climb's score: `tiled_score_stretches` when `ext` has a row per point, else `tiled_score_field`."""
    if ext.shape[0] == pts_t.shape[1] and ext.shape[0] > 0:
        return tiled_score_stretches(pool_f, lut, tab, ox, oy, inv_res, x, y, th, pts_t, ext)
    return tiled_score_field(pool_f, lut, tab, ox, oy, inv_res, x, y, th, pts_t, work)


@numba.njit(cache=True, parallel=True)
def tiled_grid_search(pool_lo, table, thresh, ox, oy, inv_res, poses, pts, offsets, out_poses, out_scores):
    """Per particle i (its map `table[i]`), the offset with the most hits (earlier offsets
    win ties, as `matcher.grid_search_hits`)."""
    for i in numba.prange(poses.shape[0]):
        tab = table[i]
        best = -1.0
        bk = 0
        for k in range(offsets.shape[0]):
            sc = tiled_score_hits(pool_lo, tab, thresh, ox, oy, inv_res, poses[i, 0] + offsets[k, 0], poses[i, 1] + offsets[k, 1], poses[i, 2] + offsets[k, 2], pts)
            if sc > best:
                best = sc
                bk = k
        out_poses[i, 0] = poses[i, 0] + offsets[bk, 0]
        out_poses[i, 1] = poses[i, 1] + offsets[bk, 1]
        out_poses[i, 2] = poses[i, 2] + offsets[bk, 2]
        out_scores[i] = best


@numba.njit(cache=True)
def coarse_scores_by_cells(pool_f, lut, tab, ox, oy, inv_res, px, py, pt, pts_t, shifts, yaws):
    """The coarse grid's field sums when its x/y offsets are whole cells: (yaws, rows, cols)
    over the bounding box of `shifts` (offset k's sum is at [shifts[k, 2], shifts[k, 0] -
    min row shift, shifts[k, 1] - min col shift]; boxes no offset uses are never read).

    For each yaw offset the points (`pts_t`, 2 x M as `place_points` takes them) are placed
    once (cell, bilinear weights; `place_points`) and for each point the map window
    all its x/y shifts touch is read once, a row at a time, each row interpolated in x as it
    is read (`hx`; a row within one tile, nearly always, looks its tile up once); every
    shift's bilinear value comes from two of those, all shifts in one flat loop (which
    vectorises; 5 x 5 short loops did not). Each offset's sum
    adds its points in the same order with the same terms as `tiled_score_field`, so it is
    that sum (up to the last bits of the placement: the shift is added in cells, not metres)."""
    H = tab.shape[0] << TILE_SHIFT
    W = tab.shape[1] << TILE_SHIFT
    if pts_t.shape[0] != 2:  # (M, 2) rows would be read as two garbage points
        raise ValueError("coarse_scores_by_cells: pts_t must be (2, M)")
    r_lo = shifts[:, 0].min()
    c_lo = shifts[:, 1].min()
    ny = shifts[:, 0].max() - r_lo + 1
    nx = shifts[:, 1].max() - c_lo + 1
    win = np.empty((ny + 1, nx + 1))
    hx = np.empty((ny + 1, nx))
    score = np.zeros((yaws.shape[0], ny, nx))
    score_flat = score.reshape((yaws.shape[0], ny * nx))
    hx_flat = hx.reshape((ny + 1) * nx)
    work = np.empty((4, pts_t.shape[1]))
    for a in range(yaws.shape[0]):
        place_points(px, py, pt + yaws[a], pts_t, ox, oy, inv_res, work)
        for i in range(pts_t.shape[1]):
            cb = int(work[0, i])
            rb = int(work[1, i])
            fu = work[2, i]
            fv = work[3, i]
            r0 = rb + r_lo  # the window's first cell
            c0 = cb + c_lo
            inside = r0 >= 0 and c0 >= 0 and r0 + ny + 1 <= H and c0 + nx + 1 <= W
            ic0 = c0 & TILE_MASK
            one_tile_col = inside and ic0 + nx <= TILE_MASK  # every window row lies in one tile
            for dr in range(ny + 1):
                r = r0 + dr
                if one_tile_col:  # the row's tile looked up once (nearly always)
                    t = tab[r >> TILE_SHIFT, c0 >> TILE_SHIFT]
                    ir = r & TILE_MASK
                    left = lut[pool_f[t, ir, ic0]]
                    for dc in range(nx):
                        right = lut[pool_f[t, ir, ic0 + dc + 1]]
                        hx[dr, dc] = (1.0 - fu) * left + fu * right
                        left = right
                else:
                    for dc in range(nx + 1):
                        cc = c0 + dc
                        if inside or (0 <= r < H and 0 <= cc < W):
                            win[dr, dc] = lut[tile_cell(pool_f, tab, r, cc)]
                        else:
                            win[dr, dc] = 0.0
                    for dc in range(nx):
                        hx[dr, dc] = (1.0 - fu) * win[dr, dc] + fu * win[dr, dc + 1]
            if inside:  # every shift's 2 x 2 cells lie on the map (nearly always)
                sa = score_flat[a]
                for k in range(ny * nx):  # one flat loop over the shifts: hx[y0 + 1, x0] is nx further on
                    sa[k] += (1.0 - fv) * hx_flat[k] + fv * hx_flat[k + nx]
            else:  # near the map's edge: shifts whose cells leave it add nothing
                for y0 in range(ny):
                    for x0 in range(nx):
                        if 0 <= r0 + y0 < H - 1 and 0 <= c0 + x0 < W - 1:
                            score[a, y0, x0] += (1.0 - fv) * hx[y0, x0] + fv * hx[y0 + 1, x0]
    return score


@numba.njit(cache=True)
def _coarse_by_cells(pool_f, lut, tab, ox, oy, inv_res, px, py, pt, pts_t, offsets, shifts, yaws, kxy, kyaw):
    """Index of the best coarse offset (prior included; earlier offsets win ties), from
    `coarse_scores_by_cells`."""
    score = coarse_scores_by_cells(pool_f, lut, tab, ox, oy, inv_res, px, py, pt, pts_t, shifts, yaws)
    r_lo = shifts[:, 0].min()
    c_lo = shifts[:, 1].min()
    best = -1e300
    bk = 0
    for k in range(offsets.shape[0]):
        sc = score[shifts[k, 2], shifts[k, 0] - r_lo, shifts[k, 1] - c_lo]
        sc -= kxy * (offsets[k, 0] ** 2 + offsets[k, 1] ** 2) + kyaw * offsets[k, 2] ** 2
        if sc > best:
            best = sc
            bk = k
    return bk


@numba.njit(cache=True)
def _climb(pool_f, lut, tab, ox, oy, inv_res, px, py, pt, coarse_pts, fine_pts, offsets, shifts, yaws, lin_step, ang_step, levels, kxy, kyaw, ext, lut_d, w_scale):
    """One particle: coarse grid, then hill climbing (see `matcher.field_search`), or
    Gauss-Newton steps when `lut_d` has rows (`gauss_newton.refine_pose`). With
    `shifts` (K, 3: rows, cols, yaw index; empty = no) the coarse grid reuses each yaw's
    point placement across its whole-cell x/y offsets (`_coarse_by_cells`)."""
    bx = px
    by = py
    bt = pt
    work = np.empty((4, max(coarse_pts.shape[0], fine_pts.shape[0])))  # tiled_score_field's scratch
    if offsets.shape[0] > 1:
        coarse_t = np.ascontiguousarray(coarse_pts.T)  # the field scores take x and y as two rows (`place_points`)
        if shifts.shape[0] == offsets.shape[0]:
            bk = _coarse_by_cells(pool_f, lut, tab, ox, oy, inv_res, px, py, pt, coarse_t, offsets, shifts, yaws, kxy, kyaw)
        else:
            best = -1e300
            bk = 0
            for k in range(offsets.shape[0]):
                sc = tiled_score_field(pool_f, lut, tab, ox, oy, inv_res, px + offsets[k, 0], py + offsets[k, 1], pt + offsets[k, 2], coarse_t, work)
                sc -= kxy * (offsets[k, 0] ** 2 + offsets[k, 1] ** 2) + kyaw * offsets[k, 2] ** 2
                if sc > best:
                    best = sc
                    bk = k
        bx += offsets[bk, 0]
        by += offsets[bk, 1]
        bt += offsets[bk, 2]
    if lut_d.shape[0] > 0:  # refine: gauss_newton (steps of at most one coarse step)
        return refine_pose(NO_FIELD, pool_f, tab, lut, lut_d, 0.0, ox, oy, inv_res, px, py, pt, bx, by, bt, fine_pts, kxy, kyaw, w_scale, 2.0 * lin_step, 2.0 * ang_step)
    fine_t = np.ascontiguousarray(fine_pts.T)
    cur = _score_fine(pool_f, lut, tab, ox, oy, inv_res, bx, by, bt, fine_t, ext, work)
    n_eval = 1
    cur -= kxy * ((bx - px) ** 2 + (by - py) ** 2) + kyaw * (bt - pt) ** 2
    ls = lin_step
    as_ = ang_step
    for _ in range(levels):
        came = -1  # the move back to the last pose: its score is known (lower), skip it
        for _it in range(16):  # bounded: a climb never runs away on a flat score
            mx = bx
            my = by
            mt = bt
            ms = cur
            mm = -1
            for m in range(6):
                if m == came:
                    continue
                cx = bx
                cy = by
                ct = bt
                if m == 0:
                    cx += ls
                elif m == 1:
                    cx -= ls
                elif m == 2:
                    cy += ls
                elif m == 3:
                    cy -= ls
                elif m == 4:
                    ct += as_
                else:
                    ct -= as_
                sc = _score_fine(pool_f, lut, tab, ox, oy, inv_res, cx, cy, ct, fine_t, ext, work)
                n_eval += 1
                sc -= kxy * ((cx - px) ** 2 + (cy - py) ** 2) + kyaw * (ct - pt) ** 2
                if sc > ms:
                    ms = sc
                    mx = cx
                    my = cy
                    mt = ct
                    mm = m
            if ms > cur:
                came = mm ^ 1  # 0<->1 (x), 2<->3 (y), 4<->5 (yaw)
                bx = mx
                by = my
                bt = mt
                cur = ms
            else:
                break
        ls *= 0.5
        as_ *= 0.5
    return bx, by, bt, cur, n_eval


@numba.njit(cache=True, parallel=True)
def tiled_field_search(pool_f, lut, table, map_of, ox, oy, inv_res, poses, coarse_pts, coarse_span, fine_pts, fine_span, offsets, shifts, yaws, lin_step, ang_step, levels, kxy, kyaw, out_poses, out_scores, out_evals, ext, lut_d, w_scale):
    """Per pose i, coarse-to-fine likelihood-field matching on the map `table[map_of[i]]` of
    the points rows coarse_span[i, 0]:coarse_span[i, 1] of `coarse_pts` (coarse grid) and
    fine_span[i, 0]:fine_span[i, 1] of `fine_pts` (climb). A filter step matches particle i
    against its own map i, all with the same scan's points; the scans between two steps are
    matched each with its own points against one particle's map (every map_of[i] the same).
    `out_evals[i]`: the refinement's scores of the fine points (for the map-read count).
    `ext`: the fine points' stretches (`matcher.surface_stretches`, rows as `fine_pts`; no
    rows = none). `lut_d` (d in cells per field code; empty = hill climb) and `w_scale`
    (1 / sigma^2, cells): the Gauss-Newton refinement (`gauss_newton`) instead of the hill
    climb."""
    # the field's values as float64 once: each read then skips a float32 -> float64 conversion
    # (the same values, so the same sums; 8 % off the search on Intel)
    lut64 = lut.astype(np.float64)
    for i in numba.prange(poses.shape[0]):
        f0 = fine_span[i, 0]
        f1 = fine_span[i, 1]
        bx, by, bt, cur, n_eval = _climb(
            pool_f, lut64, table[map_of[i]], ox, oy, inv_res, poses[i, 0], poses[i, 1], poses[i, 2],
            coarse_pts[coarse_span[i, 0]:coarse_span[i, 1]], fine_pts[f0:f1], offsets, shifts, yaws, lin_step, ang_step,
            levels, kxy, kyaw, ext[f0:f1] if ext.shape[0] > 0 else ext, lut_d, w_scale,
        )
        out_poses[i, 0] = bx
        out_poses[i, 1] = by
        out_poses[i, 2] = bt
        out_scores[i] = cur
        out_evals[i] = n_eval
