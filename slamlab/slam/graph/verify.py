"""Which loop candidates enter the pose graph.

The branch-and-bound score alone does not tell a right closure from a wrong one: in a
building most places look like some other place, and a corridor matches itself turned end
to end. Two tests decide, besides the ambiguity test of the search itself:
- A candidate that confirms the estimate (the move it asks of its node is within `trust_m`
  and `trust_rad` of nothing where the match pins the pose: `correction_fits`) enters on
  its own.
- A candidate that asks for a larger correction is a loop closure only if the graph has
  not tied the robot to that submap within the last `loop_min_path_m` of path (otherwise the
  local map already holds that place, and a match that disagrees with it is the mistake:
  a corridor seen a few doors off). A loop closure waits for others (`group_span_m` of travel). Two closures
  are consistent when the cycle they make with the graph's own estimate between their nodes
  and between their anchors closes, within both closures' covariances and the drift the
  cycle's path allows (`consistency_matrix`; Mangelson et al. 2018, "Pairwise consistent
  measurement set maximization").
  The largest set of mutually consistent candidates (a maximum clique of that relation) enters
  once it holds `group_size` different nodes spread over `group_extent_m` of the path, matched
  in at least `group_submaps` different submaps: wrong matches of different scans mostly
  disagree with each other, and where they agree (a corridor whose doors repeat, matched a few
  doors off by several scans in a row) they stop agreeing once the robot has moved on far
  enough to see something else. Matches of consecutive scans in one old submap are not
  independent: where that submap saw the robot's true place only at its far edge, a place a
  period along the corridor fits every one of them better, and they agree.
A group that enters can still be wrong (the true place not mapped yet, so nothing else could
disagree); a later group that contradicts it, from more nodes, and with it out breaks no more
other closures than a refutation allows (corridor matches counted only across their corridor),
takes it out again (`run._overrule`).
"""

from __future__ import annotations

import heapq
import logging
from dataclasses import dataclass

import numpy as np

from slamlab.geometry import FloatArray, se2_between, se2_compose, se2_inverse, wrap_angle
from slamlab.slam.graph.loops import ACCEPTED, INCONSISTENT, PENDING, LoopCandidate
from slamlab.slam.graph.small_linalg import mahalanobis_sq, rotate_covariances

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class VerifySettings:
    trust_m: float
    trust_rad: float
    loop_min_path_m: float
    group_size: int
    group_extent_m: float
    group_span_m: float
    consistency_m: float
    consistency_per_m: float
    consistency_rad: float
    consistency_rad_per_m: float
    group_submaps: int  # a group's closures are matches in at least this many submaps (see module doc)


CHI2_3 = 11.34  # chi-square, 3 degrees of freedom, 99 %: the gate of every test here


def correction(c: LoopCandidate, poses: FloatArray) -> FloatArray:
    """(3,) the move closure `c` asks of its node: the pose it implies seen from the estimate
    (node frame, m and rad)."""
    d = se2_between(poses[c.node], se2_compose(poses[c.anchor], c.relative))
    return np.array([d[0], d[1], wrap_angle(d[2])])


def correction_fits(c: LoopCandidate, poses: FloatArray, sigma_m: float, sigma_rad: float) -> bool:
    """Whether the move `c` asks for is within sigma_m / sigma_rad of nothing, where the match
    pins the pose (Mahalanobis, with the closure's own covariance added: a corridor match
    may move the node along the corridor, where it says little, at no cost)."""
    d = correction(c, poses)
    cov = c.covariance + np.diag([sigma_m**2, sigma_m**2, sigma_rad**2])
    return bool(mahalanobis_sq(d, cov) <= CHI2_3)


def tied_distances(path_m: FloatArray, ties: np.ndarray, nodes: np.ndarray) -> FloatArray:
    """(Q, Q) how far apart (m of path) the graph holds nodes `nodes` (Q,): the shortest way
    between them along the path, where an accepted closure (`ties` (T, 2): its anchor and
    node) joins its two nodes at no cost. Two places the robot passed far apart in time but
    tied by closures since are close; their relative pose is as certain as the short way."""
    keys = np.unique(np.concatenate([np.asarray(nodes, dtype=np.int64), np.asarray(ties, dtype=np.int64).reshape(-1)]))
    n = len(keys)
    along = np.maximum(np.diff(path_m[keys]), 1e-9)  # consecutive key nodes along the path (0 would be no edge)
    rows = [np.arange(n - 1)]
    cols = [np.arange(1, n)]
    weights = [along]
    if len(ties):
        t = np.searchsorted(keys, np.asarray(ties, dtype=np.int64))
        rows.append(t[:, 0])
        cols.append(t[:, 1])
        weights.append(np.full(len(t), 1e-9))
    r, c, w = np.concatenate(rows), np.concatenate(cols), np.concatenate(weights)
    lo, hi = np.minimum(r, c), np.maximum(r, c)
    order = np.lexsort((w, hi, lo))  # per pair of key nodes the cheapest edge first (a sparse matrix would add them up)
    lo, hi, w = lo[order], hi[order], w[order]
    first = np.ones(len(lo), dtype=bool)
    first[1:] = (lo[1:] != lo[:-1]) | (hi[1:] != hi[:-1])
    keep = first & (lo != hi)
    q = np.searchsorted(keys, np.asarray(nodes, dtype=np.int64))
    return shortest_paths(n, lo[keep], hi[keep], w[keep], q)[:, q]


def shortest_paths(n: int, a: np.ndarray, b: np.ndarray, w: np.ndarray, sources: np.ndarray) -> FloatArray:
    """(S, n) the shortest distance from each of `sources` (S,) to every node of the undirected
    graph on nodes 0..n-1 with edges (a[e], b[e]) of weight w[e] >= 0 (inf where unreachable):
    Dijkstra's algorithm with the standard library's binary heap. Each distance is the sum of
    its path's weights taken from the source, as `scipy.sparse.csgraph.dijkstra` sums them
    (tested equal to it, bit for bit). Why not SciPy: importing scipy.sparse.csgraph took
    ~30 MB and ~0.35 s in every graph run (issue 44), for graphs of a few hundred nodes
    searched a few times per loop closure."""
    frm = np.concatenate([a, b])  # each edge both ways, grouped by the node it leaves
    order = np.argsort(frm, kind="stable")
    to = np.concatenate([b, a])[order].tolist()
    weight = np.concatenate([w, w])[order].astype(np.float64).tolist()
    start = np.searchsorted(frm[order], np.arange(n + 1)).tolist()
    out = np.full((len(sources), n), np.inf)
    for row, src in enumerate(np.asarray(sources, dtype=np.int64).tolist()):
        dist = [float("inf")] * n
        dist[src] = 0.0
        heap = [(0.0, src)]
        while heap:
            d, u = heapq.heappop(heap)
            if d > dist[u]:
                continue  # a stale entry: u was reached shorter since
            for e in range(start[u], start[u + 1]):
                nd = d + weight[e]
                v = to[e]
                if nd < dist[v]:
                    dist[v] = nd
                    heapq.heappush(heap, (nd, v))
        out[row] = dist
    return out


def consistency_matrix(cands: list[LoopCandidate], poses: FloatArray, path_m: FloatArray, s: VerifySettings,
                       ties: np.ndarray | None = None) -> np.ndarray:
    """bool [n, n]: which pairs of the closures `cands` agree (see module doc): the pose of
    node b implied by closure a and the estimate's motion from node a to b, against the pose
    closure b implies; the difference (world axes) is tested against both closures'
    covariances and the estimate's drift over the cycle (`consistency_m` + `consistency_per_m`
    x its path, likewise in yaw). `poses` (N, 3): the graph's estimate; `path_m` (N,): the
    path length (m) at each node; `ties` (T, 2): the accepted closures' (anchor, node), which
    shorten the path between the two anchors (`tied_distances`)."""
    nodes = np.array([c.node for c in cands])
    anchors = np.array([c.anchor for c in cands])
    z = np.array([c.relative for c in cands])
    implied = se2_compose(poses[anchors], z)  # (n, 3) each closure's pose of its node
    via = se2_compose(implied[:, None, :], se2_between(poses[nodes][:, None, :], poses[nodes][None, :, :]))  # [a, b]: node b via a
    e = via - implied[None, :, :]
    e[..., 2] = wrap_angle(e[..., 2])
    # each closure's covariance in world axes (its node frame turned by the implied heading)
    c, sn = np.cos(implied[:, 2]), np.sin(implied[:, 2])
    rot = np.zeros((len(cands), 3, 3))
    rot[:, 0, 0], rot[:, 0, 1], rot[:, 1, 0], rot[:, 1, 1], rot[:, 2, 2] = c, -sn, sn, c, 1.0
    cov = np.array([q.covariance for q in cands])
    world = rotate_covariances(rot, cov)
    lever = np.hypot(*(poses[nodes][:, None, :2] - poses[nodes][None, :, :2]).transpose(2, 0, 1))  # closure a's yaw error, carried to b
    between_anchors = tied_distances(path_m, np.zeros((0, 2)) if ties is None else ties, anchors)
    length = np.abs(path_m[nodes][:, None] - path_m[nodes][None, :]) + between_anchors
    sig = s.consistency_m + s.consistency_per_m * length
    sig_rad = s.consistency_rad + s.consistency_rad_per_m * length
    total = world[:, None] + world[None, :]
    total[..., 0, 0] += sig**2 + world[:, None, 2, 2] * lever**2
    total[..., 1, 1] += sig**2 + world[:, None, 2, 2] * lever**2
    total[..., 2, 2] += sig_rad**2
    q = mahalanobis_sq(e, total)
    ok = q <= CHI2_3
    return ok & ok.T


def max_clique(adjacent: np.ndarray) -> list[int]:
    """A largest set of mutually adjacent vertices of the graph `adjacent` (bool [n, n],
    symmetric): Bron-Kerbosch with pivoting; among equally large ones the first found, which
    depends only on the vertex order."""
    n = len(adjacent)
    best: list[int] = []
    neighbours = [set(np.flatnonzero(adjacent[v]).tolist()) - {v} for v in range(n)]

    def expand(r: list[int], p: set[int], x: set[int]) -> None:
        nonlocal best
        if not p and not x:
            if len(r) > len(best):
                best = list(r)
            return
        if len(r) + len(p) <= len(best):
            return
        pivot = max(p | x, key=lambda u: (len(neighbours[u] & p), -u))
        for v in sorted(p - neighbours[pivot]):
            expand(r + [v], p & neighbours[v], x & neighbours[v])
            p = p - {v}
            x = x | {v}

    expand([], set(range(n)), set())
    return sorted(best)


class ClosureVerifier:
    """Holds the wide-window candidates until a consistent group forms (see module doc)."""

    def __init__(self, settings: VerifySettings) -> None:
        self.s = settings
        self.pending: list[LoopCandidate] = []

    def offer(self, candidates: list[LoopCandidate], node: int, poses: FloatArray, path_m: FloatArray,
              ties: np.ndarray | None = None) -> list[LoopCandidate]:
        """Take this node's candidates (those still `pending` after the search's own tests);
        returns the ones that enter the graph now (status `accepted`). `ties` (T, 2): the
        closures in the graph, (anchor, node) (`consistency_matrix`). Candidates that waited
        `group_span_m` without a group are marked `inconsistent`."""
        s = self.s
        accepted = []
        changed = False  # a group can only form when the waiting set changed
        for c in candidates:
            if c.status != PENDING:
                continue
            if correction_fits(c, poses, s.trust_m, s.trust_rad):
                c.status = ACCEPTED
                accepted.append(c)
            elif c.tied_m < s.loop_min_path_m:  # a correction against a map the graph holds tied to the robot
                c.status = INCONSISTENT
            else:
                self.pending.append(c)
                changed = True
        keep = []
        for c in self.pending:
            if path_m[node] - path_m[c.node] > s.group_span_m:
                c.status = INCONSISTENT
            else:
                keep.append(c)
        self.pending = keep
        if changed and len({c.node for c in self.pending}) >= s.group_size:
            group = [self.pending[v] for v in max_clique(consistency_matrix(self.pending, poses, path_m, s, ties))]
            # a corridor match agrees with anything along the corridor: it cannot vouch for a
            # match that asks to move along it, so where the group has full matches only they count
            full = [c for c in group if not c.along_line] or group
            if not _enough(full, path_m, s):
                # too few full matches: the corridor matches among them still vouch for each other across the
                # corridor and in yaw, which is all they ask for (nothing along it): they enter as a group of their
                # own, and the full matches wait for others like them
                group = full = [c for c in group if c.along_line]
            if _enough(full, path_m, s):
                log.debug("node %d: a group of %d closures enters (nodes %s, submaps %s, moves %s m)", node, len(group),
                          [c.node for c in group], [c.submap for c in group], [round(float(np.hypot(*correction(c, poses)[:2])), 2) for c in group])
                for c in group:
                    c.status = ACCEPTED
                    c.in_group = True
                    c.group = node
                accepted.extend(group)
                self.pending = [c for c in self.pending if c.status == PENDING]
        return accepted

    def flush(self) -> None:
        """At the end of the run: what still waits found no group."""
        for c in self.pending:
            c.status = INCONSISTENT
        self.pending = []


def _enough(group: list[LoopCandidate], path_m: FloatArray, s: VerifySettings) -> bool:
    """Whether `group` has closures from at least `group_size` nodes spread over at least
    `group_extent_m` of path, into at least `group_submaps` submaps."""
    if not group:
        return False
    return (len({c.node for c in group}) >= s.group_size and float(np.ptp([path_m[c.node] for c in group])) >= s.group_extent_m
            and len({c.submap for c in group}) >= s.group_submaps)
