"""Loop search: a node's scan against the finished submaps near its current estimate.

For each submap whose area the search window reaches (its loop candidates first, then the
nearest others: `LoopSearch.submaps_in_reach`, `max_submaps_per_node`):
1. branch and bound (`branch_bound.CorrelativeSearch`) over the window on the submap's
   max-pooled field, one scan point per search cell; no candidate above `min_score`: nothing;
2. the best candidate is refined like a local match (hill climbing on the submap's field at
   map resolution, no motion prior) and must keep a mean field value of `min_refined_score`;
3. the ambiguity test: the best candidate at least `ambiguity_m` / `ambiguity_rad` away,
   refined, must score under `ambiguity_ratio` times the best: a corridor seen end to end
   matches as well the wrong way round, and such a match says nothing. Where the other pose
   differs by a shift alone (a corridor slid along its length) the match still says where the
   robot is across the corridor and how it is turned: it stays, with no weight along that line;
4. a full match (not one along a line) whose best pose lies on the edge of its window, on a
   side the submap's area did not cut, is set aside (`edge`): the window is the drift the
   estimate can have, and a best found on its edge is no peak, since the score may still rise
   beyond it (an older pass of a corridor's other half, the true place not mapped yet);
5. what passes is a candidate closure: the node's pose seen from the submap's anchor node.
From a wide window (a long loop's return, `screen_resolution_m` set) the loop candidates are
not the nearest untied submaps but the `screen_keep` of them whose coarse search (0.4 m cells,
a few points) scores best: after tens of metres of drift the estimate is nearer to other
submaps than to the place the robot is in (`LoopSearch.screen`).
The window is the uncertainty of the estimate: `window_m` right after an accepted closure,
growing by `window_per_m` per metre travelled since (likewise the yaw window, up to a full
turn), so after a long loop the search covers whole submaps at every yaw.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import TypeVar

import numba
import numpy as np

from slamlab.geometry import FloatArray, se2_between, se2_compose, se2_inverse, wrap_angle
from slamlab.slam.field_cells import FieldCells
from slamlab.slam.graph.branch_bound import CorrelativeSearch, SearchWindow, yaw_step_for
from slamlab.slam.graph.small_linalg import congruence, from_eig, sym_eig
from slamlab.slam.graph.submaps import FIELD_LUT, FinishedSubmap, Submaps
from slamlab.slam.matcher import field_search, score_field, voxel_filter
from slamlab.slam.raycast import line_start, line_step

# loop-candidate statuses (the report draws them apart)
ACCEPTED = "accepted"
AMBIGUOUS = "ambiguous"
WEAK = "weak"  # the refined match fell below min_refined_score
PENDING = "pending"
INCONSISTENT = "inconsistent"  # no group of mutually consistent closures took it in time
PRUNED = "pruned"  # accepted, then left far off by the optimised graph and dropped
REFUTED = "refuted"  # a group that, optimised in, left earlier closures far off: taken out again
EDGE = "edge"  # a full match whose best pose lay on the edge of the drift window (see module doc)
OVERRULED = "overruled"  # of an earlier group that a later, larger group contradicted: taken out (`run._try_group`)

WALL_MARGIN_M = 0.3  # a beam passing through a wall this close to its end (m) is not a contradiction
AMBIGUITY_SEARCH = 0.9  # the second best is searched down to this share of the ambiguity ratio, then refined
SCREEN_LEVELS = 4  # branch-and-bound levels of the screen's coarse grids (the top node 8 cells a side)
MIN_POINTS = 20  # a scan with fewer search points is not searched (too little to tell places apart)
_NO_EXT = np.zeros((0, 6))
_NO_LUT = np.zeros(0)
_NO_OFFSETS = np.zeros((1, 3))
T = TypeVar("T")
R = TypeVar("R")


SIDE_BY_SIDE_READS = 1_000_000  # searches run side by side when two or more read this many top-level cells each
# (`CorrelativeSearch.top_reads`): a ms or more apiece. Smaller ones (Intel's: 10^4-10^5) cost less than handing them
# to another thread (Intel's loop search 2.2 -> 2.5 s side by side); the hospital's wide ones 10^6-10^7 (its screen 23.6 -> 11.8 s)
_POOLS: dict[int, ThreadPoolExecutor] = {}  # `side_by_side`'s threads by their number, started at first use
# a forked child (a sweep's job: `cli.app._run_in_child`) has none of its parent's threads: its pools start afresh
os.register_at_fork(after_in_child=_POOLS.clear)


def side_by_side(work: Callable[[T], R], jobs: list[T], sizes: list[int] | None = None) -> list[R]:
    """`[work(job) for job in jobs]`, the jobs spread over as many threads as numba has
    (`numba.get_num_threads()`; 1 in a sweep's parallel jobs) when at least two of them are
    large (`sizes`, top-level reads: `SIDE_BY_SIDE_READS`; None: all large), else one after the
    other here. For work that is mostly numba kernels releasing the GIL (`nogil`) and whose
    result does not depend on the thread it ran on or on the other jobs."""
    threads = numba.get_num_threads()
    large = len(jobs) if sizes is None else sum(size >= SIDE_BY_SIDE_READS for size in sizes)
    if threads < 2 or large < 2:
        return [work(job) for job in jobs]
    if threads not in _POOLS:
        _POOLS[threads] = ThreadPoolExecutor(threads, thread_name_prefix="slamlab-search")
    return list(_POOLS[threads].map(work, jobs))


@dataclass(slots=True)
class LoopCandidate:
    """One candidate closure: node `node`'s scan matched into submap `submap` (anchor node
    `anchor`). `relative`: the node's pose seen from the anchor's (the edge the graph gets);
    `score` the branch-and-bound score, `refined` the mean field value after refinement,
    `second` the refined score of the best pose elsewhere (0: none came near); `window_m` the
    half width searched (m); `node_pose` the node's estimate when it was searched and
    `match_pose` where the match put it then (global frame, m, rad); `status` see above;
    `covariance` (3, 3) how well the match pins the pose (`match_covariance`): down a
    corridor it barely says where along it the robot is, and its covariance says so."""

    node: int
    submap: int
    anchor: int
    relative: FloatArray
    score: float
    refined: float
    second: float
    window_m: float
    node_pose: FloatArray
    match_pose: FloatArray
    status: str = PENDING
    loop_id: int = -1  # its id in the pose graph once accepted
    covariance: FloatArray = field(default_factory=lambda: np.diag([1.0, 1.0, 0.1]))  # of `relative`, node frame (m^2, rad^2)
    tied_m: float = 0.0  # how far (m of path) the node was from the submap since the graph last tied them
    along_line: bool = False  # as good elsewhere along a line (a corridor): its covariance holds nothing along it
    in_group: bool = False  # accepted as one of a group of mutually consistent closures (not alone)
    group: int = -1  # with in_group: the node at which its group entered (the group's id)
    see_through: float = 0.0  # share of the scan's beams that pass through the submap's walls at the match
    free_ends: float = 0.0  # share of its beams that end where the submap saw free space


@dataclass(frozen=True, slots=True)
class WindowPolicy:
    """The search window: `xy_m` + `per_m` x d (to `max_m`) and `yaw_rad` + `yaw_per_m` x d,
    d the path (m) travelled since the last accepted closure."""

    xy_m: float
    per_m: float
    max_m: float
    yaw_rad: float
    yaw_per_m: float

    def at(self, travelled_m: FloatArray) -> FloatArray:
        """(S, 2) (half width m, half yaw rad) after `travelled_m` (S,) metres without a closure."""
        d = np.asarray(travelled_m, dtype=np.float64)
        return np.column_stack([np.minimum(self.xy_m + self.per_m * d, self.max_m), np.minimum(self.yaw_rad + self.yaw_per_m * d, math.pi)])


@dataclass(frozen=True, slots=True)
class SearchSettings:
    """The loop search's knobs (`GraphFilter`'s, see its config)."""

    resolution_m: float
    levels: int
    min_score: float
    min_refined_score: float
    ambiguity_ratio: float
    ambiguity_m: float
    ambiguity_rad: float
    max_submaps: int
    loop_min_path_m: float
    screen_resolution_m: float = 0.0
    screen_keep: int = 2
    screen_points: int = 128


class LoopSearch:
    """Searches one node's scan against the finished submaps (see module doc)."""

    def __init__(self, settings: SearchSettings, refine_step_m: float, refine_levels: int, sigma_m: float, sigma_rad: float) -> None:
        self.s = settings
        self.sigma_m = sigma_m  # the floor of a closure's sigma (m, rad): `match_covariance`
        self.sigma_rad = sigma_rad
        self.refine_step_m = refine_step_m
        self.refine_levels = refine_levels
        self.searches = 0  # branch-and-bound searches run
        self.nodes_scored = 0  # bounds computed by them
        self.seconds = 0.0
        self.screened = 0  # coarse searches run by the screen (`screen`)
        self.screen_seconds = 0.0

    def submaps_in_reach(self, pose: FloatArray, submaps: Submaps, anchors_global: FloatArray,
                         windows: FloatArray, tied_m: FloatArray, which: np.ndarray | None = None,
                         screen: FloatArray | None = None) -> list[tuple[FinishedSubmap, FloatArray, tuple[float, float], float]]:
        """(submap, the node's pose in the submap's frame, window) for the finished submaps
        whose known area their window (`windows` (S, 2): half width m, half yaw rad) around
        `pose` reaches: the loop candidates first (one or two), then the `max_submaps` - 1
        nearest others (see below). `anchors_global` (S, 3): each finished submap's anchor's
        estimate; `tied_m` (S,): how far each is from the node since the graph last tied them
        (m of path), carried with each; `which` (S,): the finished submaps these rows are
        (default: all, in order). With `screen` (the query points, node frame) and a screen
        resolution set, the loop candidates are instead the `screen_keep` untied submaps whose
        coarse search scores best (`screen`)."""
        idx = np.arange(len(submaps.finished)) if which is None else which
        frames = se2_compose(anchors_global, se2_inverse(submaps.finished_anchor_local[idx]))  # submap frame -> global
        guess = se2_between(frames, pose)
        d = np.hypot(guess[:, 0] - submaps.finished_center[idx, 0], guess[:, 1] - submaps.finished_center[idx, 1])
        near = np.flatnonzero(d <= submaps.finished_radius[idx] + windows[:, 0])
        near = near[np.argsort(d[near], kind="stable")]
        # loop candidates first: of the submaps in reach not tied to the node for `loop_min_path_m`
        # (where a loop can close), the nearest by where it was seen from (its nodes) and the
        # nearest by its known area's centre, when that is another. Down a corridor a submap's
        # area is centred ~15 m ahead of where it was seen from (30 m beams), so the nearest by
        # the centre alone was often the robot's own submap of 30 m before and never the first
        # visit's at a junction (ACES at 0.5 m steps: loop relations 0.110 -> 0.059 m); by where
        # it was seen from alone, others the centre finds were missed (the hospital).
        # Then the nearest others, which confirm the local map; the nearest alone would almost
        # always be the last few submaps
        untied = near[tied_m[near] >= self.s.loop_min_path_m]
        loop = untied[:1]
        if screen is not None and self.s.screen_resolution_m > 0 and len(untied) > self.s.screen_keep:
            # far from any tie, where the estimate is says little of which submap the robot is in: the
            # coarse search's best score says more (untied is nearest first: ties go to the nearer)
            scores = self.screen(screen, submaps, [(submaps.finished[idx[j]], guess[j], float(windows[j, 0]), float(windows[j, 1])) for j in untied])
            loop = untied[np.argsort(-scores, kind="stable")[: self.s.screen_keep]]
        elif len(untied):
            seen_from = np.hypot(guess[untied, 0] - submaps.finished_view[idx[untied], 0], guess[untied, 1] - submaps.finished_view[idx[untied], 1])
            nearest_seen = untied[int(np.argmin(seen_from))]
            if nearest_seen != untied[0]:
                loop = np.array([nearest_seen, untied[0]])
        others = near[~np.isin(near, loop)][: max(self.s.max_submaps - 1, 0)]
        near = np.concatenate([loop, others])
        return [(submaps.finished[idx[j]], guess[j], (float(windows[j, 0]), float(windows[j, 1])), float(tied_m[j])) for j in near]

    def screen(self, query: FloatArray, submaps: Submaps, targets: list[tuple[FinishedSubmap, FloatArray, float, float]]) -> FloatArray:
        """(T,) the best branch-and-bound score of the `query` points (node frame, m) in each
        target (submap, the node's pose in its frame, half width m, half yaw rad) on the
        submaps' coarse grids (`screen_resolution_m`); -1 where none reaches `min_score`."""
        t0 = time.perf_counter()
        s = self.s
        out = np.full(len(targets), -1.0)
        pts = voxel_filter(query, s.screen_resolution_m)
        if len(pts) > s.screen_points:  # evenly spread over the query: a ranking, not a match (the hospital's screen 43 -> 23 s)
            pts = pts[np.linspace(0, len(pts) - 1, s.screen_points).astype(np.int64)]
        if len(pts) >= MIN_POINTS:
            yaw_step = yaw_step_for(pts, s.screen_resolution_m)
            jobs = []  # (target, its search): made here, on this thread (`screen_grid` keeps the grids it makes)
            for i, (sm, guess, half_xy, half_yaw) in enumerate(targets):
                win = _window_in(sm, guess, half_xy, half_yaw)
                if win is not None:
                    jobs.append((i, CorrelativeSearch(submaps.screen_grid(sm, s.screen_resolution_m, SCREEN_LEVELS), pts, win, yaw_step)))

            def score(job: tuple[int, CorrelativeSearch]) -> float:
                best = job[1].best(s.min_score)
                return best.score if best.found else -1.0

            # each target's search is its own (the same score on any thread): most are too small to share
            # out within (`branch_bound.SHARED_TOP_NODES`), so they run side by side, one a core
            for (i, _), value in zip(jobs, side_by_side(score, jobs, [cs.top_reads for _, cs in jobs])):
                out[i] = value
            self.screened += len(jobs)
        self.screen_seconds += time.perf_counter() - t0
        return out

    def search(self, node: int, pose: FloatArray, fine_pts: FloatArray, own: FloatArray, origin: FloatArray, submaps: Submaps, reach: list[tuple[FinishedSubmap, FloatArray, tuple[float, float], float]],
               poses: FloatArray) -> list[LoopCandidate]:
        """Candidates of node `node` (estimate `pose`, query points `fine_pts` (M, 2) in its
        frame, m; its own scan's points `own`, seen from the lidar at `origin` there) in the
        submaps `reach` (`submaps_in_reach`, of `submaps`); `poses` (N, 3): every node's estimate. Only matches above
        `min_score` become candidates (with their status)."""
        t0 = time.perf_counter()
        s = self.s
        pts = voxel_filter(fine_pts, s.resolution_m)
        out: list[LoopCandidate] = []
        if len(pts) < MIN_POINTS:
            return out
        yaw_step = yaw_step_for(pts, s.resolution_m)
        # each submap's search and what follows from it is its own (the same candidate on any thread):
        # run side by side (`side_by_side`). The submaps' grids and arrays are fetched here first, on
        # this thread (`Submaps` keeps and unpacks them)
        jobs = []
        for sm, guess, (half_xy, half_yaw), tied in reach:
            grid = submaps.search_grid(sm, s.resolution_m, s.levels)
            arrays = submaps.arrays(sm)
            win = _window_in(sm, guess, half_xy, half_yaw)
            if win is not None:
                jobs.append((sm, guess, half_xy, tied, arrays, CorrelativeSearch(grid, pts, win, yaw_step)))

        def one(job: tuple) -> tuple[LoopCandidate | None, int]:
            return self._candidate(node, pose, fine_pts, own, origin, poses, *job)

        for candidate, nodes in side_by_side(one, jobs, [job[-1].top_reads for job in jobs]):
            self.searches += 1
            self.nodes_scored += nodes
            if candidate is not None:
                out.append(candidate)
        self.seconds += time.perf_counter() - t0
        return out

    def _candidate(self, node: int, pose: FloatArray, fine_pts: FloatArray, own: FloatArray, origin: FloatArray, poses: FloatArray,
                   sm: FinishedSubmap, guess: FloatArray, half_xy: float, tied: float, arrays: tuple[np.ndarray, np.ndarray],
                   cs: CorrelativeSearch) -> tuple[LoopCandidate | None, int]:
        """Node `node`'s candidate in submap `sm` (`search`: its arguments; `arrays` the submap's
        field and state codes, `cs` its search over the window), None when its best scores under
        `min_score`; and the bounds the searches computed. Reads only its arguments and settings."""
        s = self.s
        field_u8, state_u8 = arrays
        best = cs.best(s.min_score)
        nodes = best.nodes
        if not best.found:
            return None, nodes
        field = (field_u8, FIELD_LUT)  # read as code / 255 (`field_cells`)
        refined_pose, refined = self._refine(sm, field, best.pose, fine_pts)
        second = 0.0
        status = PENDING
        along = None  # the direction (submap frame) along which the match is ambiguous, if it is along a line
        if refined < s.min_refined_score:
            status = WEAK
        else:
            # another pose scoring near the best in the search, refined like it, must stay
            # clearly below it: both refined, so the grid's discretisation cannot decide
            other = cs.best_outside(best, s.ambiguity_m, s.ambiguity_rad, AMBIGUITY_SEARCH * s.ambiguity_ratio * best.score)
            nodes += other.nodes
            if other.found:
                other_pose, second = self._refine(sm, field, other.pose, fine_pts)
                if second >= s.ambiguity_ratio * refined:
                    along = _along_line(refined_pose, other_pose, s.ambiguity_rad / 2)
                    if along is None:
                        status = AMBIGUOUS
            if status == PENDING and along is None and at_window_edge(best.pose, sm, guess, half_xy, s.resolution_m):
                status = EDGE
        through, free_end, _ = contradictions(state_u8, field_u8, float(sm.origin[0]), float(sm.origin[1]), 1.0 / sm.resolution_m,
                                              float(refined_pose[0]), float(refined_pose[1]), float(refined_pose[2]),
                                              np.ascontiguousarray(own, dtype=np.float64), float(origin[0]), float(origin[1]),
                                              int(round(WALL_MARGIN_M / sm.resolution_m)))

        cov = match_covariance(field, sm.origin, sm.resolution_m, refined_pose, fine_pts, self.sigma_m, self.sigma_rad)
        if along is not None:
            # along the line of equally good poses (a corridor's length) the match says
            # nothing: keep the estimate's place on it, and no weight there
            refined_pose = refined_pose.copy()
            refined_pose[:2] += ((guess[0] - refined_pose[0]) * along[0] + (guess[1] - refined_pose[1]) * along[1]) * along
        # the closure joins the query node to the submap's node nearest the match: the
        # submap's content there was drawn from that node's and its neighbours' scans, so
        # local SLAM's drift between the submap's first node and that one stays out of it
        near = int(np.argmin(np.hypot(*(sm.node_local[:, :2] - refined_pose[:2]).T)))
        anchor, anchor_local = int(sm.node_ids[near]), sm.node_local[near]
        relative = se2_between(anchor_local, refined_pose)
        if along is not None:
            c, sn = np.cos(refined_pose[2]), np.sin(refined_pose[2])
            u = np.array([c * along[0] + sn * along[1], -sn * along[0] + c * along[1]])  # in the node's frame
            cov[:2, :2] += MAX_SIGMA_M**2 * np.outer(u, u)
        return LoopCandidate(
            node=node, submap=sm.index, anchor=anchor, relative=relative, score=best.score, refined=refined,
            second=second, window_m=half_xy, node_pose=np.asarray(pose, dtype=np.float64).copy(),
            match_pose=se2_compose(poses[anchor], relative), status=status,
            covariance=cov, along_line=along is not None, see_through=through / max(len(own), 1), free_ends=free_end / max(len(own), 1), tied_m=tied,
        ), nodes

    def _refine(self, sm: FinishedSubmap, field: FieldCells, pose: FloatArray, pts: FloatArray) -> tuple[FloatArray, float]:
        """Hill climbing on the submap's field from `pose` (submap frame), no motion prior:
        the refined pose and its mean field value over the points (0..1)."""
        out = np.empty((1, 3))
        score = np.empty(1)
        evals = np.empty(1, dtype=np.int64)
        p = np.ascontiguousarray(pts, dtype=np.float64)
        yaw_step = self.refine_step_m / max(float(np.max(np.hypot(p[:, 0], p[:, 1]))), 1.0)
        field_search(field, float(sm.origin[0]), float(sm.origin[1]), 1.0 / sm.resolution_m, pose.reshape(1, 3).astype(np.float64),
                     p, p, _NO_OFFSETS, self.refine_step_m, yaw_step, self.refine_levels, 0.0, 0.0, out, score, evals,
                     _NO_EXT, _NO_LUT, 0.0, 0.0)
        return out[0], float(score[0]) / max(len(p), 1)


def _window_in(sm: FinishedSubmap, guess: FloatArray, half_xy: float, half_yaw: float) -> SearchWindow | None:
    """The window +-`half_xy` (m), +-`half_yaw` (rad) around `guess` (submap frame), cut to
    the submap's area (the robot stood where the submap saw from); None when they miss."""
    H, W = sm.shape
    lo = np.maximum(guess[:2] - half_xy, sm.origin)
    hi = np.minimum(guess[:2] + half_xy, sm.origin + np.array([W, H]) * sm.resolution_m)
    if np.any(hi < lo):
        return None
    centre = (lo + hi) / 2
    return SearchWindow(np.array([centre[0], centre[1], guess[2]]), float(hi[0] - lo[0]) / 2, float(hi[1] - lo[1]) / 2, half_yaw)


def at_window_edge(pose: FloatArray, sm: FinishedSubmap, guess: FloatArray, half_xy: float, cell_m: float) -> bool:
    """Whether a search's best `pose` (submap frame, m) lies within one search cell (`cell_m`)
    of the edge of the window +-`half_xy` around `guess`, on a side the submap's area did not
    cut (`_window_in`): an edge of the drift the estimate can have, not of the map."""
    H, W = sm.shape
    area_lo = np.asarray(sm.origin, dtype=np.float64)
    area_hi = area_lo + np.array([W, H]) * sm.resolution_m
    for a in (0, 1):
        lo, hi = float(guess[a]) - half_xy, float(guess[a]) + half_xy
        if (lo > area_lo[a] and pose[a] <= lo + cell_m) or (hi < area_hi[a] and pose[a] >= hi - cell_m):
            return True
    return False


def _along_line(best: FloatArray, other: FloatArray, max_yaw_rad: float) -> FloatArray | None:
    """The unit direction (map frame) from `best` to `other` when the two differ by a shift
    alone (yaws within `max_yaw_rad`): the match is then ambiguous along that line only, as
    down a corridor. None when they differ in yaw (a corridor seen end to end, another place)."""
    if abs(float(wrap_angle(other[2] - best[2]))) > max_yaw_rad:
        return None
    d = np.asarray(other[:2], dtype=np.float64) - best[:2]
    n = float(np.hypot(d[0], d[1]))
    return d / n if n > 0 else None


@numba.njit(cache=True)
def score_hessian(field, ox, oy, inv_res, x, y, th, pts, h_m, h_rad):
    """(3, 3) second differences of `score_field` at pose (x, y, th) over (x m, y m, th rad),
    steps h_m and h_rad (central differences; mixed terms from the four diagonal neighbours)."""
    h = np.array([h_m, h_m, h_rad])
    base = np.array([x, y, th])
    f0 = score_field(field, ox, oy, inv_res, x, y, th, pts)
    out = np.empty((3, 3))
    for a in range(3):
        p = base.copy()
        p[a] += h[a]
        fp = score_field(field, ox, oy, inv_res, p[0], p[1], p[2], pts)
        p[a] -= 2 * h[a]
        fm = score_field(field, ox, oy, inv_res, p[0], p[1], p[2], pts)
        out[a, a] = (fp - 2 * f0 + fm) / (h[a] * h[a])
        for b in range(a + 1, 3):
            total = 0.0
            for sa in (-1.0, 1.0):
                for sb in (-1.0, 1.0):
                    q = base.copy()
                    q[a] += sa * h[a]
                    q[b] += sb * h[b]
                    total += sa * sb * score_field(field, ox, oy, inv_res, q[0], q[1], q[2], pts)
            out[a, b] = out[b, a] = total / (4 * h[a] * h[b])
    return out


@numba.njit(cache=True)
def contradictions(state, field, ox, oy, inv_res, x, y, th, pts, sx, sy, margin_cells):
    """How a scan seen from pose (x, y, th) contradicts a submap's cell states (`state`:
    UNKNOWN 0, FREE 1, OCCUPIED 2; origin (ox, oy) m, 1 / inv_res m cells): (beams that pass
    through an occupied cell more than `margin_cells` before their end, beams whose end lies
    in a free cell, beams that cross the submap at all). The lidar sits at (sx, sy) in the
    body frame; `pts` (M, 2) are the beams' ends there. An end counts as free only where the
    field (`field`, as `state`) holds no wall within its radius."""
    H, W = state.shape
    c = math.cos(th)
    s = math.sin(th)
    r0 = int(math.floor((y + s * sx + c * sy - oy) * inv_res))
    c0 = int(math.floor((x + c * sx - s * sy - ox) * inv_res))
    through = 0
    free_end = 0
    seen = 0
    for i in range(pts.shape[0]):
        r1 = int(math.floor((y + s * pts[i, 0] + c * pts[i, 1] - oy) * inv_res))
        c1 = int(math.floor((x + c * pts[i, 0] - s * pts[i, 1] - ox) * inv_res))
        dr, dc, sr, sc, err, major_c, n = line_start(r0, c0, r1, c1)
        r = r0
        cc = c0
        known = False
        hit = False
        for step in range(n - margin_cells):
            if 0 <= r < H and 0 <= cc < W:
                v = state[r, cc]
                if v != 0:
                    known = True
                if v == 2:
                    hit = True
                    break
            r, cc, err = line_step(r, cc, err, dr, dc, sr, sc, major_c)
        end_free = 0 <= r1 < H and 0 <= c1 < W and state[r1, c1] == 1 and field[r1, c1] == 0
        if known or end_free:
            seen += 1
        if hit:
            through += 1
        elif end_free:
            free_end += 1
    return through, free_end, seen


MAX_SIGMA_M = 10.0  # a match that pins nothing along some direction gets this sigma there (m; rad for yaw)


def match_covariance(field: np.ndarray | FieldCells, origin: FloatArray, res_m: float, pose: FloatArray, pts: FloatArray,
                     sigma_m: float, sigma_rad: float) -> FloatArray:
    """(3, 3) covariance of a matched pose (in the node's own frame, the frame of a
    `BetweenFactorPose2` error): the score's curvature at the match, taken as the information
    of a log-likelihood (the field is a Gaussian of the distance to the wall: a point on a wall
    adds 1 / sigma_field^2 per m^2 across it), inverted, plus the floor sigma_m^2 / sigma_rad^2
    on each axis (`field`: values, or a grid's `field_cells`). Across a corridor a match is
    pinned to ~1 cm, along it by nothing but the corridor's ends: its covariance there is large
    and the graph takes no along-track pull from it."""
    p = np.ascontiguousarray(pts, dtype=np.float64)
    hess = score_hessian(field, float(origin[0]), float(origin[1]), 1.0 / res_m, float(pose[0]), float(pose[1]), float(pose[2]),
                         p, res_m, res_m / max(float(np.max(np.hypot(p[:, 0], p[:, 1]))), 1.0))
    c, s = np.cos(pose[2]), np.sin(pose[2])
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])  # node frame -> submap frame
    info = congruence(np.ascontiguousarray(rot.T), -hess)
    w, v = sym_eig((info + info.T) / 2)
    w = np.maximum(w, 1.0 / MAX_SIGMA_M**2)  # a flat or concave direction: pinned by nothing
    cov = from_eig(1.0 / w, v)
    return cov + np.diag([sigma_m**2, sigma_m**2, sigma_rad**2])
