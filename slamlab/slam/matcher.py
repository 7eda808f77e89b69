"""Scan-to-map matching: score each particle's scan against the map over pose offsets.

Two matchers (numba kernels; particles run on all cores, each particle's result depends only on
its own inputs, so results are bit for bit the same whatever the thread count):
- `GridMatcher` (the course): correlation = number of scan points landing on occupied
  cells, evaluated on a fixed grid of x/y/yaw offsets around each particle.
- `LikelihoodFieldMatcher`: score = sum over points of a likelihood field
  exp(-d^2 / 2 sigma^2) (d: distance to the nearest wall, bilinear between cells), a coarse
  x/y/yaw grid on a subsample of beams, then hill climbing on all (used) beams with
  halving steps. Smooth scores make sub-cell poses reachable and weights less jumpy.
With `move_to_best` the particle moves to its best offset; the score there is its
correlation for the weighting either way.

Adding a matcher: subclass `Matcher`, implement `match` (shared map, filter=course) and
`match_each` (a map per particle, filter=rbpf), add its schema (`slamlab.config.slam`, listed in
`slamlab.config.SCHEMAS`) and `conf/matcher/NAME.yaml`.
"""

from __future__ import annotations

import copy
from abc import ABC, abstractmethod
from dataclasses import dataclass

import math

import numba
import numpy as np

from slamlab.config.slam import GridMatcherConfig as _Grid
from slamlab.config.slam import LikelihoodMatcherConfig as _Field
from slamlab.errors import ConfigError
from slamlab.geometry import FloatArray, wrap_angle
from slamlab.slam.field_cells import cell, rows_cols
from slamlab.slam.gauss_newton import NO_LUT, NO_POOL, NO_TABLE, distance_table, refine_pose
from slamlab.slam.grid import OccupancyGrid
from slamlab.slam.raycast import field_place, field_radius_cells
from slamlab.slam.scan import ScanBatch, ScanPoints
from slamlab.slam.shift_search import grid_search_shifts, score_hits, tiled_grid_search_shifts
from slamlab.slam.tiled_match import tiled_field_search, tiled_grid_search
from slamlab.slam.tiles import TiledMaps

_CLIMB = np.zeros(0)  # no distance table: `field_search` / `tiled_field_search` hill-climb
_NO_EXT_ROWS = np.zeros((0, 6))  # no stretches


@numba.njit(cache=True)
def score_field(field, ox, oy, inv_res, x, y, th, pts):
    """Sum of the likelihood field (bilinear between cell centres) at the points."""
    H, W = rows_cols(field)
    c = math.cos(th)
    s = math.sin(th)
    total = 0.0
    for i in range(pts.shape[0]):
        _, _, u, v = field_place(x, y, c, s, pts[i, 0], pts[i, 1], ox, oy, inv_res)
        c0 = int(math.floor(u))
        r0 = int(math.floor(v))
        if c0 < 0 or r0 < 0 or c0 + 1 >= W or r0 + 1 >= H:
            continue
        fu = u - c0
        fv = v - r0
        total += (1.0 - fv) * ((1.0 - fu) * cell(field, r0, c0) + fu * cell(field, r0, c0 + 1)) + fv * (
            (1.0 - fu) * cell(field, r0 + 1, c0) + fu * cell(field, r0 + 1, c0 + 1)
        )
    return total


@numba.njit(cache=True, inline="always")
def _field_at(field, H, W, u, v):
    """The field bilinear at (u, v) (cells, centres at integers); 0 off the map."""
    c0 = int(math.floor(u))
    r0 = int(math.floor(v))
    if c0 < 0 or r0 < 0 or c0 + 1 >= W or r0 + 1 >= H:
        return 0.0
    fu = u - c0
    fv = v - r0
    return (1.0 - fv) * ((1.0 - fu) * cell(field, r0, c0) + fu * cell(field, r0, c0 + 1)) + fv * (
        (1.0 - fu) * cell(field, r0 + 1, c0) + fu * cell(field, r0 + 1, c0 + 1)
    )


@numba.njit(cache=True)
def score_stretches(field, ox, oy, inv_res, x, y, th, pts, ext):
    """`score_field`, except that a point with a stretch (`surface_stretches`: ext[i] = (ux,
    uy, n_before, n_after, step_before, step_after)) scores the largest field value at
    samples along its stretch of surface."""
    H, W = rows_cols(field)
    c = math.cos(th)
    s = math.sin(th)
    total = 0.0
    for i in range(pts.shape[0]):
        u = (x + c * pts[i, 0] - s * pts[i, 1] - ox) * inv_res - 0.5
        v = (y + s * pts[i, 0] + c * pts[i, 1] - oy) * inv_res - 0.5
        best = _field_at(field, H, W, u, v)
        if ext[i, 2] > 0 or ext[i, 3] > 0:
            du = (c * ext[i, 0] - s * ext[i, 1]) * inv_res  # the stretch's direction in cells
            dv = (s * ext[i, 0] + c * ext[i, 1]) * inv_res
            for j in range(1, int(ext[i, 2]) + 1):
                best = max(best, _field_at(field, H, W, u - j * ext[i, 4] * du, v - j * ext[i, 4] * dv))
            for j in range(1, int(ext[i, 3]) + 1):
                best = max(best, _field_at(field, H, W, u + j * ext[i, 5] * du, v + j * ext[i, 5] * dv))
        total += best
    return total


@numba.njit(cache=True)
def _score_fine(field, ox, oy, inv_res, x, y, th, pts, ext):
    """The hill climb's score: `score_stretches` when `ext` has a row per point, else `score_field`."""
    if ext.shape[0] == pts.shape[0] and ext.shape[0] > 0:
        return score_stretches(field, ox, oy, inv_res, x, y, th, pts, ext)
    return score_field(field, ox, oy, inv_res, x, y, th, pts)


@numba.njit(cache=True, parallel=True)
def grid_search_hits(lo, thresh, ox, oy, inv_res, poses, pts, offsets, out_poses, out_scores):
    """For each particle, the offset (K, 3: dx m, dy m, dyaw rad, world axes) with the most
    hits; ties go to the earlier offset (offsets are sorted smallest first)."""
    for i in numba.prange(poses.shape[0]):
        best = -1.0
        bk = 0
        for k in range(offsets.shape[0]):
            sc = score_hits(lo, thresh, ox, oy, inv_res, poses[i, 0] + offsets[k, 0], poses[i, 1] + offsets[k, 1], poses[i, 2] + offsets[k, 2], pts)
            if sc > best:
                best = sc
                bk = k
        out_poses[i, 0] = poses[i, 0] + offsets[bk, 0]
        out_poses[i, 1] = poses[i, 1] + offsets[bk, 1]
        out_poses[i, 2] = poses[i, 2] + offsets[bk, 2]
        out_scores[i] = best


@numba.njit(cache=True, inline="always")
def _field_search_one(field, ox, oy, inv_res, px, py, pt, coarse_pts, fine_pts, offsets, lin_step, ang_step, levels, kxy, kyaw, ext, lut_d, sigma_cells, w_scale):
    """One pose's search (`field_search`): the best pose (x, y, yaw), its fine score and the
    number of fine scores computed."""
    bx = px
    by = py
    bt = pt
    if offsets.shape[0] > 1:
        best = -1e300
        bk = 0
        for k in range(offsets.shape[0]):
            sc = score_field(field, ox, oy, inv_res, px + offsets[k, 0], py + offsets[k, 1], pt + offsets[k, 2], coarse_pts)
            sc -= kxy * (offsets[k, 0] ** 2 + offsets[k, 1] ** 2) + kyaw * offsets[k, 2] ** 2
            if sc > best:
                best = sc
                bk = k
        bx += offsets[bk, 0]
        by += offsets[bk, 1]
        bt += offsets[bk, 2]
    if lut_d.shape[0] > 0:
        return refine_pose(
            field, NO_POOL, NO_TABLE, NO_LUT, lut_d, sigma_cells, ox, oy, inv_res, px, py, pt, bx, by, bt, fine_pts, kxy, kyaw, w_scale, 2.0 * lin_step, 2.0 * ang_step,
        )
    return _climb(field, ox, oy, inv_res, px, py, pt, bx, by, bt, fine_pts, lin_step, ang_step, levels, kxy, kyaw, ext)


@numba.njit(cache=True, inline="always")
def _climb(field, ox, oy, inv_res, px, py, pt, bx, by, bt, fine_pts, lin_step, ang_step, levels, kxy, kyaw, ext):
    """The hill climb of `field_search` from (bx, by, bt), prior centred on (px, py, pt): the
    best pose, its fine score and the number of fine scores computed."""
    cur = _score_fine(field, ox, oy, inv_res, bx, by, bt, fine_pts, ext)
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
                sc = _score_fine(field, ox, oy, inv_res, cx, cy, ct, fine_pts, ext)
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
def field_search(field, ox, oy, inv_res, poses, coarse_pts, fine_pts, offsets, lin_step, ang_step, levels, kxy, kyaw, out_poses, out_scores, out_evals, ext, lut_d, sigma_cells, w_scale):
    """Coarse grid over `offsets` with `coarse_pts`, then hill climbing with `fine_pts`:
    try +-lin_step in x, y and +-ang_step in yaw, take the best improving move, repeat; when
    none improves halve both steps, `levels` times. Every score is penalised by the motion
    prior `kxy * |dxy|^2 + kyaw * dyaw^2` (offset from the predicted pose), so flat
    directions (corridors) do not random-walk. Writes best poses, their fine scores and the
    number of fine scores computed (`out_evals`, for the map-read count). `ext`: the fine
    points' stretches (`surface_stretches`; no rows = none). With `lut_d` = [radius + 1 in
    cells], Gauss-Newton steps replace the hill climb (`gauss_newton.refine_pose`; field
    sigma `sigma_cells`, `w_scale` = 1 / sigma_cells^2)."""
    for i in numba.prange(poses.shape[0]):  # particles on all cores; each result is its own
        bx, by, bt, cur, n_eval = _field_search_one(
            field, ox, oy, inv_res, poses[i, 0], poses[i, 1], poses[i, 2], coarse_pts, fine_pts, offsets,
            lin_step, ang_step, levels, kxy, kyaw, ext, lut_d, sigma_cells, w_scale,
        )
        out_poses[i, 0] = bx
        out_poses[i, 1] = by
        out_poses[i, 2] = bt
        out_scores[i] = cur
        out_evals[i] = n_eval


@numba.njit(cache=True)
def coarse_by_cells(field, ox, oy, inv_res, px, py, pt, pts, shifts, yaws, score):
    """The coarse grid's field sums on a dense field when its x/y offsets are whole cells:
    `score` (yaws, rows, cols) over the bounding box of `shifts` ((K, 3): row, col, yaw index;
    offset k's sum lands at [shifts[k, 2], shifts[k, 0] - min row, shifts[k, 1] - min col]).
    For each yaw the points are placed once; every shift's bilinear value reuses the
    placement's cell and weights, a whole number of cells further on (the tiled maps'
    `tiled_match.coarse_scores_by_cells`, on one dense array)."""
    H, W = rows_cols(field)
    r_lo = shifts[:, 0].min()
    c_lo = shifts[:, 1].min()
    ny = score.shape[1]
    nx = score.shape[2]
    score[:] = 0.0
    for a in range(yaws.shape[0]):
        c = math.cos(pt + yaws[a])
        s = math.sin(pt + yaws[a])
        for i in range(pts.shape[0]):
            _, _, u, v = field_place(px, py, c, s, pts[i, 0], pts[i, 1], ox, oy, inv_res)
            cb = int(math.floor(u))
            rb = int(math.floor(v))
            fu = u - cb
            fv = v - rb
            r0 = rb + r_lo
            c0 = cb + c_lo
            if r0 >= 0 and c0 >= 0 and r0 + ny + 1 <= H and c0 + nx + 1 <= W:
                for dr in range(ny):
                    ra = r0 + dr
                    for dc in range(nx):
                        ca = c0 + dc
                        score[a, dr, dc] += (1.0 - fv) * ((1.0 - fu) * cell(field, ra, ca) + fu * cell(field, ra, ca + 1)) + fv * (
                            (1.0 - fu) * cell(field, ra + 1, ca) + fu * cell(field, ra + 1, ca + 1))
            else:
                for dr in range(ny):
                    for dc in range(nx):
                        score[a, dr, dc] += _field_at(field, H, W, u + dc + c_lo, v + dr + r_lo)


@numba.njit(cache=True, parallel=True)
def field_search_scans(field, ox, oy, inv_res, poses, coarse_pts, coarse_ends, fine_pts, fine_ends, offsets, shifts, yaws, lin_step, ang_step, levels, kxy, kyaw, out_poses, out_scores, out_evals):
    """`field_search` for several scans on one map, serially: pose i searched with its own
    points, rows coarse_ends[i]:coarse_ends[i + 1] of `coarse_pts` and fine_ends[i]:
    fine_ends[i + 1] of `fine_pts` (hill climb; no stretches). With whole-cell offsets
    (`shifts` / `yaws` from `cell_shifts`, else empty) the coarse grid is scored by
    `coarse_by_cells` (the same sums up to the last bits of the placement); the best offset
    is the first (smallest) of the highest scores less the prior, as in `field_search`.
    Scans run on all cores, one at a time to a thread; each result is its own (the graph
    filter's local matches and its scans between steps)."""
    by_cells = shifts.shape[0] == offsets.shape[0] and offsets.shape[0] > 1
    r_lo = shifts[:, 0].min() if by_cells else 0
    c_lo = shifts[:, 1].min() if by_cells else 0
    ny = shifts[:, 0].max() - r_lo + 1 if by_cells else 0
    nx = shifts[:, 1].max() - c_lo + 1 if by_cells else 0
    for i in numba.prange(poses.shape[0]):
        score = np.empty((yaws.shape[0] if by_cells else 0, ny, nx))
        px = poses[i, 0]
        py = poses[i, 1]
        pt = poses[i, 2]
        fine = fine_pts[fine_ends[i]:fine_ends[i + 1]]
        if by_cells:
            coarse_by_cells(field, ox, oy, inv_res, px, py, pt, coarse_pts[coarse_ends[i]:coarse_ends[i + 1]], shifts, yaws, score)
            best = -1e300
            bk = 0
            for k in range(offsets.shape[0]):
                sc = score[shifts[k, 2], shifts[k, 0] - r_lo, shifts[k, 1] - c_lo]
                sc -= kxy * (offsets[k, 0] ** 2 + offsets[k, 1] ** 2) + kyaw * offsets[k, 2] ** 2
                if sc > best:
                    best = sc
                    bk = k
            bx, by, bt, cur, n_eval = _climb(field, ox, oy, inv_res, px, py, pt, px + offsets[bk, 0], py + offsets[bk, 1], pt + offsets[bk, 2],
                                             fine, lin_step, ang_step, levels, kxy, kyaw, _NO_EXT_ROWS)
        else:
            bx, by, bt, cur, n_eval = _field_search_one(
                field, ox, oy, inv_res, px, py, pt, coarse_pts[coarse_ends[i]:coarse_ends[i + 1]], fine, offsets,
                lin_step, ang_step, levels, kxy, kyaw, _NO_EXT_ROWS, _CLIMB, 0.0, 0.0,
            )
        out_poses[i, 0] = bx
        out_poses[i, 1] = by
        out_poses[i, 2] = bt
        out_scores[i] = cur
        out_evals[i] = n_eval


def offset_grid(xy_half_width_m: float, xy_step_m: float, yaw_half_width_rad: float, yaw_step_rad: float) -> FloatArray:
    """(K, 3) offsets (dx m, dy m, dyaw rad), sorted by size so ties favour small moves."""
    nxy = int(round(xy_half_width_m / xy_step_m)) if xy_step_m > 0 else 0
    nyaw = int(round(yaw_half_width_rad / yaw_step_rad)) if yaw_step_rad > 0 else 0
    dxy = np.arange(-nxy, nxy + 1) * xy_step_m
    dyaw = np.arange(-nyaw, nyaw + 1) * yaw_step_rad
    g = np.array(np.meshgrid(dxy, dxy, dyaw, indexing="ij")).reshape(3, -1).T
    key = (g[:, 0] / max(xy_step_m, 1e-9)) ** 2 + (g[:, 1] / max(xy_step_m, 1e-9)) ** 2 + (g[:, 2] / max(yaw_step_rad, 1e-9)) ** 2
    return np.ascontiguousarray(g[np.argsort(key, kind="stable")])


def cell_shifts(offsets: FloatArray, res_m: float) -> tuple[np.ndarray, np.ndarray, FloatArray]:
    """When every x/y offset is a whole number of cells of `res_m` (so a kernel can place each
    yaw's points once and shift them by cells): shifts (K, 3) int (rows, cols, yaw index),
    by_yaw (Y, K / Y) the offsets of each yaw in their order, yaws (Y,) rad. Otherwise empty
    arrays (the kernel then places every offset)."""
    yaws, yaw_idx = np.unique(offsets[:, 2], return_inverse=True)
    cells = offsets[:, :2] / res_m
    whole = np.round(cells)
    if not np.allclose(cells, whole, rtol=0.0, atol=1e-9):
        return np.empty((0, 3), dtype=np.int64), np.empty((0, 0), dtype=np.int64), np.empty(0)
    shifts = np.column_stack([whole[:, 1], whole[:, 0], yaw_idx]).astype(np.int64)
    # an offset grid has the same x/y offsets at every yaw
    by_yaw = np.argsort(yaw_idx, kind="stable").reshape(len(yaws), -1).astype(np.int64)
    return shifts, by_yaw, yaws


def _fine_samples(n_fine: int, ext: FloatArray) -> int:
    """Field values one climb score reads: one per fine point, and a stretch (`ext` row) one
    per sample along it."""
    return n_fine + int(ext[:, 2:4].sum())


class Matcher(ABC):
    """Interface: `match(grid, poses (N,3), scan) -> (poses (N,3), scores (N,))` against one
    shared map, and `match_each(maps, poses, scan)` where particle i matches against its own
    map i of a `TiledMaps` (the RBPF). `field_sigma_m` / `field_radius_m` > 0 ask the map to
    keep a likelihood field."""

    field_sigma_m: float = 0.0
    field_radius_m: float = 0.0
    move_to_best: bool = True
    # map cells read so far (a bilinear field value is 4 reads, a hit test 1; a coarse grid of
    # whole-cell shifts on tiled maps reads each yaw's window once per point): at ~1 ns a read
    # it bounds the matcher's time
    map_reads: int = 0

    @abstractmethod
    def match(self, grid: OccupancyGrid, poses: FloatArray, scan: ScanPoints) -> tuple[FloatArray, FloatArray]:
        ...

    def for_beam_spacing(self, spacing_rad: float) -> Matcher:
        """This matcher for a lidar whose beams are `spacing_rad` (rad) apart: itself, unless
        its score weighs against something that does not grow with the beam count
        (`LikelihoodFieldMatcher.prior_beam_deg`)."""
        return self

    def match_each(self, maps: TiledMaps, poses: FloatArray, scan: ScanPoints, prior_scale: float = 1.0,
                   tables: np.ndarray | None = None) -> tuple[FloatArray, FloatArray]:
        """Particle i against its own map i (filter=rbpf). `prior_scale` (<= 1) scales a
        motion prior's variance (the RBPF's step normalisation); matchers without a prior
        ignore it. `tables`: the tile tables pose i matches against (default `maps.table`,
        every particle's). A matcher that only implements `match` works with filter=course only."""
        raise ConfigError("filter", f"{type(self).__name__} does not support filter=rbpf (no match_each)")

    def prepare_scans(self, scans: ScanBatch) -> ScanBatch | MatchPoints:
        """The points `match_scans` matches, prepared for many scans at once (a run prepares
        the scans between its steps a chunk of steps at a time); here the scans as they are."""
        return scans

    def match_scans(self, maps: TiledMaps, p: int, poses: FloatArray, scans: ScanBatch | MatchPoints) -> FloatArray:
        """Scan i of `scans` (none empty; as `prepare_scans` gives them), predicted at poses[i]
        (S, 3), against particle p's map alone (the maps are not changed): the matched poses
        (S, 3). Here one `match_each` per scan; a matcher with a batched kernel overrides it."""
        assert isinstance(scans, ScanBatch), "this matcher matches the scans as they are"
        tables = maps.table[p:p + 1]
        out = np.empty((len(scans), 3))
        for i in range(len(scans)):
            out[i] = self.match_each(maps, poses[i:i + 1], scans.points(i), tables=tables)[0][0]
        return out

    def _cell_shifts(self, res_m: float) -> tuple[np.ndarray, np.ndarray, FloatArray]:
        """`cell_shifts(self.offsets, res_m)`, computed once per map resolution (it depends on
        nothing else, and `match` runs at every step)."""
        cache = self.__dict__.setdefault("_shifts_by_res", {})
        if res_m not in cache:
            cache[res_m] = cell_shifts(self.offsets, res_m)
        return cache[res_m]

    def _finish(self, poses: FloatArray, best: FloatArray, scores: FloatArray) -> tuple[FloatArray, FloatArray]:
        if not self.move_to_best:
            return poses, scores
        best[:, 2] = wrap_angle(best[:, 2])
        return best, scores


class GridMatcher(Matcher):
    """The course's map correlation over a grid of offsets (hit counts on occupied cells).

    Offsets: x and y from -xy_half_width_m to +xy_half_width_m in xy_step_m (0.2 / 0.05 =
    9 x 9), yaw likewise (yaw_half_width_rad 0 = no yaw search). `beam_step` uses every
    k-th scan point; `max_gap_m` only points with a scan neighbour that close (`isolated_filter`).
    """

    # defaults and checks: `slamlab.config.slam.GridMatcherConfig` (built from it at the edge)
    def __init__(
        self,
        xy_half_width_m: float = _Grid.xy_half_width_m,
        xy_step_m: float = _Grid.xy_step_m,
        yaw_half_width_rad: float = _Grid.yaw_half_width_rad,
        yaw_step_rad: float = _Grid.yaw_step_rad,
        move_to_best: bool = _Grid.move_to_best,
        beam_step: int = _Grid.beam_step,
        max_gap_m: float = _Grid.max_gap_m,
        prior_beam_deg: float = _Grid.prior_beam_deg,  # no motion prior here: nothing to weigh
    ) -> None:
        self.beam_step = int(beam_step)
        self.max_gap_m = float(max_gap_m)
        self.offsets = offset_grid(xy_half_width_m, xy_step_m, yaw_half_width_rad, yaw_step_rad)
        self.move_to_best = bool(move_to_best)

    def _points(self, scan: ScanPoints) -> FloatArray:
        """The scan points the offsets are scored with (after `isolated_filter`)."""
        return np.ascontiguousarray(isolated_filter(scan.xy, self.max_gap_m)[:: self.beam_step])

    def match(self, grid: OccupancyGrid, poses: FloatArray, scan: ScanPoints) -> tuple[FloatArray, FloatArray]:
        pts = self._points(scan)
        best = np.empty_like(poses)
        scores = np.empty(len(poses))
        args = (grid.log_odds, np.float32(grid.s.occupied_threshold), grid.origin[0], grid.origin[1], 1.0 / grid.res,
                np.ascontiguousarray(poses), pts, self.offsets)
        shifts, by_yaw, yaws = self._cell_shifts(grid.res)
        if len(shifts):  # whole-cell offsets (the course's 5 cm grid on a 5 cm map)
            grid_search_shifts(*args, shifts, by_yaw, yaws, best, scores)
        else:
            grid_search_hits(*args, best, scores)
        self.map_reads += len(poses) * len(self.offsets) * len(pts)
        return self._finish(poses, best, scores)

    def match_each(self, maps: TiledMaps, poses: FloatArray, scan: ScanPoints, prior_scale: float = 1.0,
                   tables: np.ndarray | None = None) -> tuple[FloatArray, FloatArray]:
        pts = self._points(scan)
        best = np.empty_like(poses)
        scores = np.empty(len(poses))
        args = (maps.pool_lo, maps.table if tables is None else tables, maps.lo_code(maps.s.occupied_threshold), maps.origin[0],
                maps.origin[1], 1.0 / maps.res, np.ascontiguousarray(poses), pts, self.offsets)
        shifts, by_yaw, yaws = self._cell_shifts(maps.res)
        if len(shifts):
            tiled_grid_search_shifts(*args, shifts, by_yaw, yaws, best, scores)
        else:
            tiled_grid_search(*args, best, scores)
        self.map_reads += len(poses) * len(self.offsets) * len(pts)
        return self._finish(poses, best, scores)


def has_close_neighbour(xy: FloatArray, max_gap_m: float, ends: np.ndarray | None = None) -> np.ndarray:
    """(M,) bool: points with a scan neighbour (the point before or after) within `max_gap_m`.
    With `ends` (a `ScanBatch`'s: several scans' points in one array) only points of one scan
    are neighbours."""
    near = np.zeros(len(xy), dtype=bool)
    if len(xy) >= 2:
        close = np.hypot(*np.diff(xy, axis=0).T) <= max_gap_m  # close[k]: points k and k + 1 (m)
        if ends is not None:
            # no neighbours across two scans (ends at 0 or M: empty scans at the batch's edges,
            # where no gap lies between two scans)
            inner = ends[1:-1]
            close[inner[(inner > 0) & (inner < len(xy))] - 1] = False
        near[:-1] |= close
        near[1:] |= close
    return near


@dataclass(frozen=True, slots=True)
class MatchPoints:
    """Several scans' points as the likelihood matcher matches them (`_points` of each):
    scan i's coarse-grid points are rows coarse_ends[i]:coarse_ends[i + 1] of `coarse` (M, 2),
    its hill-climb points rows fine_ends[i]:fine_ends[i + 1] of `fine`, with `ext` their
    stretches (rows as `fine`, or none) and `samples[i]` the field values one climb score of
    scan i reads (`_fine_samples`). A scan without points has none."""

    coarse: FloatArray
    fine: FloatArray
    ext: FloatArray
    coarse_ends: np.ndarray
    fine_ends: np.ndarray
    samples: np.ndarray

    def __len__(self) -> int:
        return len(self.fine_ends) - 1

    @property
    def counts(self) -> np.ndarray:
        """(m,) climb points per scan (0 only for a scan without points)."""
        return np.diff(self.fine_ends)

    def scans(self, start: int, stop: int) -> MatchPoints:
        """Scans start..stop-1 (views)."""
        c0, c1, f0, f1 = (int(e) for e in (self.coarse_ends[start], self.coarse_ends[stop], self.fine_ends[start], self.fine_ends[stop]))
        ext = self.ext[f0:f1]
        if not ext[:, 2:4].any():  # no stretch among these scans: the climb's plain (vectorised) score
            ext = _NO_STRETCHES
        return MatchPoints(self.coarse[c0:c1], self.fine[f0:f1], ext,
                           self.coarse_ends[start:stop + 1] - c0, self.fine_ends[start:stop + 1] - f0, self.samples[start:stop])

    def nonempty(self) -> MatchPoints:
        """The scans that have points (an empty scan has no rows, so the rows stay)."""
        keep = self.counts > 0
        return MatchPoints(self.coarse, self.fine, self.ext, np.concatenate([[0], self.coarse_ends[1:][keep]]).astype(np.int64),
                           np.concatenate([[0], self.fine_ends[1:][keep]]).astype(np.int64), self.samples[keep])


def _picked_rows(scans: ScanBatch, max_gap_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Over the batch's points: which ones `_points` keeps in their scan (with a scan
    neighbour within `max_gap_m`, or every point of a scan where none has one), and a kept
    point's place among its scan's kept ones (meaningless where a point is not kept)."""
    if not max_gap_m > 0:
        pick = np.ones(len(scans.xy), dtype=bool)
    else:
        near = has_close_neighbour(scans.xy, max_gap_m, scans.ends)
        scan_has = np.diff(_running_count(near)[scans.ends]) > 0
        pick = near | ~np.repeat(scan_has, scans.counts)
    n_picked = _running_count(pick)
    # a kept point's place in its scan: kept points up to it, less those before its scan
    return pick, n_picked[1:] - 1 - np.repeat(n_picked[scans.ends[:-1]], scans.counts)


def _every_kth(scans: ScanBatch, pick: np.ndarray, rank: np.ndarray, k: int) -> tuple[FloatArray, np.ndarray]:
    """Every k-th kept point of each scan, from its first (`kept[::k]` scan by scan): the
    points (rows in scan order) and each scan's end row among them."""
    take = pick if k == 1 else pick & (rank % k == 0)
    return np.ascontiguousarray(scans.xy[take]), _running_count(take)[scans.ends]


def _running_count(flags: np.ndarray) -> np.ndarray:
    """(N + 1,) int64: how many of flags[:i] are set, for i = 0..N."""
    out = np.zeros(len(flags) + 1, dtype=np.int64)
    np.cumsum(flags, out=out[1:])
    return out


def isolated_filter(xy: FloatArray, max_gap_m: float) -> FloatArray:
    """The points (in scan order) with a scan neighbour (the point before or after) within
    `max_gap_m`; all points when `max_gap_m` <= 0 or when none has one (a scan of lone
    points is matched as it is, never as an empty scan). Why: far along a wall seen at a
    grazing angle, one beam's hit lies metres from the next, so the wall enters the map as a
    row of separate blobs of field, and the next scan's far hits score best where they land
    on them: where the robot was. Down a bare 64 m corridor of `benchmarks/sim_carmen.py`
    that comb held the estimate up to 16 m behind the robot, the learnt odometry scale pinned
    at its lower limit. Points closer together still draw a weaker comb (between hits 0.3 m
    apart the field is a third of its peak); 0.6 m is `lidar2d`'s value by measurement, not
    a threshold where the comb vanishes. The grid matcher's hit count sees a comb wherever
    hits are more than a cell apart, so there the filter only drops the lone far hits.
    `surface_stretches` keeps the lone hits that lie on a line, for the likelihood matcher."""
    if max_gap_m <= 0 or len(xy) < 2:
        return xy
    near = has_close_neighbour(xy, max_gap_m)
    return xy[near] if near.any() else xy


# a lone hit on a wall lies on a line with its neighbours: a 1-2 cm range error over gaps of 0.6 m or more
# turns the line by under 2 degrees, so 5 degrees tells one wall from hits on different surfaces
COLLINEAR_COS = math.cos(math.radians(5.0))
STRETCH_MAX_SAMPLES = 10  # samples on each side of a lone hit (bounds the cost of a long gap)


def surface_stretches(xy: FloatArray, max_gap_m: float, step_m: float) -> FloatArray:
    """(M, 6) per scan point: (ux, uy, n_before, n_after, step_before, step_after), the
    stretch of surface a lone hit stands for, or zeros. A lone hit (both neighbours more
    than `max_gap_m` away) that lies on a line with its two neighbours (directions within
    5 degrees, `COLLINEAR_COS`) stands for the surface halfway to each of them: direction
    (ux, uy) (body frame, unit), sampled every `step_m` on each side, or in
    `STRETCH_MAX_SAMPLES` equal steps where half the gap is longer (there the samples are
    coarser and a weaker comb is left: at 0.2 m steps the field between two samples falls to
    0.61 of its peak for sigma 0.1 m).

    Why: `isolated_filter` drops lone hits because, matched as points, they lock onto the
    comb of blobs earlier lone hits left in the map. Matched as the largest field value
    along their stretch they keep what they do know (where the wall is across it, and the
    wall's direction, which far points give best) and lose the along-wall position they do
    not know. Measured with `lidar2d` (0.6 m, step = the field's sigma; 20 degrees, and
    `COLLINEAR_COS`'s 5), seeds 0-4: ACES's mean online error at 0.2 m steps drops (0.0508 m
    dropped -> 0.0441 / 0.0477), at 0.1 m steps it rises (0.0461 -> 0.0485 / 0.0498), so
    `lidar2d` keeps `drop` (its yaml lists the whole matrix)."""
    m = len(xy)
    ext = np.zeros((m, 6))
    if max_gap_m <= 0 or m < 3:
        return ext
    d = np.diff(xy, axis=0)
    gap = np.hypot(d[:, 0], d[:, 1])
    u = d / np.maximum(gap, 1e-12)[:, None]  # unit direction from point k to k + 1
    before, after = gap[:-1], gap[1:]  # of the interior points 1..m-2
    lone = (before > max_gap_m) & (after > max_gap_m) & ((u[:-1] * u[1:]).sum(axis=1) >= COLLINEAR_COS)
    line = u[:-1] + u[1:]
    line /= np.maximum(np.hypot(line[:, 0], line[:, 1]), 1e-12)[:, None]
    n_before = np.where(lone, np.minimum(np.ceil(before / 2 / step_m), STRETCH_MAX_SAMPLES), 0)
    n_after = np.where(lone, np.minimum(np.ceil(after / 2 / step_m), STRETCH_MAX_SAMPLES), 0)
    inner = ext[1:-1]
    inner[:, 0:2] = np.where(lone[:, None], line, 0.0)
    inner[:, 2] = n_before
    inner[:, 3] = n_after
    inner[:, 4] = np.where(lone, before / 2 / np.maximum(n_before, 1), 0.0)
    inner[:, 5] = np.where(lone, after / 2 / np.maximum(n_after, 1), 0.0)
    return ext


_NO_STRETCHES = np.zeros((0, 6))


def _voxel_index(xy: FloatArray, cell_m: float) -> np.ndarray:
    """Indices (ascending) of the first point of each `cell_m` square (`voxel_filter`). The
    square's (column, row) is folded into one integer first: `np.unique` of 1-D keys is several
    times faster than of rows, and keeps the same first points."""
    keys = np.floor(np.asarray(xy) / cell_m).astype(np.int64)
    if len(keys) == 0:
        return np.zeros(0, dtype=np.int64)
    lo = keys.min(axis=0)
    span = int(keys[:, 1].max() - lo[1]) + 1
    _, first = np.unique((keys[:, 0] - lo[0]) * span + (keys[:, 1] - lo[1]), return_index=True)
    return np.sort(first)


def voxel_filter(xy: FloatArray, cell_m: float) -> FloatArray:
    """The first point (in scan order) of each `cell_m` square the points fall in, in scan
    order; all points when `cell_m` <= 0. Why: a surface then weighs by its size, not by the
    angle it covers, so a person half a metre away (150 of 1,000 beams) cannot outvote the
    walls around it."""
    if cell_m <= 0 or len(xy) == 0:
        return xy
    return xy[_voxel_index(xy, cell_m)]


class LikelihoodFieldMatcher(Matcher):
    """Coarse-to-fine matching on a likelihood field (see module doc).

    - sigma_m / radius_m: field width and cut-off (m).
    - xy_half_width_m, xy_step_m, yaw_half_width_rad, yaw_step_rad: the coarse grid
      (evaluated with every `coarse_beam_step`-th point); half widths 0 skip it.
    - beam_step: points used by the hill climb and the score (every k-th).
    - refine: what follows the coarse grid: `climb` (hill climbing: +-x, +-y, +-yaw moves,
      `refine_levels` step halvings starting from half the coarse steps) or `gauss_newton`
      (damped Gauss-Newton steps on the same score, `gauss_newton.py`: ~7x fewer scores;
      `refine_levels` is then unused).
    - refine_levels: step halvings of the hill climb, starting from half the coarse steps.
    - prior_sigma_xy_m / prior_sigma_yaw_rad: motion prior; a pose offset d from the
      prediction costs 0.5 (d / sigma)^2 score units (0 = no prior).
    - prior_beam_deg: the prior's sigmas are for a lidar whose beams are this far apart
      (degrees; 0 = for any lidar). The score is a sum over points, so a lidar with beams k
      times closer scores k times more points off the same walls and outweighs the same prior
      k times over; `for_beam_spacing` multiplies the prior's weight by k.
    - voxel_m: match one point per voxel_m square of the scan (`voxel_filter`; 0 = all).
    - max_gap_m: match only points with a scan neighbour this close (`isolated_filter`; 0 = all).
    - isolated: what the hill climb does with the lone points `max_gap_m` singles out: `drop`
      them, or match those on a line as a `stretch` of surface (`surface_stretches`, sampled
      every `sigma_m` up to 2 x 10 samples). The coarse grid drops them either way.
    """

    # defaults and checks: `slamlab.config.slam.LikelihoodMatcherConfig` (built from it at the edge)
    def __init__(
        self,
        sigma_m: float = _Field.sigma_m,
        radius_m: float = _Field.radius_m,
        xy_half_width_m: float = _Field.xy_half_width_m,
        xy_step_m: float = _Field.xy_step_m,
        yaw_half_width_rad: float = _Field.yaw_half_width_rad,
        yaw_step_rad: float = _Field.yaw_step_rad,
        coarse_beam_step: int = _Field.coarse_beam_step,
        beam_step: int = _Field.beam_step,
        refine_levels: int = _Field.refine_levels,
        prior_sigma_xy_m: float = _Field.prior_sigma_xy_m,
        prior_sigma_yaw_rad: float = _Field.prior_sigma_yaw_rad,
        move_to_best: bool = _Field.move_to_best,
        voxel_m: float = _Field.voxel_m,
        max_gap_m: float = _Field.max_gap_m,
        isolated: str = _Field.isolated,
        refine: str = _Field.refine,
        prior_beam_deg: float = _Field.prior_beam_deg,
    ) -> None:
        self.prior_beam_deg = float(prior_beam_deg)
        self.gauss_newton = refine == "gauss_newton"
        self.voxel_m = float(voxel_m)
        self.max_gap_m = float(max_gap_m)
        self.stretches = isolated == "stretch"
        sxy, syaw = float(prior_sigma_xy_m), float(prior_sigma_yaw_rad)
        self.kxy = 0.5 / sxy**2 if sxy > 0 else 0.0
        self.kyaw = 0.5 / syaw**2 if syaw > 0 else 0.0
        self.field_sigma_m = float(sigma_m)
        self.field_radius_m = float(radius_m)
        self.xy_step_m = float(xy_step_m)
        self.yaw_step_rad = float(yaw_step_rad)
        self.coarse_beam_step = int(coarse_beam_step)
        self.beam_step = int(beam_step)
        self.refine_levels = int(refine_levels)
        self.xy_half_width_m = float(xy_half_width_m)
        self.yaw_half_width_rad = float(yaw_half_width_rad)
        self.offsets = offset_grid(xy_half_width_m, xy_step_m, yaw_half_width_rad, yaw_step_rad)
        self.move_to_best = bool(move_to_best)

    def for_beam_spacing(self, spacing_rad: float) -> LikelihoodFieldMatcher:
        """With `prior_beam_deg` set: this matcher with its prior's weight multiplied by
        prior_beam_deg / the lidar's beam spacing (to 2 decimals: a 1-degree SICK is exactly
        1, itself). A URG-04LX (0.36 degrees, 5.6 m) on the corridor probe
        (`benchmarks/sim_carmen.py --lidar urg`) matched each step ~5 % short down bare
        corridors under the prior tuned on 1-degree lidars (1.5 m behind after 29 m)."""
        if not (self.prior_beam_deg > 0 and spacing_rad > 0):
            return self
        k = round(self.prior_beam_deg / math.degrees(spacing_rad), 2)
        if k == 1.0:
            return self
        out = copy.copy(self)
        out.kxy, out.kyaw = self.kxy * k, self.kyaw * k
        out.map_reads = 0
        return out

    def with_yaw_window(self, yaw_half_width_rad: float) -> LikelihoodFieldMatcher:
        """This matcher with its coarse grid spanning +-yaw_half_width_rad (rad) in the same
        yaw steps; everything else (points, prior, refinement) the same. Its map reads are
        counted on its own."""
        out = copy.copy(self)
        for cache in ("_shifts_by_res", "_coarse_reads"):  # made from the offsets: a shallow copy would share them
            out.__dict__.pop(cache, None)
        out.yaw_half_width_rad = float(yaw_half_width_rad)
        out.offsets = offset_grid(self.xy_half_width_m, self.xy_step_m, out.yaw_half_width_rad, self.yaw_step_rad)
        out.map_reads = 0
        return out

    def with_yaw_held(self) -> LikelihoodFieldMatcher:
        """This matcher matching x and y only: every match keeps its predicted yaw (no yaw in
        the coarse grid, and a refinement yaw step of 1e-9 rad, too small to turn)."""
        out = self.with_yaw_window(0.0)  # its offsets: x and y only, whatever the yaw step
        out.yaw_step_rad = 1e-9
        return out

    def match(self, grid: OccupancyGrid, poses: FloatArray, scan: ScanPoints) -> tuple[FloatArray, FloatArray]:
        assert grid.field is not None, "grid built without a likelihood field"
        coarse, fine, ext = self._points(scan)
        best = np.empty_like(poses)
        scores = np.empty(len(poses))
        evals = np.empty(len(poses), dtype=np.int64)
        field_search(
            grid.field_cells, grid.origin[0], grid.origin[1], 1.0 / grid.res, np.ascontiguousarray(poses), coarse, fine,
            self.offsets, self.xy_step_m * 0.5, self.yaw_step_rad * 0.5, self.refine_levels,
            self.kxy, self.kyaw, best, scores, evals, ext, *self._refinement(grid.res),
        )
        self._count_field_reads(len(poses), len(coarse), len(fine), evals, ext)
        return self._finish(poses, best, scores)

    def match_scans_on(self, grid: OccupancyGrid, poses: FloatArray, scans: ScanBatch | MatchPoints) -> tuple[FloatArray, FloatArray]:
        """Scan i of `scans` (none empty), predicted at poses[i] (S, 3), against the one map
        `grid`, in one serial kernel call (`field_search_scans`): the matched poses (S, 3) and
        their scores (S,), each what `match` gives that scan alone (without stretches: with
        `isolated=stretch` the scans are matched one `match` at a time)."""
        assert grid.field is not None, "grid built without a likelihood field"
        if self.stretches or self.gauss_newton:
            batch = scans if isinstance(scans, ScanBatch) else None
            assert batch is not None, "stretches and Gauss-Newton match scans as they are"
            out = [self.match(grid, poses[i:i + 1], batch.points(i)) for i in range(len(batch))]
            return np.concatenate([o[0] for o in out]) if out else np.empty((0, 3)), np.concatenate([o[1] for o in out]) if out else np.empty(0)
        pts = self.prepare_scans(scans) if isinstance(scans, ScanBatch) else scans
        n = len(pts)
        best = np.empty((n, 3))
        scores = np.empty(n)
        evals = np.empty(n, dtype=np.int64)
        shifts, _, yaws = self._cell_shifts(grid.res)
        field_search_scans(
            grid.field_cells, grid.origin[0], grid.origin[1], 1.0 / grid.res, np.ascontiguousarray(poses, dtype=np.float64),
            pts.coarse, pts.coarse_ends, pts.fine, pts.fine_ends, self.offsets, shifts, yaws, self.xy_step_m * 0.5, self.yaw_step_rad * 0.5,
            self.refine_levels, self.kxy, self.kyaw, best, scores, evals,
        )
        self.map_reads += len(pts.coarse) * self._coarse_reads_per_point(grid.res) + 4 * int((evals * pts.samples).sum())
        return self._finish(np.asarray(poses, dtype=np.float64), best, scores)

    def match_each(self, maps: TiledMaps, poses: FloatArray, scan: ScanPoints, prior_scale: float = 1.0,
                   tables: np.ndarray | None = None) -> tuple[FloatArray, FloatArray]:
        coarse, fine, ext = self._points(scan)
        n = len(poses)
        table = maps.table if tables is None else tables
        assert len(table) == n, "one tile table per pose"  # the kernel reads table[i] unchecked
        spans = (np.tile([0, len(coarse)], (n, 1)), np.tile([0, len(fine)], (n, 1)))  # one scan for all
        best, scores, evals = self._search(maps, table, np.arange(n), poses, coarse, fine, ext, spans, prior_scale)
        self._count_field_reads(n, len(coarse), len(fine), evals, ext, maps.res)
        return self._finish(poses, best, scores)

    def prepare_scans(self, scans: ScanBatch) -> MatchPoints:
        """`_points` of every scan of the batch. Without voxels or stretches (the `lidar2d`
        preset) the points are picked for all scans at once in NumPy, the same rows `_points`
        picks scan by scan: that was ~35 us of Python a scan between Intel's filter steps."""
        if self.voxel_m > 0 or self.stretches:
            parts = [self._points(scans.points(i)) for i in range(len(scans))]
            coarse, fine = (np.concatenate([np.empty((0, 2))] + [q[k] for q in parts]) for k in (0, 1))
            ext = _NO_STRETCHES
            if any(len(q[2]) for q in parts):  # stretches for all (a scan without any: rows of none)
                ext = np.concatenate([q[2] if len(q[2]) else np.zeros((len(q[1]), 6)) for q in parts])
            c_ends, f_ends = (np.cumsum([0] + [len(q[k]) for q in parts]).astype(np.int64) for k in (0, 1))
            samples = np.array([_fine_samples(len(f), e) for _, f, e in parts], dtype=np.int64)
            return MatchPoints(coarse, fine, ext, c_ends, f_ends, samples)
        pick, rank = _picked_rows(scans, self.max_gap_m)
        (coarse, c_ends), (fine, f_ends) = (_every_kth(scans, pick, rank, k) for k in (self.coarse_beam_step, self.beam_step))
        return MatchPoints(coarse, fine, _NO_STRETCHES, c_ends, f_ends, np.diff(f_ends))

    def match_scans(self, maps: TiledMaps, p: int, poses: FloatArray, scans: ScanBatch | MatchPoints) -> FloatArray:
        """Every scan against particle p's map in one kernel call, on all cores; each scan's
        result is what `match_each` gives it alone."""
        pts = self.prepare_scans(scans) if isinstance(scans, ScanBatch) else scans
        if len(pts) == 0:
            return np.empty((0, 3))
        spans = tuple(np.column_stack([e[:-1], e[1:]]) for e in (pts.coarse_ends, pts.fine_ends))
        best, scores, evals = self._search(maps, maps.table, np.full(len(pts), p), poses, pts.coarse, pts.fine, pts.ext, spans, 1.0)
        # the reads of each scan as `_count_field_reads` counts them, summed
        self.map_reads += len(pts.coarse) * self._coarse_reads_per_point(maps.res) + 4 * int((evals * pts.samples).sum())
        return self._finish(np.asarray(poses, dtype=np.float64), best, scores)[0]

    def _search(self, maps: TiledMaps, table: np.ndarray, map_of: np.ndarray, poses: FloatArray, coarse: FloatArray, fine: FloatArray,
                ext: FloatArray, spans: tuple[np.ndarray, np.ndarray], prior_scale: float) -> tuple[FloatArray, FloatArray, np.ndarray]:
        """`tiled_field_search`: pose i on map table[map_of[i]] with the points of its spans."""
        assert maps.has_field, "maps built without a likelihood field"
        n = len(poses)
        best = np.empty((n, 3))
        scores = np.empty(n)
        evals = np.empty(n, dtype=np.int64)
        shifts, _, yaws = self._cell_shifts(maps.res)
        lut_d, _, w_scale = self._refinement(maps.res, maps.field_lut)
        tiled_field_search(
            maps.pool_f, maps.field_lut, table, map_of.astype(np.int64), maps.origin[0], maps.origin[1], 1.0 / maps.res,
            np.ascontiguousarray(poses, dtype=np.float64), coarse, spans[0].astype(np.int64), fine, spans[1].astype(np.int64),
            self.offsets, shifts, yaws, self.xy_step_m * 0.5, self.yaw_step_rad * 0.5, self.refine_levels,
            self.kxy / prior_scale, self.kyaw / prior_scale, best, scores, evals, ext, lut_d, w_scale,
        )
        return best, scores, evals

    def _refinement(self, res_m: float, lut: np.ndarray | None = None) -> tuple[np.ndarray, float, float]:
        """The kernels' Gauss-Newton inputs (`gauss_newton.refine_pose`) for a map of `res_m`:
        (d in cells per field code of `lut`, or [radius + 1] for a dense field; sigma in cells;
        1 / sigma^2). No table when the hill climb refines. Made once per map (`match` runs at
        every step)."""
        if not self.gauss_newton:
            return _CLIMB, 0.0, 0.0
        cache = self.__dict__.setdefault("_refinement_by_map", {})
        key = (res_m, None if lut is None else lut.tobytes())
        if key not in cache:
            sigma = self.field_sigma_m / res_m
            cap = field_radius_cells(self.field_sigma_m, self.field_radius_m, res_m) + 1.0  # a cell past the radius
            table = np.array([cap]) if lut is None else distance_table(lut, sigma, cap)
            cache[key] = (table, sigma, 1.0 / sigma**2)
        return cache[key]

    def fine_points(self, scan: ScanPoints) -> FloatArray:
        """(M, 2) the points of `scan` the hill climb and the score use (after
        `isolated_filter` and `voxel_filter`; body frame, m)."""
        return self._points(scan)[1]

    def _points(self, scan: ScanPoints) -> tuple[FloatArray, FloatArray, FloatArray]:
        """The scan points the coarse grid and the hill climb use (after `isolated_filter`
        and `voxel_filter`), and the climb's points' stretches (`surface_stretches`; no rows
        unless `isolated=stretch`)."""
        xy = scan.xy
        near = has_close_neighbour(xy, self.max_gap_m) if self.max_gap_m > 0 else None
        # `drop`'s points as indices into the scan: those with a close neighbour (all when none has one), voxel-thinned
        close = np.flatnonzero(near) if near is not None and near.any() else np.arange(len(xy))
        if self.voxel_m > 0 and len(close):
            close = close[_voxel_index(xy[close], self.voxel_m)]
        fine = close[:: self.beam_step]
        ext = _NO_STRETCHES
        if self.stretches and near is not None and near.any() and not near.all():
            stretches = surface_stretches(xy, self.max_gap_m, self.field_sigma_m)
            lone = np.flatnonzero(stretches[:, 2] > 0)
            if len(lone):  # add the lone hits on a line, in scan order
                fine = np.union1d(fine, lone)
                ext = np.ascontiguousarray(stretches[fine])
        return np.ascontiguousarray(xy[close[:: self.coarse_beam_step]]), np.ascontiguousarray(xy[fine]), ext

    def _count_field_reads(self, n: int, n_coarse: int, n_fine: int, evals: np.ndarray, ext: FloatArray, res_m: float | None = None) -> None:
        """Add the cells `n` particles' searches read: four per bilinear field value, except
        that on tiled maps (`res_m` given) a coarse grid of whole-cell shifts
        (`tiled_match.coarse_scores_by_cells`) reads each yaw's window of cells once per point."""
        self.map_reads += n * n_coarse * self._coarse_reads_per_point(res_m) + 4 * int(evals.sum()) * _fine_samples(n_fine, ext)

    def _coarse_reads_per_point(self, res_m: float | None) -> int:
        """Cells the coarse grid reads per point (computed once per map resolution)."""
        cache = self.__dict__.setdefault("_coarse_reads", {})
        if res_m not in cache:
            shifts = self._cell_shifts(res_m)[0] if res_m is not None else np.empty((0, 3))
            if len(self.offsets) <= 1:
                cache[res_m] = 0
            elif len(shifts) == len(self.offsets):
                window = int(np.ptp(shifts[:, 0]) + 2) * int(np.ptp(shifts[:, 1]) + 2)  # (rows + 1) x (cols + 1)
                cache[res_m] = len(np.unique(shifts[:, 2])) * window
            else:
                cache[res_m] = 4 * len(self.offsets)
        return cache[res_m]
