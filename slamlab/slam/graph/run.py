"""The graph filter's loop: local SLAM, loop search, pose-graph optimisation.

    run_graph(sequence, components) -> SlamResult

Per processed step k (the same steps as the particle filters, `steps.*`):
1. local SLAM (`local.LocalSlam`): the odometry increment predicts the node and the run's
   likelihood-field matcher (with its motion prior) places the scan on the online map, a map
   of everything mapped so far (`filter.local_map=map`; or the older active submap, or the
   RBPF); the scan also goes into the active submaps (`submaps.Submaps`);
2. node k joins the pose graph after node k-1 by that matched motion;
3. scans between steps are matched against the online map as it is now (`steps.between=match`);
4. every `search_every` nodes, the last `query_m` of scans are searched against the finished
   submaps in reach (`loops.LoopSearch`); candidates go through the verifier
   (`verify.ClosureVerifier`): one that confirms the estimate enters alone and the graph is
   updated incrementally (ISAM2), a group asking for a correction is optimised in as a whole
   (`_try_group`: refuted if it breaks the closures the graph held, unless those are an earlier
   group from fewer nodes, which it then overrules); closures the optimum leaves far off are dropped;
5. when the graph puts node k `redraw_m` / `redraw_rad` away from the online map, that map is
   drawn again from the graph (`redraw_poses`: in the graph's frame, or laid rigidly on the
   online map's with `redraw_frame=online`); the online (causal) pose of step k is local SLAM's.
At the end the graph is optimised once more: its estimate places the nodes, and (with
`filter.final_match`, when the scans between steps were matched: `steps.between=match`)
every scan is matched once more on a map of the nodes' scans at those poses (`final_match`):
that is the smoothed trajectory. The final map is drawn by ray casting
every node's scan from its smoothed pose.

How far a submap can be from where the estimate puts it grows with the path travelled
between the node and the submap since they were last tied together: the shorter of the path
itself and, through any accepted closure, the path from the closure's node plus the path
between its anchor and the submap's (`TiedSubmaps`). That distance sets each submap's
search window (`loops.WindowPolicy`).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

import numpy as np

from slamlab.code_pages import give_back_library_pages
from slamlab.errors import ConfigError
from slamlab.frames import Sequence
from slamlab.geometry import FloatArray, se2_between, se2_compose, se2_fit
from slamlab.heap import release_freed_memory
from slamlab.io.table import Table
from slamlab.slam.graph import GraphFilter
from slamlab.slam.graph.final_match import match_on_final_map
from slamlab.slam.graph.local import LocalSlam
from slamlab.slam.graph.particles import ParticleTracker
from slamlab.slam.graph.loops import ACCEPTED, OVERRULED, PENDING, PRUNED, REFUTED, LoopCandidate, LoopSearch, SearchSettings, WindowPolicy
from slamlab.slam.graph.pose_graph import GraphNoise, PoseGraph
from slamlab.slam.graph.small_linalg import sym_eig
from slamlab.slam.graph.submaps import Submaps
from slamlab.slam.graph.verify import ClosureVerifier, VerifySettings
from slamlab.slam.mapping import map_from_trajectory
from slamlab.slam.matcher import LikelihoodFieldMatcher
from slamlab.slam.plan import BetweenScans, Components, plan_steps
from slamlab.slam.result import SlamResult
from slamlab.slam.scan import ScanBatch, ScanPoints, points_to_world, project_scans, range_limits, scan_to_points
from slamlab.slam.steps import fill_between_steps

WIDE_M = 5.0  # a search window wider than this (m, half width) ...
WIDE_RAD = 0.5  # ... or this (rad) is a wide one (`filter.wide_every`)
log = logging.getLogger(__name__)
REFUTE_MIN = 3  # a group is refuted when it leaves more than this many earlier closures far off ...
REFUTE_SHARE = 0.02  # ... and more than this share of them
REFRESH_EVERY = 10  # every node's estimate read back from ISAM2 every this many nodes (the search windows'
# submap placements, and the check of every closure against the estimate)


def run_graph(sequence: Sequence, c: Components, progress: Callable[[int, int], bool | None] | None = None) -> SlamResult:
    """Run the graph filter over `sequence` (see module doc). `progress(scans_done,
    scans_total)` after every step; when it returns True the run stops there and returns the
    scans up to that step."""
    f = c.filter
    assert isinstance(f, GraphFilter)
    s = f.settings
    matcher = c.matcher
    if not isinstance(matcher, LikelihoodFieldMatcher):
        raise ConfigError("matcher", "filter=graph matches into submaps with a likelihood field: use matcher=likelihood")
    plan = plan_steps(sequence, c)
    scans, times, odom, step_scans = plan.scans, plan.times, plan.odometry, plan.step_scans
    n_steps = len(step_scans)
    ms = c.map
    min_r, max_r = range_limits(ms, sequence)

    def points(i: int):
        return scan_to_points(scans[i], sequence.body_height_m, min_r, max_r, ms.ground_threshold_m)

    start = odom[step_scans[0]].copy()
    submaps = Submaps(ms, s.submap_nodes, matcher.field_sigma_m, matcher.field_radius_m, field_when_finished=s.local_map == "map",
                       walls_at_hits=s.wall_at == "hits")
    if s.local_map == "particles":
        tracker: LocalSlam = ParticleTracker(matcher, ms, submaps, start, c.particles, c.motion, c.weighting, c.resampler, c.seed, s.online)
    else:
        wide = matcher.with_yaw_window(s.local_yaw_half_width_rad) if s.local_yaw_half_width_rad > matcher.yaw_half_width_rad else None
        tracker = LocalSlam(matcher, ms, submaps, s.local_map, start, c.motion.scale_gain_per_m, wide, s.wall_at == "hits", s.near_hits_m, s.yaw_drift_gain_per_m,
                            s.local_check_rad, s.local_weak_fit)
    give_back_library_pages("gtsam")  # its import's set-up code, run once (the optimiser reads ~12 of its 28 MB again)
    graph = PoseGraph(start, GraphNoise(s.local_sigma_m, s.local_sigma_per_m, s.local_sigma_rad, s.local_sigma_per_rad,
                                        s.loop_sigma_m, s.loop_sigma_rad, s.loss, s.loss_scale, s.local_sigma_along_per_m))
    search = LoopSearch(SearchSettings(s.search_resolution_m, s.search_levels, s.min_score, s.min_refined_score,
                                       s.ambiguity_ratio, s.ambiguity_m, s.ambiguity_rad, s.max_submaps_per_node, s.loop_min_path_m,
                                       s.screen_resolution_m, s.screen_keep, s.screen_points),
                        refine_step_m=ms.resolution_m, refine_levels=matcher.refine_levels + 1,
                        sigma_m=s.loop_sigma_m, sigma_rad=s.loop_sigma_rad)
    policy = WindowPolicy(s.window_m, s.window_per_m, s.window_max_m, s.window_yaw_rad, s.window_yaw_per_m)
    verifier = ClosureVerifier(VerifySettings(s.trust_m, s.trust_rad, s.loop_min_path_m, s.group_size, s.group_extent_m, s.group_span_m, s.consistency_m,
                                              s.consistency_per_m, s.consistency_rad, s.consistency_rad_per_m, group_submaps=s.group_submaps))
    causal = np.empty((n_steps, 3))
    on_map = np.empty((n_steps, 3))  # local_map=map: each node's pose on the online map as it is now ...
    laid = np.zeros(3)  # ... and the rigid motion from the graph's frame to that map's (`redraw_frame=online`)
    path_m = np.zeros(n_steps)  # path length (m) of the local trajectory at each node
    candidates: list[LoopCandidate] = []
    rows: dict[str, list] = {k: [] for k in ("step_time_s", "closures", "optimise_s")}
    between = np.full((len(scans), 3), np.nan) if c.between == "match" else None

    def project(a: int, b: int) -> ScanBatch:
        return project_scans(scans, a, b, sequence.body_height_m, min_r, max_r, ms.ground_threshold_m)

    between_scans = BetweenScans(step_scans, len(scans), project, lambda batch: batch)
    tied = TiedSubmaps()
    tying: list[LoopCandidate] = []  # the accepted closures that tie their node to their submap (`tied`), in the order tied
    by_loop: dict[int, LoopCandidate] = {}  # the candidate behind each closure of the graph
    first_scan = None
    wide_until_m = -np.inf  # while a correction waits for its group, wide windows are searched from every node up to this path (m)
    t_loop = time.perf_counter()
    for k, si in enumerate(step_scans):
        t0 = time.perf_counter()
        pts = points(si)
        if k == 0:
            first_scan = (points_to_world(pts.xy, start), points_to_world(pts.origin.reshape(1, 2), start)[0])
        else:
            motion = tracker.step(se2_between(odom[step_scans[k - 1]], odom[si]), pts)
            step_m = float(np.hypot(motion[0], motion[1]))
            path_m[k] = path_m[k - 1] + step_m
            graph.add_node(motion, tracker.slack(pts, step_m, s.local_slip_per_m))
        for done in tracker.insert(k, pts):
            tied.add_submap(done.anchor, path_m)
        if between is not None:
            js, batch = between_scans.of_step(k)
            if len(js):
                ref = tracker.reference
                since = se2_between(odom[si], odom[js])
                since[:, :2] *= tracker.scale[0]  # the learnt odometry scale (1 when none is learnt)
                matched = tracker.match_online(se2_compose(ref, since), batch)
                between[js] = se2_between(ref, matched)
        tracker.finish_step()
        new: list[LoopCandidate] = []
        fine = matcher.fine_points(pts)
        tracker.remember(k, float(path_m[k]), fine, s.query_m)
        if submaps.finished and k % s.search_every == 0 and len(pts.xy):
            query = tracker.query(ms.resolution_m) if s.query_m > 0 else fine
            wide_every = 1 if path_m[k] <= wide_until_m else s.wide_every
            new = _search_loops(k, query, fine, pts.origin, submaps, graph, search, policy, tied.drift(k, path_m), wide_every)
            candidates.extend(new)
        accepted = verifier.offer(new, k, graph.poses, path_m, graph.active_ties)
        if any(c.status == PENDING for c in new):
            # a loop's return: one match asks for a correction and waits for others to agree (or not). Wide windows are
            # searched from one node in `wide_every` to save time; from every node until the group forms or its wait ends
            wide_until_m = path_m[k] + s.group_span_m
        opt_s = 0.0
        group = [c for c in accepted if c.in_group]
        for cand in accepted:
            cand.loop_id = graph.add_loop(cand.anchor, cand.node, cand.relative, cand.covariance)
            by_loop[cand.loop_id] = cand
        if group:  # a correction: the whole graph with it, kept only if the closures before it still hold
            opt_s, _ = _try_group(graph, by_loop, group, s, k)
        else:
            graph.update()
            if k % REFRESH_EVERY == 0:
                t1 = time.perf_counter()
                graph.refresh()
                if _prune(graph, by_loop, s.prune_m, s.prune_rad):
                    graph.update()
                    graph.refresh()
                opt_s = time.perf_counter() - t1
        untied = [cand for cand in tying if cand.status != ACCEPTED]
        for cand in untied:  # pruned or overruled since: no longer a tie between its node and its submap
            tied.remove_closure(cand.node, cand.anchor, path_m)
        if untied:
            tying = [cand for cand in tying if cand.status == ACCEPTED]
        for cand in accepted:
            if cand.status == ACCEPTED and not cand.along_line:  # a corridor match leaves the place along it open: no tie
                tied.add_closure(cand.node, cand.anchor, path_m)
                tying.append(cand)
        if tracker.whole:
            on_map[k] = tracker.online
            redraw = redraw_poses(graph.poses[: k + 1], on_map[: k + 1], laid, s.redraw_frame, s.redraw_m, s.redraw_rad)
            if redraw is not None:
                # the graph moved the robot away from where the online map has it: draw that map again from the graph
                t1 = time.perf_counter()
                on_map[: k + 1], laid = redraw
                d = se2_between(tracker.online, on_map[k])
                log.debug("node %d: the graph moved the robot %.2f m, %.1f deg from the online map: redrawn", k, float(np.hypot(d[0], d[1])), float(np.degrees(d[2])))
                tracker.redraw((points(i) for i in step_scans[: k + 1]), on_map[: k + 1])
                opt_s += time.perf_counter() - t1
        causal[k] = tracker.online if tracker.whole else graph.poses[k]
        rows["closures"].append(len(accepted))
        rows["optimise_s"].append(opt_s)
        rows["step_time_s"].append(time.perf_counter() - t0)
        if progress is not None and progress(len(scans) if k == n_steps - 1 else int(si) + 1, len(scans)):
            if k < n_steps - 1:
                n_steps, step_scans = k + 1, step_scans[: k + 1]
                causal, path_m = causal[:n_steps], path_m[:n_steps]
                scans, times, odom = scans[: si + 1], times[: si + 1], odom[: si + 1]
            break
    verifier.flush()
    graph.update()
    final_s = _optimise(graph, by_loop, s.prune_m, s.prune_rad) if graph.loops else 0.0
    give_back_library_pages("gtsam")  # its last use in this run: nothing after reads the graph
    smooth = graph.poses.copy()
    if between is not None:
        between = between[: len(odom)]
    trajectory = fill_between_steps(step_scans, smooth, odom, between)
    map_mb = tracker.memory_mb()
    tracker.drop_online_map()
    submaps.release()
    release_freed_memory()  # what the online map, the submaps and the steps freed, before the final maps are drawn
    if s.final_match and between is not None:  # every scan matched once more on the map of the optimised nodes (`final_match`)
        t1 = time.perf_counter()
        trajectory = match_on_final_map(trajectory, step_scans, points, project, matcher, ms, s.wall_at == "hits")
        final_match_s = time.perf_counter() - t1
    else:
        final_match_s = 0.0
    runtime = time.perf_counter() - t_loop  # the filter's work: every step, the last optimisation and the final match
    final_map = map_from_trajectory(sequence, trajectory, ms, scan_indices=step_scans)  # every node's scan at its smoothed pose
    steps = Table({
        "step": np.arange(n_steps),
        "scan_index": np.array([scans[i].index for i in step_scans], dtype=np.int64),
        "t": times[step_scans],
        "neff": np.ones(n_steps),
        "resampled": np.zeros(n_steps, dtype=bool),
        "best_weight": np.ones(n_steps),
        **{k: np.asarray(v) for k, v in rows.items()},
    })
    status = [cand.status for cand in candidates]
    return SlamResult(
        times=times,
        trajectory=trajectory,
        causal=fill_between_steps(step_scans, causal, odom, between),
        odometry=se2_compose(start, se2_between(odom[step_scans[0]], odom)),
        log_odds=final_map,
        steps=steps,
        particles=1,
        resample_count=0,
        runtime_s=runtime,
        fill="odometry" if between is None else "match",
        first_scan_xy=None if first_scan is None else first_scan[0],
        first_scan_origin=None if first_scan is None else first_scan[1],
        extras={
            "mode": c.mode,
            "processed_steps": n_steps,
            "step_scans": step_scans,
            "neff_mean": 1.0,
            "neff_min": 1.0,
            "filter": f.name,
            "odometry_jumps": plan.jumps_up_to(len(odom)),
            "thin_scans": plan.thin_up_to(n_steps),
            "matcher_map_reads": int(matcher.map_reads) + (int(tracker.step_matcher.map_reads) if tracker.step_matcher is not matcher else 0),
            "map_mb": map_mb,
            "map_peak_mb": submaps.peak_mb,
            "graph": {
                "nodes": int(graph.n),
                "submaps": len(submaps.anchors),
                "searches": int(search.searches),
                "search_bounds": int(search.nodes_scored),
                "candidates": len(candidates),
                "accepted": sum(st == ACCEPTED for st in status),
                "rejected": sum(st != ACCEPTED for st in status),
                "by_status": {st: status.count(st) for st in sorted(set(status))},
                "optimisations": len(graph.optimisations),
                "optimise_s": float(sum(o.seconds for o in graph.optimisations)),
                "update_s": float(graph.update_seconds),
                "redraws": int(tracker.redraws),
                **({"local_checks_taken": int(tracker.checks_taken)} if s.local_check_rad > 0 and s.local_map == "map" else {}),
                **({"local_turns_held": int(tracker.turns_held)} if s.local_weak_fit > 0 and s.local_map == "map" else {}),
                **({"yaw_drift_rad_per_m": float(tracker.yaw_drift)} if s.yaw_drift_gain_per_m > 0 else {}),
                "largest_correction_m": float(max([o.moved_max_m for o in graph.optimisations if not o.taken_back], default=0.0)),
                "final_optimise_s": final_s,
                "final_match_s": final_match_s,
                "search_s": float(search.seconds),
                "screened": int(search.screened),
                "screen_s": float(search.screen_seconds),
            },
            "loop_candidates": candidates,
            "loops": closures_table(candidates, graph, times[step_scans], smooth),
        },
    )


class TiedSubmaps:
    """How far (m of path) node k is from each finished submap's anchor since the two were
    last tied: the path between them, or through an accepted closure c (the path from c's
    node to k plus the path between c's anchor and the submap's), whichever is shorter.
    d_j(k) = path(k) + min(-path(anchor_j), min_c (|path(anchor_c) - path(anchor_j)| - path(node_c))),
    whose second term does not depend on k: it is kept per submap and lowered as closures come."""

    def __init__(self) -> None:
        self.anchor_path = np.zeros(0)  # path (m) at each finished submap's anchor
        self.best = np.zeros(0)  # min over the terms above but path(k)
        self.closures: list[tuple[float, float]] = []  # (path at node, path at anchor) of each accepted closure

    def add_submap(self, anchor: int, path_m: FloatArray) -> None:
        pa = float(path_m[anchor])
        b = -pa
        if self.closures:
            c = np.array(self.closures)
            b = min(b, float(np.min(np.abs(c[:, 1] - pa) - c[:, 0])))
        self.anchor_path = np.append(self.anchor_path, pa)
        self.best = np.append(self.best, b)

    def add_closure(self, node: int, anchor: int, path_m: FloatArray) -> None:
        pn, pa = float(path_m[node]), float(path_m[anchor])
        self.closures.append((pn, pa))
        np.minimum(self.best, np.abs(pa - self.anchor_path) - pn, out=self.best)

    def remove_closure(self, node: int, anchor: int, path_m: FloatArray) -> None:
        """An accepted closure taken out again (`_overrule`): every submap's term recomputed
        from the closures that remain."""
        self.closures.remove((float(path_m[node]), float(path_m[anchor])))
        self.best = -self.anchor_path
        if self.closures:
            c = np.array(self.closures)
            terms = np.abs(c[:, 1][None, :] - self.anchor_path[:, None]) - c[:, 0][None, :]
            self.best = np.minimum(self.best, terms.min(axis=1))

    def drift(self, k: int, path_m: FloatArray) -> FloatArray:
        """(S,) the distance for node k to each finished submap (m)."""
        return path_m[k] + self.best


def _search_loops(k: int, query: FloatArray, own: FloatArray, origin: FloatArray, submaps: Submaps, graph: PoseGraph, search: LoopSearch,
                  policy: WindowPolicy, drift_m: FloatArray, wide_every: int) -> list[LoopCandidate]:
    """Node k's loop candidates in the finished submaps within their windows (`drift_m` (S,):
    each submap's `TiedSubmaps` distance): the `query` points (node k's frame: its last metres
    of scans, `LocalSlam.query`) searched and refined, node k's `own` scan points (seen from
    `origin`) checked against the submap's free space. A wide window (over WIDE_M or WIDE_RAD:
    tens of times the work of a narrow one) is searched only from every `wide_every`-th node."""
    anchors = submaps.finished_anchor
    poses = graph.poses
    windows = policy.at(drift_m)
    wide = (windows[:, 0] > WIDE_M) | (windows[:, 1] > WIDE_RAD)
    if k % wide_every:  # wide searches (a long loop's return) only from every `wide_every`-th node
        windows = windows[~wide]
        keep = np.flatnonzero(~wide)
        screen = None
    else:
        keep = np.arange(len(anchors))
        screen = query if wide.any() else None
    reach = search.submaps_in_reach(poses[k], submaps, poses[anchors[keep]], windows, drift_m[keep], keep, screen)
    return search.search(k, poses[k], query, own, origin, submaps, reach, poses)


def closures_table(candidates: list[LoopCandidate], graph: PoseGraph, node_times: FloatArray, final: FloatArray) -> Table:
    """loops.csv (docs/RUN_DIRECTORY.md): one row per loop candidate the search found, in the
    order found. t and t_anchor (s): the node's and the submap anchor's scan times; status
    (`loops.py`'s statuses: accepted, ambiguous, weak, edge, inconsistent, pruned, refuted,
    overruled); the scores; window_m and tied_m;
    node_x/y (m): the node's estimate when searched; match_x/y: where the match put it then;
    moved_m: how far it asked the node to move; final_x/y and anchor_x/y: the node's and the
    anchor's optimised positions (the closure drawn on the map); residual_m: how far the
    final graph is from it; sigma_along_m: its largest translation sigma (a corridor's length);
    see_through and free_ends: the shares of the node's beams that, at the match, pass through
    the submap's walls or end where it saw free space."""
    if not candidates:
        return Table({})
    nodes = np.array([c.node for c in candidates])
    anchors = np.array([c.anchor for c in candidates])
    rel = np.array([c.relative for c in candidates])
    implied = se2_compose(final[anchors], rel)
    residual = np.hypot(implied[:, 0] - final[nodes, 0], implied[:, 1] - final[nodes, 1])
    node_pose = np.array([c.node_pose for c in candidates])
    match_pose = np.array([c.match_pose for c in candidates])
    return Table({
        "t": node_times[nodes], "node": nodes, "submap": np.array([c.submap for c in candidates]), "anchor": anchors,
        "t_anchor": node_times[anchors], "status": np.array([c.status for c in candidates]),
        "score": np.array([c.score for c in candidates]), "refined": np.array([c.refined for c in candidates]),
        "second": np.array([c.second for c in candidates]), "window_m": np.array([c.window_m for c in candidates]),
        "tied_m": np.array([c.tied_m for c in candidates]),
        "node_x": node_pose[:, 0], "node_y": node_pose[:, 1], "match_x": match_pose[:, 0], "match_y": match_pose[:, 1],
        "moved_m": np.hypot(match_pose[:, 0] - node_pose[:, 0], match_pose[:, 1] - node_pose[:, 1]),
        "final_x": final[nodes, 0], "final_y": final[nodes, 1], "anchor_x": final[anchors, 0], "anchor_y": final[anchors, 1],
        "residual_m": residual, "sigma_along_m": np.array([float(np.sqrt(sym_eig(np.ascontiguousarray(c.covariance[:2, :2]))[0][-1])) for c in candidates]),
        "see_through": np.array([c.see_through for c in candidates]), "free_ends": np.array([c.free_ends for c in candidates]),
    })


def redraw_poses(graph_poses: FloatArray, on_map: FloatArray, laid: FloatArray, frame: str, m: float,
                 rad: float) -> tuple[FloatArray, FloatArray] | None:
    """Where to draw the online map again, nodes 0..K-1 ((K, 3)), with the rigid motion that
    lays the graph's frame on the online map's from then on; or None to keep the map. It is
    drawn again when the graph's estimate `graph_poses` (K, 3), moved by `laid` (the motion the
    last redraw took; zeros before any), puts the newest node `m` metres or `rad` away from
    where the online map has it (`on_map`, (K, 3): each node's pose on that map as it is now).
    `frame` (`filter.redraw_frame`): `graph` draws it at the graph's poses, in the graph's own
    frame (its first node fixed; `laid` stays zero); `online` at the graph's poses moved by the
    one rigid motion that best lays every node on the online map (least squares over
    positions): the map takes the graph's shape but keeps its place, so the online path moves
    by what the graph bent and not by a turn of the whole map (an early heading error that the
    graph undid about the start)."""
    if frame == "graph":
        return (graph_poses.copy(), laid) if _apart(graph_poses[-1], on_map[-1], m, rad) else None
    if not _apart(se2_compose(laid, graph_poses[-1]), on_map[-1], m, rad):
        return None
    laid = se2_fit(graph_poses[:, :2], on_map[:, :2])
    return se2_compose(laid, graph_poses), laid


def _apart(a: FloatArray, b: FloatArray, m: float, rad: float) -> bool:
    """Whether poses a and b differ by more than m metres or rad radians."""
    d = se2_between(a, b)
    return bool(np.hypot(d[0], d[1]) > m or abs(d[2]) > rad)


def _try_group(graph: PoseGraph, by_loop: dict[int, LoopCandidate], group: list[LoopCandidate], s, k: int
               ) -> tuple[float, list[LoopCandidate]]:
    """A group of closures asking for a correction, already added to the graph: the whole
    graph optimised with them, the group first taken in as it says (`PoseGraph.optimise_batch`
    with the group trusted: under the robust loss alone a correction of a metre or more stays
    open, held by the path and the closures that hold its drifted shape). If that leaves more
    than REFUTE_SHARE of the closures the graph held before (at least REFUTE_MIN) far off,
    the group contradicts what the graph already knew (a corridor matched a few doors off,
    consistently): its closures are taken out (status `refuted`) and the estimate goes back.
    Otherwise the closures the optimum leaves far off are pruned as usual.

    Taken in first, a large correction can leave earlier closures far off that agree with it:
    the first run bends the path its own way, and the robust loss then weighs the earlier
    closures, now metres off, at almost nothing (the hospital log: a return to the start
    7 m off, taken in, left the top-left corridor's closure of 210 s earlier 7 m off, and the
    corridor stayed doubled). So when it leaves any far off, the group and those closures are
    tried together, all taken in as they say, from the estimate before the group: if that
    leaves none of them far off, it stands.

    Before a refutation, the group is tried against the earlier groups it contradicts
    (`_overrule`). Returns seconds and the closures the group overruled."""
    t0 = time.perf_counter()
    ids = {c.loop_id for c in group}
    before = np.array([j for j in np.flatnonzero(graph.active) if j not in ids], dtype=np.int64)
    kept = graph.poses.copy()
    trials = len(graph.optimisations)
    graph.optimise_batch(trusted=ids)
    off = before[graph.loops_off(before, s.prune_m, s.prune_rad)]
    if len(off):
        alone = graph.poses.copy()
        graph.restore(kept)
        together = np.concatenate([np.array(sorted(ids), dtype=np.int64), off])
        graph.optimise_batch(trusted=set(together.tolist()))
        if graph.loops_off(together, s.prune_m, s.prune_rad).any():
            graph.restore(alone, taken_back=1)
        else:
            log.debug("node %d: a group of %d closures in with the %d earlier closures it left off alone", k, len(group), len(off))
            off = off[:0]
    broken = len(off)
    overruled: list[LoopCandidate] = []
    if broken > max(REFUTE_MIN, REFUTE_SHARE * len(before)):
        overruled = _overrule(graph, by_loop, group, off, before, kept, trials, s, k)
    if broken > max(REFUTE_MIN, REFUTE_SHARE * len(before)) and not overruled:
        for c in group:
            graph.drop_loop(c.loop_id)
            c.status = REFUTED
        graph.restore(kept, taken_back=len(graph.optimisations) - trials)
        log.debug("node %d: a group of %d closures refuted: %d of %d earlier closures would break", k, len(group), broken, len(before))
    else:
        _prune_and_reoptimise(graph, by_loop, s.prune_m, s.prune_rad)
        log.debug("node %d: a group of %d closures in (%d earlier closures off)", k, len(group), broken)
    return time.perf_counter() - t0, overruled


def _overrule(graph: PoseGraph, by_loop: dict[int, LoopCandidate], group: list[LoopCandidate], off: np.ndarray,
              before: np.ndarray, kept: FloatArray, since: int, s, k: int) -> list[LoopCandidate]:
    """A group that would be refuted because it leaves the closures `off` far off, tried
    against the earlier groups among them: the largest set of mutually consistent closures
    wins (Mangelson et al. 2018), so an earlier group of closures from fewer nodes that the
    new group contradicts, where nothing else does, was the mistake. The trial: those groups
    taken out whole, the graph optimised from `kept` (the estimate before the new group) with
    the new group taken in as it says; it stands when that leaves no more of the other
    earlier closures far off than a refutation allows (a corridor match counted only across
    its corridor and in yaw: it says nothing along it), and the groups' closures become
    `overruled`. Otherwise everything goes back as it was and the caller refutes the new
    group. Why: a group formed from two metres of a first pass down a corridor, into an older
    pass of the other half of that corridor (the true place not mapped yet, so no second best
    could show the alias), held a simulated short-range lidar's map 16 m off to the end; the
    groups that came back to the true place were each refuted for breaking it (sim_carmen.py
    `--lidar urg`, world 1, 0.25 m steps). `since`: how many optimisations the graph had before
    the new group's first trial (those after it are discarded here: marked taken back). Returns
    the closures it overruled (none: it did not)."""
    rivals = {by_loop[int(j)].group for j in off if by_loop[int(j)].in_group}
    if not rivals:
        return []
    theirs = np.array([j for j in before if by_loop[int(j)].in_group and by_loop[int(j)].group in rivals], dtype=np.int64)
    if len({c.node for c in group}) <= len({by_loop[int(j)].node for j in theirs}):
        return []  # the earlier groups hold as many nodes: the new one does not outweigh them
    trials = len(graph.optimisations)
    for j in theirs:
        graph.drop_loop(int(j))
    graph.restore(kept, taken_back=len(graph.optimisations) - since)  # the new group's trials so far are discarded
    graph.optimise_batch(trusted={c.loop_id for c in group})
    rest = np.setdiff1d(before, theirs)
    along = np.array([by_loop[int(j)].along_line for j in rest], dtype=bool)
    still = int(graph.loops_off(rest, s.prune_m, s.prune_rad, free_along=along).sum())
    if still > max(REFUTE_MIN, REFUTE_SHARE * len(rest)):
        for j in theirs:
            graph.revive_loop(int(j))
        graph.restore(kept, taken_back=len(graph.optimisations) - trials)
        log.debug("node %d: a group of %d closures cannot overrule groups %s: %d other closures would break", k, len(group), sorted(rivals), still)
        return []
    for j in theirs:
        by_loop[int(j)].status = OVERRULED
    log.debug("node %d: a group of %d closures overrules %d closures of groups %s (%d other closures off)", k, len(group), len(theirs), sorted(rivals), still)
    return [by_loop[int(j)] for j in theirs]


def _prune(graph: PoseGraph, by_loop: dict[int, LoopCandidate], prune_m: float, prune_rad: float) -> bool:
    """Drop the closures the estimate leaves more than prune_m / prune_rad off (their
    candidates' status becomes `pruned`); whether any was dropped."""
    active = np.flatnonzero(graph.active)
    off = active[graph.loops_off(active, prune_m, prune_rad)]
    if len(off):
        for loop in off:
            graph.drop_loop(int(loop))
            by_loop[int(loop)].status = PRUNED
    return bool(len(off))


def _optimise(graph: PoseGraph, by_loop: dict[int, LoopCandidate], prune_m: float, prune_rad: float) -> float:
    """The whole graph by Levenberg-Marquardt; then drop the closures the optimum leaves far
    off and optimise again while any were dropped (at most three times). Returns the seconds
    spent."""
    t0 = time.perf_counter()
    graph.optimise_batch()
    _prune_and_reoptimise(graph, by_loop, prune_m, prune_rad)
    return time.perf_counter() - t0


def _prune_and_reoptimise(graph: PoseGraph, by_loop: dict[int, LoopCandidate], prune_m: float, prune_rad: float) -> None:
    """After an optimisation: drop the closures it leaves far off (`_prune`) and optimise
    again while any were dropped, at most three times."""
    for _ in range(3):
        if not _prune(graph, by_loop, prune_m, prune_rad):
            break
        graph.optimise_batch()
