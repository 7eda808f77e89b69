"""Gauss-Newton refinement of a likelihood-field match (`matcher.refine: gauss_newton`).

The matcher maximises S(x) - P(x): S the sum over scan points of the likelihood field
f = exp(-d^2 / 2 sigma^2) (bilinear between cell centres), d a point's distance to the
nearest wall, and P the motion prior kxy |dxy|^2 + kyaw dyaw^2. Maximising the sum of f is
minimising the sum of Welsch's robust loss of d, so iteratively reweighted Gauss-Newton
applies: the gradient is the exact gradient of S - P (from the bilinear f), the curvature
sum_i (f_i / sigma^2) J_i^T J_i + P'' with J_i the gradient of point i's distance d (bilinear
in a table of d per field value) with respect to (x, y, yaw). A step is kept only when it
raises S - P (Levenberg-Marquardt damping otherwise), so the search never ends below its
start: the coarse grid's best offset.

Against the hill climb (`refine: climb`: +-x, +-y, +-yaw moves, halving the step four
times, ~56 scores per particle on Intel) it needs ~8 scores per particle, each a little
dearer, and ends at a slightly higher S - P (Intel, 180 particle matches: +0.01 on average).
`refine_pose` reads either a dense field (the shared map of `filter=course`, the graph's online
map) or a particle's tiles (`filter=rbpf`, field codes decoded by `lut`, their d by `lut_d`).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from slamlab.slam.field_cells import cell, rows_cols
from slamlab.slam.raycast import field_place
from slamlab.slam.tiles import TILE, TILE_SHIFT, tile_cell

# `refine_pose` reads a dense field or tiles: the one it does not read is passed empty
NO_FIELD = np.zeros((0, 0), dtype=np.float32)
NO_POOL = np.zeros((0, TILE, TILE), dtype=np.uint8)
NO_TABLE = np.zeros((0, 0), dtype=np.int32)
NO_LUT = np.zeros(0, dtype=np.float32)

MAX_ITERATIONS = 12  # scores per particle at most (13 with the start)
TOLERANCE = 5e-4  # stop once a kept step moves less than this in x and y (m) and yaw (rad)
_DAMP_FIRST = 4.0  # Levenberg-Marquardt: a rejected step multiplies the diagonal by 1 + damping
_DAMP_GROW = 4.0
_DAMP_SHRINK = 0.3
_DAMP_MAX = 1e4


def distance_table(lut: np.ndarray, sigma_cells: float, cap_cells: float) -> np.ndarray:
    """d (cells) for each field value of `lut`: f = exp(-d^2 / 2 sigma^2), so d = sigma
    sqrt(-2 ln f); a zero (beyond the field's radius, or unknown) reads as `cap_cells` (the
    matcher passes the radius + 1: just past the last non-zero value)."""
    f = np.asarray(lut, dtype=np.float64)
    d = np.full(f.shape, float(cap_cells))
    pos = f > 0
    d[pos] = sigma_cells * np.sqrt(np.maximum(-2.0 * np.log(f[pos]), 0.0))
    return d


@numba.njit(cache=True, inline="always")
def add_point(f00, f01, f10, f11, d00, d01, d10, d11, fu, fv, inv_res, rx, ry, w_scale, g, h):
    """Add one point's terms: its field value (returned), to `g` (3,) the gradient of f with
    respect to (x m, y m, yaw rad), to `h` (6: xx, xy, xt, yy, yt, tt) its curvature weight
    (f / sigma^2) J^T J. (fu, fv): the point's place in its 2 x 2 cells; (rx, ry): its offset
    from the body (m, rotated), so a yaw change moves it by (-ry, rx)."""
    f = (1.0 - fv) * ((1.0 - fu) * f00 + fu * f01) + fv * ((1.0 - fu) * f10 + fu * f11)
    dfu = ((1.0 - fv) * (f01 - f00) + fv * (f11 - f10)) * inv_res
    dfv = ((1.0 - fu) * (f10 - f00) + fu * (f11 - f01)) * inv_res
    g[0] += dfu
    g[1] += dfv
    g[2] += dfv * rx - dfu * ry
    ddu = ((1.0 - fv) * (d01 - d00) + fv * (d11 - d10)) * inv_res
    ddv = ((1.0 - fu) * (d10 - d00) + fu * (d11 - d01)) * inv_res
    ddt = ddv * rx - ddu * ry
    w = f * w_scale
    h[0] += w * ddu * ddu
    h[1] += w * ddu * ddv
    h[2] += w * ddu * ddt
    h[3] += w * ddv * ddv
    h[4] += w * ddv * ddt
    h[5] += w * ddt * ddt
    return f


@numba.njit(cache=True)
def step(g, h, ex, ey, et, kxy, kyaw, damping, max_xy, max_yaw):
    """The damped Gauss-Newton step (dx m, dy m, dyaw rad) from a pose (ex, ey, et) away from
    the prediction, with the field's gradient `g` and curvature `h` there; scaled down to at
    most `max_xy` / `max_yaw`. (0, 0, 0) when the curvature is singular."""
    # minimise E = -(S - P): gradient a, curvature (h + P'') with the damped diagonal
    a0 = 2.0 * kxy * ex - g[0]
    a1 = 2.0 * kxy * ey - g[1]
    a2 = 2.0 * kyaw * et - g[2]
    h00 = (h[0] + 2.0 * kxy) * (1.0 + damping)
    h11 = (h[3] + 2.0 * kxy) * (1.0 + damping)
    h22 = (h[5] + 2.0 * kyaw) * (1.0 + damping)
    h01 = h[1]
    h02 = h[2]
    h12 = h[4]
    c00 = h11 * h22 - h12 * h12
    c01 = h02 * h12 - h01 * h22
    c02 = h01 * h12 - h02 * h11
    det = h00 * c00 + h01 * c01 + h02 * c02
    if not det > 1e-300:
        return 0.0, 0.0, 0.0
    c11 = h00 * h22 - h02 * h02
    c12 = h02 * h01 - h00 * h12
    c22 = h00 * h11 - h01 * h01
    dx = -(c00 * a0 + c01 * a1 + c02 * a2) / det
    dy = -(c01 * a0 + c11 * a1 + c12 * a2) / det
    dt = -(c02 * a0 + c12 * a1 + c22 * a2) / det
    m = max(abs(dx) / max_xy, abs(dy) / max_xy, abs(dt) / max_yaw)
    if m > 1.0:  # the field's gradient is local: go at most one coarse step (x, y and yaw)
        dx /= m
        dy /= m
        dt /= m
    return dx, dy, dt


@numba.njit(cache=True)
def next_damping(kept, damping):
    """The damping after a step was kept (less) or not (more); a value above the maximum
    means stop (no step short enough raises the score)."""
    if kept:
        return damping * _DAMP_SHRINK
    return _DAMP_FIRST if damping == 0.0 else damping * _DAMP_GROW


@numba.njit(cache=True)
def converged(dx, dy, dt):
    return abs(dx) < TOLERANCE and abs(dy) < TOLERANCE and abs(dt) < TOLERANCE


@numba.njit(cache=True, inline="always")
def _distance(f, sigma_cells, cap):
    """d (cells) of a dense field value: as `distance_table`."""
    return sigma_cells * math.sqrt(max(-2.0 * math.log(float(f)), 0.0)) if f > 0.0 else cap  # float64 log, as the table


@numba.njit(cache=True)
def field_gradient(field, pool_f, tab, lut, lut_d, sigma_cells, ox, oy, inv_res, x, y, th, pts, w_scale, g, h):
    """The sum of the field at the points (M, 2, body-yaw frame) with the body at (x, y, th)
    (returned; as `matcher.score_field`), its gradient in `g` and curvature in `h`
    (`add_point`). Reads the dense `field` (H, W; either form `field_cells.cell` reads) when it
    has cells (d from f; cells past the radius read d = radius + 1 as in `distance_table`, given
    as `lut_d[0]`), else particle tiles `pool_f[tab[...]]` decoded by `lut` and `lut_d`."""
    FH, FW = rows_cols(field)
    dense = FH > 0
    H = FH if dense else tab.shape[0] << TILE_SHIFT
    W = FW if dense else tab.shape[1] << TILE_SHIFT
    cap = lut_d[0]
    c = math.cos(th)
    s = math.sin(th)
    g[:] = 0.0
    h[:] = 0.0
    total = 0.0
    for i in range(pts.shape[0]):
        wx, wy, u, v = field_place(x, y, c, s, pts[i, 0], pts[i, 1], ox, oy, inv_res)  # as `score_field`: the same sums
        rx = wx - x  # the point's offset from the body: a yaw change moves it by (-ry, rx)
        ry = wy - y
        c0 = int(math.floor(u))
        r0 = int(math.floor(v))
        if c0 < 0 or r0 < 0 or c0 + 1 >= W or r0 + 1 >= H:
            continue
        if dense:
            f00 = cell(field, r0, c0)
            f01 = cell(field, r0, c0 + 1)
            f10 = cell(field, r0 + 1, c0)
            f11 = cell(field, r0 + 1, c0 + 1)
            d00 = _distance(f00, sigma_cells, cap)
            d01 = _distance(f01, sigma_cells, cap)
            d10 = _distance(f10, sigma_cells, cap)
            d11 = _distance(f11, sigma_cells, cap)
        else:
            a00 = tile_cell(pool_f, tab, r0, c0)
            a01 = tile_cell(pool_f, tab, r0, c0 + 1)
            a10 = tile_cell(pool_f, tab, r0 + 1, c0)
            a11 = tile_cell(pool_f, tab, r0 + 1, c0 + 1)
            f00 = lut[a00]
            f01 = lut[a01]
            f10 = lut[a10]
            f11 = lut[a11]
            d00 = lut_d[a00]
            d01 = lut_d[a01]
            d10 = lut_d[a10]
            d11 = lut_d[a11]
        total += add_point(f00, f01, f10, f11, d00, d01, d10, d11, u - c0, v - r0, inv_res, rx, ry, w_scale, g, h)
    return total


@numba.njit(cache=True)
def refine_pose(field, pool_f, tab, lut, lut_d, sigma_cells, ox, oy, inv_res, px, py, pt, bx, by, bt, pts, kxy, kyaw, w_scale, max_xy, max_yaw):
    """Refine (bx, by, bt) by damped Gauss-Newton steps on the map `field_gradient` reads;
    the prior is centred on the prediction (px, py, pt). Returns the pose, its score (prior
    included) and the number of scores computed."""
    g = np.empty(3)
    h = np.empty(6)
    g2 = np.empty(3)
    h2 = np.empty(6)
    cur = field_gradient(field, pool_f, tab, lut, lut_d, sigma_cells, ox, oy, inv_res, bx, by, bt, pts, w_scale, g, h)
    cur -= kxy * ((bx - px) ** 2 + (by - py) ** 2) + kyaw * (bt - pt) ** 2
    n_eval = 1
    damping = 0.0
    for _ in range(MAX_ITERATIONS):
        dx, dy, dt = step(g, h, bx - px, by - py, bt - pt, kxy, kyaw, damping, max_xy, max_yaw)
        if dx == 0.0 and dy == 0.0 and dt == 0.0:  # singular curvature or no gradient: nowhere to go
            break
        cx = bx + dx
        cy = by + dy
        ct = bt + dt
        sc = field_gradient(field, pool_f, tab, lut, lut_d, sigma_cells, ox, oy, inv_res, cx, cy, ct, pts, w_scale, g2, h2)
        sc -= kxy * ((cx - px) ** 2 + (cy - py) ** 2) + kyaw * (ct - pt) ** 2
        n_eval += 1
        kept = sc > cur
        damping = next_damping(kept, damping)
        if kept:
            bx = cx
            by = cy
            bt = ct
            cur = sc
            g[:] = g2
            h[:] = h2
            if converged(dx, dy, dt):
                break
        elif damping > _DAMP_MAX:
            break
    return bx, by, bt, cur, n_eval
