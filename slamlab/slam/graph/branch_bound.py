"""Exact branch-and-bound correlative scan matching over x, y and yaw (Olson 2009, "Real-time
correlative scan matching"; Hess et al. 2016, section V: Cartographer's loop search).

The search space is discrete: yaws theta0 + k * yaw_step (k = -K..K) and whole-cell offsets
(dx, dy) in [-wx, wx] x [-wy, wy] of a `score grid` G (uint8, [H, W], row = y). For yaw k
the scan's points are rotated and placed once (`place_points`: cell of each point at zero
offset); a candidate (k, dx, dy) scores

    score(k, dx, dy) = sum over points p of G[row_p,k + dy, col_p,k + dx]   (0 off the grid)

an integer, so two searches that find the same candidate agree to the bit. Branch and bound
never scores most candidates: a node of height h covers the 2^h x 2^h offsets
[dx0, dx0 + 2^h) x [dy0, dy0 + 2^h) of one yaw, and its bound is the same sum over the max-pooled
grid P_h[r, c] = max G[r .. r + 2^h - 1, c .. c + 2^h - 1] (`max_pool_levels`), which no child
can exceed. Nodes are expanded depth first, best bound first, and pruned when their bound
cannot beat the best leaf found so far. Ties are broken towards the smallest (k, dx, dy), the
order `exhaustive_search` scans in, so both return the same candidate (tested).

`search_excluding` finds the best candidate outside a box around a given one: the second-best
pose the loop search's ambiguity test compares with.
"""

from __future__ import annotations

from dataclasses import dataclass

import math

import numba
import numpy as np

from slamlab.geometry import FloatArray

NO_EXCLUSION = np.zeros((0, 6), dtype=np.int64)  # exclusion boxes (k_lo, k_hi, dx_lo, dx_hi, dy_lo, dy_hi): none


@numba.njit(cache=True)
def max_pool_levels(grid, levels):
    """(levels, H + pad, W + pad) uint8, pad = 2^(levels - 1) - 1: level h holds
    P_h[r, c] = max grid[r - pad .. r - pad + 2^h - 1, c - pad .. c - pad + 2^h - 1] (cells off
    the grid count 0), so a grid cell (r, c) sits at (r + pad, c + pad) on every level. Each
    level is the max of four shifted copies of the one below (window 2^h = two of 2^(h-1))."""
    H, W = grid.shape
    pad = (1 << (levels - 1)) - 1
    out = np.zeros((levels, H + pad, W + pad), dtype=np.uint8)
    for r in range(H):
        for c in range(W):
            out[0, r + pad, c + pad] = grid[r, c]
    HP = H + pad
    WP = W + pad
    for h in range(1, levels):
        s = 1 << (h - 1)
        for r in range(HP):
            for c in range(WP):
                v = out[h - 1, r, c]
                if r + s < HP:
                    v = max(v, out[h - 1, r + s, c])
                    if c + s < WP:
                        v = max(v, out[h - 1, r + s, c + s])
                if c + s < WP:
                    v = max(v, out[h - 1, r, c + s])
                out[h, r, c] = v
    return out


@numba.njit(cache=True, nogil=True)
def place_points(pts, x0, y0, yaws, ox, oy, inv_res):
    """(Y, M) rows and cols of the points (M, 2, body frame, m) with the body at (x0, y0) (m,
    map frame) and each yaw (Y,) rad, on a grid of origin (ox, oy) m and 1 / inv_res m cells:
    the candidates' points at zero offset. int32: half the memory of int64 for a wide search's
    10^3 yaws x 10^3 points."""
    Y = yaws.shape[0]
    M = pts.shape[0]
    rows = np.empty((Y, M), dtype=np.int32)
    cols = np.empty((Y, M), dtype=np.int32)
    for k in range(Y):
        c = math.cos(yaws[k])
        s = math.sin(yaws[k])
        for i in range(M):
            wx = x0 + c * pts[i, 0] - s * pts[i, 1]
            wy = y0 + s * pts[i, 0] + c * pts[i, 1]
            cols[k, i] = int(math.floor((wx - ox) * inv_res))
            rows[k, i] = int(math.floor((wy - oy) * inv_res))
    return rows, cols


@numba.njit(cache=True, inline="always")
def _level_score(pool, h, rows, cols, k, dx, dy):
    """Sum of level h of `pool` over yaw k's points shifted by (dx, dy) cells."""
    HP = pool.shape[1]
    WP = pool.shape[2]
    pad = (1 << (pool.shape[0] - 1)) - 1
    total = 0
    for i in range(rows.shape[1]):
        r = rows[k, i] + dy + pad
        c = cols[k, i] + dx + pad
        if 0 <= r < HP and 0 <= c < WP:
            total += pool[h, r, c]
    return total


@numba.njit(cache=True, inline="always")
def _before(k, dx, dy, bk, bdx, bdy):
    """(k, dx, dy) < (bk, bdx, bdy), lexicographically."""
    if k != bk:
        return k < bk
    if dx != bdx:
        return dx < bdx
    return dy < bdy


@numba.njit(cache=True, inline="always")
def _inside_exclusion(k, dx0, dy0, size, ex):
    """The whole node (yaw k, offsets dx0.., dy0.. of side `size`; a leaf: size 1) lies inside
    one of the exclusion boxes `ex` (B, 6)."""
    for b in range(ex.shape[0]):
        if ex[b, 0] <= k <= ex[b, 1] and ex[b, 2] <= dx0 and dx0 + size - 1 <= ex[b, 3] and ex[b, 4] <= dy0 and dy0 + size - 1 <= ex[b, 5]:
            return True
    return False


@numba.njit(cache=True, inline="always")
def node_grid(top, wx, wy):
    """(nx, ny): the top-level nodes of one yaw in x and y, `top` cells a side, over the
    offsets [-wx, wx] x [-wy, wy] (cells)."""
    return (2 * wx) // top + 1, (2 * wy) // top + 1


PLANE_READS_PER_CELL = 4  # `top_bounds` lays the top level out in phase planes when a search reads it at least
# this many times per cell (a wide window); below, re-laying it would cost more than it saves


def top_bounds(pool, rows, cols, wx, wy):
    """The bounds of every top-level node (`bnb_search`'s first level), yaw after yaw on all
    cores: entry (k * nx + a) * ny + b is the node of yaw k at offsets (-wx + a * top,
    -wy + b * top). On a wide window (tens of metres, every yaw) there are 10^5-10^6 of them
    and they are most of the search's reads: the deeper levels prune to a few nodes more.
    Such a window is summed from the top level's phase planes (`_phase_planes`,
    `_top_bounds_planes`), a small one node by node (`_top_bounds_direct`): the same integers."""
    top = 1 << (pool.shape[0] - 1)
    nx, ny = node_grid(top, wx, wy)
    if rows.shape[0] * nx * ny * rows.shape[1] >= PLANE_READS_PER_CELL * pool.shape[1] * pool.shape[2]:
        return _top_bounds_planes(_phase_planes(pool[-1], top), rows, cols, wx, wy, top)
    return _top_bounds_direct(pool, rows, cols, wx, wy)


@numba.njit(cache=True, parallel=True, nogil=True)
def _top_bounds_direct(pool, rows, cols, wx, wy):
    """`top_bounds`, each node's sum over the points on its own."""
    L = pool.shape[0]
    Y = rows.shape[0]
    top = 1 << (L - 1)
    nx, ny = node_grid(top, wx, wy)
    out = np.empty(Y * nx * ny, dtype=np.int64)
    for k in numba.prange(Y):  # each entry its own: the same values whatever the thread count
        for a in range(nx):
            for b in range(ny):
                out[(k * nx + a) * ny + b] = _level_score(pool, L - 1, rows, cols, k, -wx + a * top, -wy + b * top)
    return out


@numba.njit(cache=True, nogil=True)
def _phase_planes(level, top):
    """The pooled grid `level` (HP, WP) as top x top phase planes, each transposed:
    planes[pr, pc, j, i] = level[pr + i * top, pc + j * top] (0 past the grid). The top-level
    nodes of one yaw lie `top` cells apart, so what one point reads over all of them is one
    plane's block of consecutive cells (`_top_bounds_planes`) instead of a cell every `top`
    rows and columns."""
    HP, WP = level.shape
    PH = (HP + top - 1) // top
    PW = (WP + top - 1) // top
    out = np.zeros((top, top, PW, PH), dtype=np.uint8)
    for r in range(HP):
        pr = r % top
        i = r // top
        for c in range(WP):
            out[pr, c % top, c // top, i] = level[r, c]
    return out


@numba.njit(cache=True, parallel=True, nogil=True)
def _top_bounds_planes(planes, rows, cols, wx, wy, top):
    """`top_bounds` from the phase planes (`_phase_planes`): for each point, the block of its
    plane under all the nodes of its yaw added to their sums, column after column of nodes
    (consecutive cells of the plane onto consecutive entries). Integer sums: the values of
    `_top_bounds_direct` in any order, on any number of threads."""
    Y = rows.shape[0]
    M = rows.shape[1]
    PW = planes.shape[2]
    PH = planes.shape[3]
    pad = top - 1
    nx, ny = node_grid(top, wx, wy)
    out = np.empty(Y * nx * ny, dtype=np.int64)
    for k in numba.prange(Y):
        acc = np.zeros(nx * ny, dtype=np.int32)  # the yaw's sums (M x 255 fits): twice the lanes of int64 adds
        for i in range(M):
            R = rows[k, i] - wy + pad  # the point's cell (padded) at the yaw's first node
            C = cols[k, i] - wx + pad
            pr = R % top  # floor modulo: the phase of negative cells too
            pc = C % top
            i0 = (R - pr) // top
            j0 = (C - pc) // top
            b0 = max(0, -i0)  # nodes whose cell lies on the grid
            b1 = min(ny, PH - i0)
            a0 = max(0, -j0)
            a1 = min(nx, PW - j0)
            if b0 >= b1 or a0 >= a1:
                continue
            for a in range(a0, a1):
                col = planes[pr, pc, j0 + a]
                base = a * ny
                for b in range(b0, b1):
                    acc[base + b] += col[i0 + b]
        out[k * nx * ny:(k + 1) * nx * ny] = acc
    return out


BNB_SHARES = 2  # a wide search's top nodes are dealt to this many searches run side by side: a fixed
# number, so the result and the bound count are the same on any number of threads
SHARED_TOP_NODES = 20_000  # a search of this many top nodes or more is shared out (a wide window: tens of
# metres, every yaw); below, one search on one thread (thread start-up would cost more than it saves)


def bnb_search(pool, rows, cols, wx, wy, min_score, ex, t_score):
    """Branch and bound over yaw index k (rows / cols' first axis), dx in [-wx, wx], dy in
    [-wy, wy] (cells) on `pool` (`max_pool_levels`), from the top-level bounds `t_score`
    (`top_bounds`: computed once for a scan in a window, also for its second-best search).
    Returns (score, k, dx, dy, nodes): the best candidate scoring >= min_score (score -1 when
    none does), ties to the smallest (k, dx, dy), and the number of bounds it used (the top
    level's included, computed here or not). Candidates inside an exclusion box (rows of `ex`
    (B, 6): k_lo, k_hi, dx_lo, dx_hi, dy_lo, dy_hi) are left out.

    With `SHARED_TOP_NODES` top nodes or more, they are dealt in turn, best bound first, to
    `BNB_SHARES` searches on all cores (each share then holds some of the best nodes); each
    share finds its own best, and the best of those is the whole window's, with the same tie
    rule: the same answer as one search, for a little more pruning work."""
    if t_score.shape[0] >= SHARED_TOP_NODES:
        return _bnb_shares(pool, rows, cols, wx, wy, min_score, ex, t_score, BNB_SHARES)
    return _bnb_one(pool, rows, cols, wx, wy, min_score, ex, t_score)


@numba.njit(cache=True, inline="always")
def _ranked(t_score, min_score):
    """The top nodes that could hold a candidate (bound >= min_score: on a wide window ~10 %
    of them), best bound first, and among equal bounds the smallest (k, dx, dy)."""
    keep = np.flatnonzero(t_score >= min_score)
    return keep[np.argsort(-t_score[keep], kind="mergesort")]


@numba.njit(cache=True, nogil=True)
def _bnb_one(pool, rows, cols, wx, wy, min_score, ex, t_score):
    """`bnb_search` in one share, on this thread: (score, k, dx, dy, nodes)."""
    sc, k, dx, dy, nodes = _bnb_share(pool, rows, cols, wx, wy, min_score, ex, t_score, _ranked(t_score, min_score))
    if sc < min_score:
        return -1, -1, 0, 0, nodes + t_score.shape[0]
    return sc, k, dx, dy, nodes + t_score.shape[0]


@numba.njit(cache=True, parallel=True, nogil=True)
def _bnb_shares(pool, rows, cols, wx, wy, min_score, ex, t_score, shares):
    """`bnb_search` in `shares` shares on all cores: (score, k, dx, dy, nodes)."""
    ranked = _ranked(t_score, min_score)
    each = np.empty((shares, 5), dtype=np.int64)
    for s in numba.prange(shares):
        part = ranked[s::shares]
        sc, k, dx, dy, nodes = _bnb_share(pool, rows, cols, wx, wy, min_score, ex, t_score, part)
        each[s, 0] = sc
        each[s, 1] = k
        each[s, 2] = dx
        each[s, 3] = dy
        each[s, 4] = nodes
    best = min_score - 1
    bk = rows.shape[0]
    bdx = wx + 1
    bdy = wy + 1
    nodes = t_score.shape[0]
    for s in range(shares):
        nodes += each[s, 4]
        if each[s, 0] > best or (each[s, 0] == best and _before(each[s, 1], each[s, 2], each[s, 3], bk, bdx, bdy)):
            best = each[s, 0]
            bk = each[s, 1]
            bdx = each[s, 2]
            bdy = each[s, 3]
    if best < min_score:
        return -1, -1, 0, 0, nodes
    return best, bk, bdx, bdy, nodes


@numba.njit(cache=True)
def _bnb_share(pool, rows, cols, wx, wy, min_score, ex, t_score, ranked):
    """`bnb_search` from the top nodes `ranked` (indices into `t_score`, best bound first):
    (score, k, dx, dy, bounds computed below the top level); score < min_score when no
    candidate reaches it."""
    L = pool.shape[0]
    Y = rows.shape[0]
    top = 1 << (L - 1)
    nx, ny = node_grid(top, wx, wy)
    nodes = 0
    # the stack: the top level (pushed worst first, so the best pops first), then at most 4
    # children per level on the way down
    cap = ranked.shape[0] + 4 * L + 4
    s_score = np.empty(cap, dtype=np.int64)
    s_k = np.empty(cap, dtype=np.int64)
    s_dx = np.empty(cap, dtype=np.int64)
    s_dy = np.empty(cap, dtype=np.int64)
    s_h = np.empty(cap, dtype=np.int64)
    sp = 0
    for j in range(ranked.shape[0] - 1, -1, -1):
        q = ranked[j]
        s_score[sp] = t_score[q]
        s_k[sp] = q // (nx * ny)
        s_dx[sp] = -wx + ((q // ny) % nx) * top
        s_dy[sp] = -wy + (q % ny) * top
        s_h[sp] = L - 1
        sp += 1
    best = min_score - 1
    bk = Y
    bdx = wx + 1
    bdy = wy + 1
    c_score = np.empty(4, dtype=np.int64)
    c_dx = np.empty(4, dtype=np.int64)
    c_dy = np.empty(4, dtype=np.int64)
    while sp > 0:
        sp -= 1
        sc = s_score[sp]
        k = s_k[sp]
        dx0 = s_dx[sp]
        dy0 = s_dy[sp]
        h = s_h[sp]
        # a node's leaves can at best tie with its bound: prune unless it can win or win the tie
        if sc < best or (sc == best and not _before(k, dx0, dy0, bk, bdx, bdy)):
            continue
        size = 1 << h
        if _inside_exclusion(k, dx0, dy0, size, ex):
            continue
        if h == 0:
            best = sc
            bk = k
            bdx = dx0
            bdy = dy0
            continue
        half = size >> 1
        nc = 0
        for a in range(2):
            for b in range(2):
                cx = dx0 + a * half
                cy = dy0 + b * half
                if cx > wx or cy > wy:
                    continue
                v = _level_score(pool, h - 1, rows, cols, k, cx, cy)
                nodes += 1
                if v < best:
                    continue
                c_score[nc] = v
                c_dx[nc] = cx
                c_dy[nc] = cy
                nc += 1
        # push the children worst first: the best bound (then the smallest offset) on top
        for _ in range(nc):
            w = 0
            for j in range(1, nc):
                if c_score[j] < c_score[w] or (c_score[j] == c_score[w] and _before(k, c_dx[w], c_dy[w], k, c_dx[j], c_dy[j])):
                    w = j
            s_score[sp] = c_score[w]
            s_k[sp] = k
            s_dx[sp] = c_dx[w]
            s_dy[sp] = c_dy[w]
            s_h[sp] = h - 1
            sp += 1
            c_score[w] = c_score[nc - 1]
            c_dx[w] = c_dx[nc - 1]
            c_dy[w] = c_dy[nc - 1]
            nc -= 1
    return best, bk, bdx, bdy, nodes


@numba.njit(cache=True)
def exhaustive_search(grid, rows, cols, wx, wy):
    """Every candidate scored on `grid` itself: (score, k, dx, dy), ties to the smallest
    (k, dx, dy). The reference `bnb_search` is tested against."""
    H, W = grid.shape
    best = -1
    bk = 0
    bdx = 0
    bdy = 0
    for k in range(rows.shape[0]):
        for dx in range(-wx, wx + 1):
            for dy in range(-wy, wy + 1):
                total = 0
                for i in range(rows.shape[1]):
                    r = rows[k, i] + dy
                    c = cols[k, i] + dx
                    if 0 <= r < H and 0 <= c < W:
                        total += grid[r, c]
                if total > best:
                    best = total
                    bk = k
                    bdx = dx
                    bdy = dy
    return best, bk, bdx, bdy


FAR_SHARE = 0.95  # the yaw step is set by the distance 95 % of the points lie within


def yaw_step_for(points_xy: FloatArray, res_m: float) -> float:
    """The yaw step (rad) at which a far point moves about one cell: acos(1 - res^2 / (2 d^2))
    (Hess et al. 2016, eq. 7), d the distance (m) within which 95 % of the points lie rather
    than the farthest one's: a 30 m beam would ask for three times the yaws of a 10 m room for
    the sake of a few points, which then move up to three cells between yaws."""
    d = float(np.quantile(np.hypot(points_xy[:, 0], points_xy[:, 1]), FAR_SHARE)) if len(points_xy) else 0.0
    d = max(d, res_m)
    return float(math.acos(max(1.0 - res_m**2 / (2.0 * d**2), -1.0)))


@dataclass(frozen=True, slots=True)
class SearchGrid:
    """A score grid ready for `correlative_search`: `pool` = `max_pool_levels(grid)`, its
    origin (m) and resolution (m)."""

    pool: np.ndarray
    origin_xy: tuple[float, float]
    resolution_m: float

    @staticmethod
    def of(grid: np.ndarray, origin_xy: tuple[float, float], resolution_m: float, levels: int) -> SearchGrid:
        return SearchGrid(max_pool_levels(np.ascontiguousarray(grid, dtype=np.uint8), int(levels)), origin_xy, resolution_m)

    @property
    def nbytes(self) -> int:
        return int(self.pool.nbytes)


@dataclass(frozen=True, slots=True)
class SearchResult:
    """The best candidate of a search: its pose (x m, y m, yaw rad, map frame), its score as
    the mean grid value over the points in [0, 1] (`score_sum` / (255 M)), and the candidate
    indices; `found` False when no candidate reached the minimum score."""

    found: bool
    pose: FloatArray
    score: float
    score_sum: int
    k: int
    dx: int
    dy: int
    nodes: int


@dataclass(frozen=True, slots=True)
class SearchWindow:
    """Where to search: around `center` (x m, y m, yaw rad, map frame), +-`half_x_m` in x,
    +-`half_y_m` in y and +-`yaw_rad` (pi or more: every yaw)."""

    center: FloatArray
    half_x_m: float
    half_y_m: float
    yaw_rad: float


class CorrelativeSearch:
    """Candidates of one scan in one window of one grid (points placed once per yaw), searched
    by branch and bound, again with an exclusion box for the second best."""

    def __init__(self, grid: SearchGrid, points_xy: FloatArray, window: SearchWindow, yaw_step_rad: float) -> None:
        self.grid = grid
        self.window = window
        res = grid.resolution_m
        if window.yaw_rad >= math.pi:
            n = int(math.ceil(math.pi / yaw_step_rad))
            step = math.pi / n
            self.yaws = window.center[2] + np.arange(-n, n) * step  # the full turn once
        else:
            n = int(math.ceil(window.yaw_rad / yaw_step_rad))
            step = window.yaw_rad / n if n else yaw_step_rad
            self.yaws = window.center[2] + np.arange(-n, n + 1) * step
        self.wx = max(int(math.ceil(window.half_x_m / res)), 0)
        self.wy = max(int(math.ceil(window.half_y_m / res)), 0)
        pts = np.ascontiguousarray(points_xy, dtype=np.float64)
        self.n_points = len(pts)
        self.rows, self.cols = place_points(pts, float(window.center[0]), float(window.center[1]), self.yaws,
                                           grid.origin_xy[0], grid.origin_xy[1], 1.0 / res)
        self._top: np.ndarray | None = None

    @property
    def top_reads(self) -> int:
        """Cells the top level's bounds read (yaws x top nodes x points): the search's size."""
        nx, ny = node_grid(1 << (self.grid.pool.shape[0] - 1), self.wx, self.wy)
        return len(self.yaws) * nx * ny * self.n_points

    def _result(self, found: tuple[int, int, int, int, int]) -> SearchResult:
        score, k, dx, dy, nodes = (int(v) for v in found)
        if score < 0:
            return SearchResult(False, np.zeros(3), 0.0, -1, -1, 0, 0, nodes)
        res = self.grid.resolution_m
        c = self.window.center
        pose = np.array([c[0] + dx * res, c[1] + dy * res, float(self.yaws[k])])
        return SearchResult(True, pose, score / (255.0 * max(self.n_points, 1)), score, k, dx, dy, nodes)

    def _top_bounds(self) -> np.ndarray:
        """The top-level bounds, computed at the first search and kept for the second."""
        if self._top is None:
            self._top = top_bounds(self.grid.pool, self.rows, self.cols, self.wx, self.wy)
        return self._top

    def best(self, min_score: float) -> SearchResult:
        """The best candidate whose mean grid value reaches `min_score` (in [0, 1])."""
        threshold = int(math.ceil(min_score * 255.0 * self.n_points))
        return self._result(bnb_search(self.grid.pool, self.rows, self.cols, self.wx, self.wy, threshold, NO_EXCLUSION, self._top_bounds()))

    def best_outside(self, around: SearchResult, xy_m: float, yaw_rad: float, min_score: float) -> SearchResult:
        """The best candidate reaching `min_score` more than `xy_m` (in x or y) or `yaw_rad` away
        from `around` (the second best pose, for the ambiguity test). On a full turn the yaw
        indices wrap, so the excluded yaws may be two ranges."""
        res = self.grid.resolution_m
        Y = len(self.yaws)
        step = float(self.yaws[1] - self.yaws[0]) if Y > 1 else 1.0
        ek = int(math.floor(yaw_rad / step)) if Y > 1 else 0
        exy = int(math.floor(xy_m / res))
        lo, hi = around.k - ek, around.k + ek
        ranges = [(lo, hi)]
        if self.window.yaw_rad >= math.pi:
            if 2 * ek + 1 >= Y:
                ranges = [(0, Y - 1)]
            elif lo < 0:
                ranges = [(0, hi), (lo + Y, Y - 1)]
            elif hi >= Y:
                ranges = [(lo, Y - 1), (0, hi - Y)]
        ex = np.array([[a, b, around.dx - exy, around.dx + exy, around.dy - exy, around.dy + exy] for a, b in ranges], dtype=np.int64)
        threshold = int(math.ceil(min_score * 255.0 * self.n_points))
        return self._result(bnb_search(self.grid.pool, self.rows, self.cols, self.wx, self.wy, threshold, ex, self._top_bounds()))
