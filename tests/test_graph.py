"""filter=graph: the branch-and-bound search is exact, wrong closures cannot bend the map, the
online poses do not depend on the future, and a run is reproducible to the byte.

The end-to-end tests drive the graph filter on a simulated CARMEN log of the `loops` building
at 3x (benchmarks/sim_carmen.py: 656 m, two loops, wheel odometry drifting by a hundred metres),
where local SLAM alone ends up metres off and only loop closures keep the map together."""

from __future__ import annotations

import contextlib
import dataclasses
import importlib.util
import math
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from slamlab.assemble import build_components
from slamlab.datasets.carmen import load_carmen
from slamlab.errors import ConfigError
from slamlab.eval.relations import relation_errors
from slamlab.geometry import se2_between, se2_compose
from slamlab.slam.engine import run_slam
from slamlab.slam.graph.branch_bound import NO_EXCLUSION, CorrelativeSearch, SearchGrid, SearchWindow, bnb_search, exhaustive_search, max_pool_levels, place_points, top_bounds
from slamlab.slam.graph.loops import ACCEPTED, EDGE, OVERRULED, PENDING, PRUNED, REFUTED, LoopCandidate, LoopSearch, SearchSettings, at_window_edge
from slamlab.slam.graph.pose_graph import GraphNoise, PoseGraph
from slamlab.slam.graph.submaps import search_grid_of
from slamlab.slam.grid import OccupancyGrid
from slamlab.slam.graph.run import _try_group, redraw_poses
from slamlab.slam.graph.verify import ClosureVerifier, VerifySettings, consistency_matrix, max_clique, shortest_paths, tied_distances
from test_slam_engine import _cfg

_spec = importlib.util.spec_from_file_location("sim_carmen", Path(__file__).resolve().parents[1] / "benchmarks" / "sim_carmen.py")
sim_carmen = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(sim_carmen)

GRAPH = ("+experiment=lidar2d", "filter=graph", "dataset.path=unused")


# ---- branch and bound ------------------------------------------------------------------------
def _random_case(rng: np.random.Generator):
    H, W = (int(v) for v in rng.integers(5, 60, 2))
    grid = (rng.random((H, W)) ** 3 * 255).astype(np.uint8)
    if rng.random() < 0.3:
        grid = (grid > 200).astype(np.uint8) * 255  # few values: many ties
    pts = rng.normal(0.0, 1.0, (int(rng.integers(1, 30)), 2)) * rng.uniform(0.1, 2.0)
    yaws = rng.uniform(-3.0, 3.0, int(rng.integers(1, 6)))
    rows, cols = place_points(pts, W * 0.025, H * 0.025, yaws, 0.0, 0.0, 20.0)
    return grid, rows, cols, int(rng.integers(0, 20)), int(rng.integers(0, 20)), int(rng.integers(1, 7))


def test_branch_and_bound_returns_the_exhaustive_searchs_best_on_random_maps_and_scans():
    rng = np.random.default_rng(1)
    for _ in range(300):
        grid, rows, cols, wx, wy, levels = _random_case(rng)
        pool = max_pool_levels(grid, levels)
        score, k, dx, dy, _ = bnb_search(pool, rows, cols, wx, wy, 0, NO_EXCLUSION, top_bounds(pool, rows, cols, wx, wy))
        # the same candidate (ties go to the smallest yaw index, then dx, then dy) and the
        # same integer score, bit for bit
        assert (score, k, dx, dy) == exhaustive_search(grid, rows, cols, wx, wy)


def test_branch_and_bound_shared_out_gives_one_searchs_answer_and_its_bound_count_on_any_thread_count(monkeypatch):
    """A wide search's top nodes are dealt to `BNB_SHARES` searches run side by side: the same
    candidate as one search (and the exhaustive one, when it reaches the minimum score); their
    number is fixed, so one thread gives what all give, bounds counted included."""
    import numba

    from slamlab.slam.graph import branch_bound

    rng = np.random.default_rng(6)
    threads = numba.get_num_threads()
    for _ in range(100):
        grid, rows, cols, wx, wy, levels = _random_case(rng)
        pool = max_pool_levels(grid, levels)
        tb = top_bounds(pool, rows, cols, wx, wy)
        full = exhaustive_search(grid, rows, cols, wx, wy)
        min_score = int(full[0] * rng.uniform(0.5, 1.2))
        one = bnb_search(pool, rows, cols, wx, wy, min_score, NO_EXCLUSION, tb)  # these windows: one search
        assert one[:4] == (full if full[0] >= min_score else (-1, -1, 0, 0))
        monkeypatch.setattr(branch_bound, "SHARED_TOP_NODES", 0)  # every search shared out
        try:
            numba.set_num_threads(1)
            shared = bnb_search(pool, rows, cols, wx, wy, min_score, NO_EXCLUSION, tb)
        finally:
            numba.set_num_threads(threads)
        assert bnb_search(pool, rows, cols, wx, wy, min_score, NO_EXCLUSION, tb) == shared
        assert shared[:4] == one[:4] and shared[4] >= tb.shape[0]
        monkeypatch.undo()


def test_the_top_level_bounds_are_each_nodes_pooled_sum_whatever_the_thread_count():
    """`top_bounds` (on all cores): entry (k * nx + a) * ny + b is the top level's sum for yaw k
    at offsets (-wx + a * top, -wy + b * top), the same with one thread as with all."""
    import numba

    rng = np.random.default_rng(4)
    grid = (rng.random((70, 50)) * 255).astype(np.uint8)
    pts = rng.normal(0.0, 1.0, (40, 2))
    rows, cols = place_points(pts, 1.2, 1.8, rng.uniform(-3.0, 3.0, 9), 0.0, 0.0, 20.0)
    levels, wx, wy = 4, 37, 21
    pool = max_pool_levels(grid, levels)
    threads = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = top_bounds(pool, rows, cols, wx, wy)
    finally:
        numba.set_num_threads(threads)
    assert np.array_equal(top_bounds(pool, rows, cols, wx, wy), one)
    top, pad = 1 << (levels - 1), (1 << (levels - 1)) - 1
    nx, ny = (2 * wx) // top + 1, (2 * wy) // top + 1
    assert len(one) == len(rows) * nx * ny
    for q in rng.choice(len(one), 30, replace=False):
        k, a, b = q // (nx * ny), (q // ny) % nx, q % ny
        r, c = rows[k] - wy + b * top + pad, cols[k] - wx + a * top + pad
        inside = (r >= 0) & (r < pool.shape[1]) & (c >= 0) & (c < pool.shape[2])
        assert one[q] == int(pool[levels - 1, r[inside], c[inside]].astype(np.int64).sum())


def test_the_top_level_bounds_from_phase_planes_are_each_nodes_own_sum_on_random_maps_and_scans():
    """A wide window's top bounds come from the top level laid out in phase planes
    (`_top_bounds_planes`): the same integers as summing each node on its own
    (`_top_bounds_direct`), points off the grid on any side included, on one thread and all;
    `top_bounds` takes either path and gives the same."""
    import numba

    from slamlab.slam.graph import branch_bound

    rng = np.random.default_rng(9)
    threads = numba.get_num_threads()
    for _ in range(60):
        grid, rows, cols, wx, wy, levels = _random_case(rng)
        rows, cols = rows + int(rng.integers(-40, 40)), cols + int(rng.integers(-40, 40))  # scans partly or wholly off the grid
        pool = max_pool_levels(grid, levels)
        top = 1 << (levels - 1)
        direct = branch_bound._top_bounds_direct(pool, rows, cols, wx, wy)
        planes = branch_bound._phase_planes(pool[-1], top)
        assert np.array_equal(branch_bound._top_bounds_planes(planes, rows, cols, wx, wy, top), direct)
        try:
            numba.set_num_threads(1)
            assert np.array_equal(branch_bound._top_bounds_planes(planes, rows, cols, wx, wy, top), direct)
        finally:
            numba.set_num_threads(threads)
        assert np.array_equal(top_bounds(pool, rows, cols, wx, wy), direct)


def test_side_by_side_returns_each_jobs_result_in_order_on_any_thread_count():
    """`loops.side_by_side`: what the loop over the jobs gives, in the jobs' order, whether the
    jobs ran on several threads or one after the other on this one (fewer than two large jobs, or
    one numba thread: a sweep's parallel jobs)."""
    import threading

    import numba

    from slamlab.slam.graph.loops import side_by_side

    seen: set[int] = set()

    def work(job: int) -> int:
        seen.add(threading.get_ident())
        return job * job

    jobs = list(range(50))
    assert side_by_side(work, jobs) == [j * j for j in jobs]
    seen.clear()
    assert side_by_side(work, jobs, [0] * 49 + [10**9]) == [j * j for j in jobs]  # one large job: nothing to run beside it
    assert seen == {threading.get_ident()}
    threads = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        seen.clear()
        assert side_by_side(work, jobs) == [j * j for j in jobs]
        assert seen == {threading.get_ident()}  # one thread: here, in order
    finally:
        numba.set_num_threads(threads)


def test_side_by_side_in_a_forked_child_starts_its_own_threads():
    """A process that used `side_by_side`'s threads and then forks (a sweep's job runs in a
    forked child): the child has none of those threads, so it starts its own rather than hand
    jobs to a pool nobody serves (it would wait forever)."""
    import os
    import signal

    from slamlab.slam.graph import loops

    assert loops.side_by_side(abs, [-1, -2, -3]) == [1, 2, 3]  # the parent's pool (when numba has two threads)
    pid = os.fork()
    if pid == 0:  # the child: exit 0 when it gets the answer; killed below if it hangs
        code = 1
        try:
            code = 0 if loops.side_by_side(abs, [-4, -5]) == [4, 5] else 1
        finally:
            os._exit(code)
    for _ in range(200):  # up to 10 s
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            break
        time.sleep(0.05)
    else:
        os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)
        pytest.fail("the forked child's side_by_side hung")
    assert os.waitstatus_to_exitcode(status) == 0


@pytest.mark.parametrize("f", [1, 2, 3])
def test_a_submaps_search_grid_holds_the_largest_field_code_of_each_block_of_cells(f):
    """`search_grid_of`: the coarse grid's cell (i, j) is the max over map cells [f i, f i + f) x
    [f j, f j + f) (cells off the map: 0), the search's level 0, at each level's padding."""
    rng = np.random.default_rng(f)
    field_u8 = (rng.random((37, 23)) * 255).astype(np.uint8)
    grid = search_grid_of(field_u8, np.array([1.0, -2.0]), 0.05, 0.05 * f, 3)
    pad = (1 << 2) - 1
    level0 = grid.pool[0, pad:, pad:]
    assert level0.shape == (-(-37 // f), -(-23 // f)) and grid.resolution_m == pytest.approx(0.05 * f)
    for i in range(level0.shape[0]):
        for j in range(level0.shape[1]):
            assert level0[i, j] == field_u8[f * i:f * i + f, f * j:f * j + f].max()


def test_branch_and_bound_finds_a_scan_in_a_room_scoring_a_fraction_of_the_candidates():
    """A 20 x 20 m room with a partition (0.1 m cells), a scan of its walls from (6, 7) turned
    by 0.12 rad, searched over +-8 m and +-0.3 rad from (7, 6.5): found at its pose, bit for bit
    the exhaustive score, with a small share of the 6 million candidates scored."""
    grid = np.zeros((200, 200), dtype=np.uint8)
    grid[[0, 199], :] = 255
    grid[:, [0, 199]] = 255
    grid[60, 40:160] = 255
    grid[60:140, 120] = 255
    walls = np.argwhere(grid > 0)[::7] * 0.1 + 0.05  # (row, col) cell centres -> y, x
    xy = walls[:, ::-1]
    pose = np.array([6.0, 7.0, 0.12])
    c, s_ = math.cos(pose[2]), math.sin(pose[2])
    d = xy - pose[:2]
    pts = np.column_stack([c * d[:, 0] + s_ * d[:, 1], -s_ * d[:, 0] + c * d[:, 1]])  # in the body frame
    window = SearchWindow(np.array([7.0, 6.5, 0.0]), 8.0, 8.0, 0.3)
    search = CorrelativeSearch(SearchGrid.of(grid, (0.0, 0.0), 0.1, 7), pts, window, 0.01)
    best = search.best(0.5)
    assert best.found and np.allclose(best.pose, pose, atol=[0.1, 0.1, 0.006])
    full = exhaustive_search(grid, search.rows, search.cols, search.wx, search.wy)
    assert best.score_sum == full[0]
    candidates = len(search.yaws) * (2 * search.wx + 1) * (2 * search.wy + 1)
    assert best.nodes < candidates / 100


def test_the_second_best_search_leaves_out_the_box_around_the_best():
    rng = np.random.default_rng(3)
    grid = (rng.random((60, 60)) * 255).astype(np.uint8)
    pts = rng.normal(0.0, 0.8, (25, 2))
    window = SearchWindow(np.array([1.5, 1.5, 0.0]), 1.0, 1.0, 0.2)
    search = CorrelativeSearch(SearchGrid.of(grid, (0.0, 0.0), 0.05, 5), pts, window, 0.05)
    best = search.best(0.0)
    second = search.best_outside(best, 0.3, 0.1, 0.0)
    assert second.found and second.score <= best.score
    # the exhaustive best over the candidates outside the box is the one found
    ek, exy = int(math.floor(0.1 / 0.05)), int(math.floor(0.3 / 0.05))
    top = -1
    for k in range(len(search.yaws)):
        for dx in range(-search.wx, search.wx + 1):
            for dy in range(-search.wy, search.wy + 1):
                if abs(k - best.k) <= ek and abs(dx - best.dx) <= exy and abs(dy - best.dy) <= exy:
                    continue
                one = exhaustive_search(grid, search.rows[k:k + 1] + dy, search.cols[k:k + 1] + dx, 0, 0)[0]
                top = max(top, one)
    assert second.score_sum == top


# ---- which submaps a node searches --------------------------------------------------------------
def _finished(views: list[tuple[float, float]], centres: list[tuple[float, float]], radii: list[float]) -> SimpleNamespace:
    """Finished submaps as `LoopSearch.submaps_in_reach` reads them, each in the global frame
    (anchor local pose = identity): where each was seen from, and its known area's circle."""
    n = len(views)
    return SimpleNamespace(finished=[f"submap {i}" for i in range(n)], finished_anchor_local=np.zeros((n, 3)),
                           finished_view=np.array(views, dtype=float), finished_center=np.array(centres, dtype=float),
                           finished_radius=np.array(radii, dtype=float))


def _reach(submaps: SimpleNamespace, pose, tied_m) -> list[str]:
    search = LoopSearch(SearchSettings(0.1, 6, 0.55, 0.5, 0.9, 1.0, 0.35, 2, 30.0), 0.05, 4, 0.03, 0.01)
    n = len(submaps.finished)
    windows = np.tile([5.0, 0.5], (n, 1))
    found = search.submaps_in_reach(np.asarray(pose, dtype=float), submaps, np.zeros((n, 3)), windows, np.asarray(tied_m, dtype=float))
    return [sm for sm, *_ in found]


def test_a_junction_seen_from_nearby_is_searched_beside_a_corridor_submap_whose_area_is_nearer():
    # the robot at (20, 0) in a corridor along x. Submap 0: the corridor, seen from x = 0..4 with 30 m
    # beams: its known area's centre is at x = 15. Submap 1: the junction, seen from (20, 4), its area
    # centred at (20, 10). Submap 2: the robot's own, a few metres back (tied to it)
    corridor_junction_own = _finished([(2, 0), (20, 4), (18, 0)], [(15, 0), (20, 10), (26, 0)], [16, 12, 15])
    assert _reach(corridor_junction_own, (20, 0, 0), [200, 200, 5]) == ["submap 1", "submap 0", "submap 2"]
    # one submap nearest both ways: one loop candidate, then the nearest other
    assert _reach(corridor_junction_own, (20, 0, 0), [200, 5, 5]) == ["submap 0", "submap 2"]
    # no loop candidate (everything tied lately): the nearest max_submaps - 1
    assert _reach(corridor_junction_own, (20, 0, 0), [5, 5, 5]) == ["submap 0"]
    # out of every window: nothing
    assert _reach(corridor_junction_own, (200, 0, 0), [200, 200, 5]) == []


# ---- verification -----------------------------------------------------------------------------
def _closure(node: int, anchor: int, poses: np.ndarray, error=(0.0, 0.0, 0.0)) -> LoopCandidate:
    rel = se2_compose(se2_between(poses[anchor], poses[node]), np.asarray(error, dtype=float))
    return LoopCandidate(node=node, submap=0, anchor=anchor, relative=rel, score=0.9, refined=0.9, second=0.0, window_m=5.0,
                         node_pose=poses[node], match_pose=poses[node], covariance=np.diag([1e-3, 1e-3, 1e-4]), tied_m=100.0)


def test_closures_that_agree_form_a_clique_and_a_wrong_one_stays_out():
    poses = np.column_stack([np.arange(100) * 0.5, np.zeros(100), np.zeros(100)])
    s = VerifySettings(0.1, 0.02, 30.0, 3, 8.0, 20.0, 0.3, 0.02, 0.05, 0.002, group_submaps=1)
    path = np.arange(100) * 0.5
    good = [_closure(n, a, poses) for n, a in ((80, 10), (84, 12), (90, 14), (95, 20))]
    wrong = _closure(88, 13, poses, (2.0, 0.0, math.radians(20)))
    ok = consistency_matrix(good + [wrong], poses, path, s)
    assert ok[:4, :4].all() and not ok[4, :4].any()
    assert max_clique(ok) == [0, 1, 2, 3]


def test_corridor_matches_enter_as_their_own_group_when_too_few_full_matches_back_them():
    # down a corridor along x the estimate is 0.5 m off across it; two full matches and three corridor matches
    # (nothing pinned along x) all say so. Two full matches are too few to move the robot: the corridor matches
    # enter alone (they ask only for what they pin), the full ones wait for a third
    poses = np.column_stack([np.arange(100) * 0.5, np.zeros(100), np.zeros(100)])
    path = np.arange(100) * 0.5
    s = VerifySettings(0.1, 0.02, 30.0, 3, 2.0, 20.0, 0.3, 0.02, 0.05, 0.002, group_submaps=1)  # every match in one submap
    def cands(full_nodes):
        out = [_closure(n, 10, poses, (0.0, 0.5, 0.0)) for n in full_nodes]
        for n in (86, 90, 94):
            c = _closure(n, 10, poses, (0.0, 0.5, 0.0))
            c.covariance, c.along_line = np.diag([100.0, 1e-3, 1e-4]), True
            out.append(c)
        return out
    two = cands((80, 84))
    entered = ClosureVerifier(s).offer(two, 94, poses, path)
    assert [c.node for c in entered] == [86, 90, 94] and all(c.in_group for c in entered)
    assert [c.status for c in two[:2]] == [PENDING, PENDING]
    three = cands((78, 80, 84))
    entered = ClosureVerifier(s).offer(three, 94, poses, path)
    assert sorted(c.node for c in entered) == [78, 80, 84, 86, 90, 94]


def test_a_group_enters_once_its_matches_are_in_two_submaps():
    # four scans in a row matched in one old submap, each asking the same 3 m move along the corridor (x): one
    # submap seen a period off agrees with itself, so they wait. A match in another submap that agrees lets them in
    poses = np.column_stack([np.arange(100) * 0.5, np.zeros(100), np.zeros(100)])
    path = np.arange(100) * 0.5
    s = VerifySettings(0.1, 0.02, 30.0, 3, 2.0, 20.0, 0.3, 0.02, 0.05, 0.002, group_submaps=2)
    one_submap = [_closure(n, 10, poses, (3.0, 0.0, 0.0)) for n in (80, 82, 84, 86)]
    verifier = ClosureVerifier(s)
    assert verifier.offer(one_submap, 86, poses, path) == []
    assert all(c.status == PENDING for c in one_submap)
    other = _closure(88, 30, poses, (3.0, 0.0, 0.0))
    other.submap = 1
    entered = verifier.offer([other], 88, poses, path)
    assert sorted(c.node for c in entered) == [80, 82, 84, 86, 88] and all(c.in_group for c in entered)
    again = [_closure(n, 10, poses, (3.0, 0.0, 0.0)) for n in (80, 82, 84, 86)]
    assert len(ClosureVerifier(dataclasses.replace(s, group_submaps=1)).offer(again, 86, poses, path)) == 4


def test_a_closure_ties_two_far_places_of_the_path_together():
    path = np.arange(200) * 1.0
    far = tied_distances(path, np.zeros((0, 2)), np.array([10, 190]))
    tied = tied_distances(path, np.array([[12, 188]]), np.array([10, 190]))
    assert far[0, 1] == pytest.approx(180.0) and tied[0, 1] == pytest.approx(4.0, abs=1e-6)


@pytest.mark.parametrize("seed", range(6))
def test_shortest_paths_equal_scipys_dijkstra_bit_for_bit(seed):
    """`shortest_paths` (the standard library's heap) gives SciPy's distances to the last bit, on
    graphs like the verifier's (a path of uneven steps with near-free ties across it) and on
    random ones with parallel edges, isolated nodes and unreachable parts."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import dijkstra

    rng = np.random.default_rng(seed)
    n = int(rng.integers(4, 300))
    if seed % 2 == 0:  # the verifier's graphs: consecutive key nodes along the path, ties of 1e-9
        steps = rng.uniform(0.0, 50.0, n - 1) * (rng.random(n - 1) > 0.1)
        a, b, w = np.arange(n - 1), np.arange(1, n), np.maximum(steps, 1e-9)
        t = rng.integers(0, n, (int(rng.integers(0, n)), 2))
        a, b, w = np.concatenate([a, t[:, 0]]), np.concatenate([b, t[:, 1]]), np.concatenate([w, np.full(len(t), 1e-9)])
    else:  # random weights, some pairs joined twice, some nodes joined to nothing
        m = int(rng.integers(0, 3 * n))
        a, b, w = rng.integers(0, n - 2, m), rng.integers(0, n - 2, m), rng.exponential(3.0, m) * rng.uniform(0.5, 2.0, m)
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    order = np.lexsort((w, hi, lo))  # as tied_distances does: one edge per pair, the cheapest (SciPy would add them up)
    lo, hi, w = lo[order], hi[order], w[order]
    first = np.ones(len(lo), dtype=bool)
    first[1:] = (lo[1:] != lo[:-1]) | (hi[1:] != hi[:-1])
    keep = first & (lo != hi)
    lo, hi, w = lo[keep], hi[keep], w[keep]
    sources = rng.choice(n - 2, size=min(n - 2, 7), replace=False)  # the last two nodes are no source
    ours = shortest_paths(n, lo, hi, w, sources)
    theirs = dijkstra(csr_matrix((w, (lo, hi)), shape=(n, n)), directed=False, indices=sources)
    assert np.array_equal(ours, theirs)  # inf where unreachable on both
    assert seed % 2 == 0 or np.isinf(ours[:, -2:]).all()  # the random graphs' last two nodes are joined to nothing


# ---- the pose graph ---------------------------------------------------------------------------
def _square_loop() -> np.ndarray:
    """(165, 3) true poses around an 80 m square: 40 steps of 0.5 m a side, then a quarter turn on the spot."""
    truth = [np.zeros(3)]
    for _side in range(4):
        for _ in range(40):
            truth.append(se2_compose(truth[-1], np.array([0.5, 0.0, 0.0])))
        truth.append(se2_compose(truth[-1], np.array([0.0, 0.0, math.pi / 2])))
    return np.array(truth)


def test_a_wrong_closure_added_on_purpose_barely_moves_the_optimised_trajectory():
    """A square loop with noisy local edges and correct closures; one closure 2 m and 20 deg
    off, added to the same graph, moves no node by more than 2 cm (the robust loss)."""
    rng = np.random.default_rng(4)
    truth = _square_loop()
    noise = GraphNoise(0.01, 0.02, 0.005, 0.02, 0.03, 0.01, "cauchy", 1.0)

    def graph(wrong: bool) -> np.ndarray:
        g = PoseGraph(truth[0], noise)
        for k in range(1, len(truth)):
            g.add_node(se2_compose(se2_between(truth[k - 1], truth[k]), rng_steps[k - 1]))
        for a, n in ((0, 160), (5, 150), (40, 120), (2, 162)):
            g.add_loop(a, n, se2_between(truth[a], truth[n]))
        if wrong:
            g.add_loop(60, 100, se2_compose(se2_between(truth[60], truth[100]), np.array([2.0, 0.0, math.radians(20)])))
        g.update()
        g.optimise_batch()
        return g.poses.copy()

    rng_steps = rng.normal(0.0, [0.01, 0.01, 0.004], (len(truth) - 1, 3))
    without, with_wrong = graph(False), graph(True)
    assert np.hypot(*(without[:, :2] - truth[:, :2]).T).max() < 0.2  # the loop closed
    assert np.hypot(*(with_wrong[:, :2] - without[:, :2]).T).max() <= 0.02


def test_a_group_of_closures_closes_a_loop_the_robust_loss_alone_would_leave_open():
    """A square loop (80 m) whose local edges slip 3 cm sideways a step on its first two sides
    ends 1.7 m from its start; closures between nodes 10 steps apart along the way hold that
    drifted shape (as matches into recent submaps built on the drifted path do). Four mutually
    consistent closures back to the start (a verified group) ask for the correction. Under the
    robust loss, closures 50 sigmas off weigh less than the path and the closures holding it,
    so Levenberg-Marquardt from the estimate leaves them off (they would be pruned). The group
    is first taken in as it says (its closures without the robust loss), then the whole graph is
    optimised under the loss from there: the loop closes (as far as the closures that hold
    the drifted shape let it)."""
    truth = _square_loop()

    def loop_error(trusting: bool) -> tuple[list[bool], float]:
        g = PoseGraph(truth[0], GraphNoise(0.01, 0.02, 0.005, 0.02, 0.03, 0.01, "cauchy", 0.5))
        for k in range(1, len(truth)):
            g.add_node(se2_compose(se2_between(truth[k - 1], truth[k]), np.array([0.0, 0.03 if k <= 80 else 0.0, 0.0])))
        earlier = [g.add_loop(n - 10, n, se2_between(g.poses[n - 10], g.poses[n])) for n in range(50, 150, 5)]
        g.update()
        assert 1.5 < float(np.hypot(*(g.poses[160, :2] - truth[160, :2]))) < 2.0
        group, by_loop = [], {}
        for a, n in ((2, 156), (4, 158), (6, 160), (8, 162)):
            c = _closure(n, a, truth)
            c.in_group = True
            c.loop_id = g.add_loop(a, n, c.relative, c.covariance)
            by_loop[c.loop_id] = c
            group.append(c)
        for j in earlier:
            by_loop[j] = _closure(0, 0, truth)
        if trusting:
            _try_group(g, by_loop, group, SimpleNamespace(prune_m=0.5, prune_rad=0.15), len(truth) - 1)
        else:  # what the group's optimisation was before: the whole graph under the loss, from the estimate
            g.optimise_batch()
        off = list(g.loops_off(np.array([c.loop_id for c in group]), 0.5, 0.15))
        assert not any(c.status in (PRUNED, REFUTED) for c in group)
        return off, float(np.hypot(*(g.poses[156:163, :2] - truth[156:163, :2]).T).max())

    off, error = loop_error(trusting=False)
    assert all(off) and error > 1.0  # the robust loss alone leaves the loop open
    off, error = loop_error(trusting=True)
    assert not any(off) and error < 0.3



class _TrialGraph:
    """A stand-in for `PoseGraph` in `_try_group`'s decisions: which closures an optimisation
    leaves far off depends on which closures it first took in as they say (`off_after`:
    trusted set -> off closures; an untrusted re-optimisation keeps the last answer)."""

    def __init__(self, n_loops: int, off_after) -> None:
        self.active = [True] * n_loops
        self.off_after = off_after
        self.trusted: list[set[int]] = []
        self.off: set[int] = set()
        self._poses = np.zeros((2, 3))
        self.optimisations: list = []

    @property
    def poses(self) -> np.ndarray:
        return self._poses

    def optimise_batch(self, trusted=()) -> None:
        self.trusted.append(set(trusted))
        if trusted:
            self.off = set(self.off_after(set(trusted)))
            self._poses = np.full((2, 3), float(len(self.trusted)))  # each trial's own estimate

    def loops_off(self, loops, m, rad) -> np.ndarray:
        return np.array([int(j) in self.off and self.active[int(j)] for j in loops], dtype=bool)

    taken_back = 0

    def restore(self, poses, taken_back: int = 0) -> None:
        self.taken_back += taken_back
        self._poses = np.array(poses)
        self.off = set(self.off_after(set(self.trusted[int(poses[0, 0]) - 1]))) if poses[0, 0] else set()

    def drop_loop(self, j: int) -> None:
        self.active[j] = False


@pytest.mark.parametrize("together_holds", [True, False])
def test_a_group_that_leaves_earlier_closures_off_is_tried_together_with_them(together_holds):
    """Closures 0-5 are in the graph (0-1 a corridor's earlier loop closure); group 6-7 comes
    in. Taken in alone it leaves 0 and 1 far off. Then the group and 0-1 are tried together,
    all taken in as they say: if that leaves none of them off it stands and nothing is pruned;
    otherwise the estimate of the group alone comes back and 0-1 are pruned, as before."""
    group_ids = {6, 7}

    def off_after(trusted: set[int]) -> set[int]:
        if trusted == group_ids:
            return {0, 1}
        return set() if together_holds else {1}

    g = _TrialGraph(8, off_after)
    truth = np.column_stack([np.arange(10.0), np.zeros(10), np.zeros(10)])
    by_loop = {j: _closure(9, 0, truth) for j in range(8)}
    group = [by_loop[6], by_loop[7]]
    for j, c in by_loop.items():
        c.loop_id = j
        c.status = ACCEPTED
    _try_group(g, by_loop, group, SimpleNamespace(prune_m=0.5, prune_rad=0.15), 9)
    assert g.trusted[0] == group_ids and g.trusted[1] == {0, 1, 6, 7}  # alone, then together
    if together_holds:
        assert all(g.active) and g.poses[0, 0] == 2.0  # the joint estimate stands
        assert not any(c.status in (PRUNED, REFUTED) for c in by_loop.values())
    else:
        assert g.poses[0, 0] != 2.0  # the joint trial was taken back
        assert [j for j in range(8) if not g.active[j]] == [0, 1]
        assert by_loop[0].status == PRUNED and by_loop[1].status == PRUNED and by_loop[6].status == ACCEPTED
    assert g.taken_back == (0 if together_holds else 1)  # the joint trial, when taken back, is marked as such


def test_an_optimisation_taken_back_is_no_correction():
    """`restore(..., taken_back=n)` marks the last n optimisations as trials taken back; the
    run's largest correction counts only the others."""
    truth = _square_loop()
    g = PoseGraph(truth[0], GraphNoise(0.01, 0.02, 0.005, 0.02, 0.03, 0.01, "cauchy", 0.5))
    for k in range(1, len(truth)):  # local edges slipping 3 cm sideways a step on two sides: the end 1.7 m off
        g.add_node(se2_compose(se2_between(truth[k - 1], truth[k]), np.array([0.0, 0.03 if k <= 80 else 0.0, 0.0])))
    loops = {g.add_loop(a, n, _closure(n, a, truth).relative) for a, n in ((2, 156), (4, 158), (6, 160), (8, 162))}
    kept = g.poses.copy()
    g.optimise_batch(trusted=loops)
    assert g.optimisations[-1].moved_max_m > 1.0
    g.restore(kept, taken_back=1)
    assert g.optimisations[-1].taken_back and np.array_equal(g.poses, kept)
    g.optimise_batch()
    assert not g.optimisations[-1].taken_back


def _drifted_square(truth: np.ndarray) -> PoseGraph:
    """A graph of the square loop whose local edges slip 3 cm sideways a step on its first two
    sides (its end 1.7 m off), no closures yet; each step's length is as unsure as down a bare
    corridor (sigma 0.13 m a step along it), so a closure may move the path metres along its sides."""
    g = PoseGraph(truth[0], GraphNoise(0.01, 0.02, 0.005, 0.02, 0.03, 0.01, "cauchy", 0.5, local_sigma_along_per_m=0.25))
    for k in range(1, len(truth)):
        g.add_node(se2_compose(se2_between(truth[k - 1], truth[k]), np.array([0.0, 0.03 if k <= 80 else 0.0, 0.0])))
    g.update()
    return g


def _enter_group(g: PoseGraph, by_loop: dict, pairs, truth: np.ndarray, shift_m: float = 0.0, in_group: bool = True):
    """Closures (anchor, node) from `pairs` added to `g` as one group (or singly), each saying its
    node is `shift_m` ahead of where it truly is; entered by `_try_group` (a group) or by an
    update (singly). Returns the closures and the closures the group overruled."""
    group = []
    for a, n in pairs:
        c = _closure(n, a, truth, (shift_m, 0.0, 0.0))
        c.status, c.in_group, c.group = ACCEPTED, in_group, max(n for _, n in pairs) if in_group else -1
        c.loop_id = g.add_loop(a, n, c.relative, c.covariance)
        by_loop[c.loop_id] = c
        group.append(c)
    if not in_group:
        g.update()
        return group, []
    _, overruled = _try_group(g, by_loop, group, SimpleNamespace(prune_m=0.5, prune_rad=0.15), max(n for _, n in pairs))
    return group, overruled


@pytest.mark.parametrize("later_nodes", [5, 3])
def test_a_later_larger_group_overrules_an_earlier_group_it_contradicts(later_nodes):
    """Back at the start of the drifted square, a group of closures from 4 nodes says they are
    3 m further along than they are (a corridor matched a period off), and enters: nothing
    contradicts it yet. Then a group of correct closures comes: it leaves the first group far
    off, which would refute it. The larger set of mutually consistent closures wins: from 5
    nodes it overrules the first group (taken out, `overruled`) and the loop closes where it
    truly is; from 3 nodes it is refuted and the first group stays, as before."""
    truth = _square_loop()
    g, by_loop = _drifted_square(truth), {}
    wrong, none = _enter_group(g, by_loop, ((2, 150), (4, 152), (6, 154), (8, 156)), truth, shift_m=3.0)
    assert not none and all(c.status == ACCEPTED for c in wrong)
    assert float(np.hypot(*(g.poses[156, :2] - truth[156, :2]))) > 2.0  # the wrong group holds the end 3 m off
    pairs = ((2, 158), (4, 159), (6, 160), (8, 161), (10, 162)) if later_nodes == 5 else ((2, 158), (6, 160), (10, 162))
    n_before = len(g.optimisations)
    right, overruled = _enter_group(g, by_loop, pairs, truth)
    trials = g.optimisations[n_before:]
    # only what stands counts (metrics.json `largest_correction_m`): the first trial (the group alone) is discarded either
    # way, and a refuted group's every trial
    assert trials[0].taken_back and all(o.taken_back for o in trials) == (later_nodes <= len(wrong))
    end_error = float(np.hypot(*(g.poses[150:165, :2] - truth[150:165, :2]).T).max())
    if later_nodes > len(wrong):
        assert overruled == wrong and all(c.status == OVERRULED for c in wrong)
        assert all(c.status == ACCEPTED for c in right) and not any(g.active[c.loop_id] for c in wrong)
        assert end_error < 0.5
    else:
        assert not overruled and all(c.status == REFUTED for c in right) and all(c.status == ACCEPTED for c in wrong)
        assert all(g.active[c.loop_id] for c in wrong) and not any(g.active[c.loop_id] for c in right)
        assert end_error > 2.0


def test_a_group_does_not_overrule_one_that_other_closures_agree_with():
    """As above, with 5 more closures taken in singly since the wrong group (matches that
    confirmed the estimate it left): the correct group of 5 nodes outweighs the wrong group
    but not the wrong group and those closures together, so it is refuted, and the graph keeps
    every closure it had, at the same estimate."""
    truth = _square_loop()
    g, by_loop = _drifted_square(truth), {}
    wrong, _ = _enter_group(g, by_loop, ((2, 150), (4, 152), (6, 154), (8, 156)), truth, shift_m=3.0)
    agreeing, _ = _enter_group(g, by_loop, [(10 + i, 157 + i) for i in range(5)], truth, shift_m=3.0, in_group=False)
    g.refresh()
    kept = g.poses.copy()
    right, overruled = _enter_group(g, by_loop, ((2, 158), (4, 159), (6, 160), (8, 161), (10, 162)), truth)
    assert not overruled and all(c.status == REFUTED for c in right)
    assert all(c.status == ACCEPTED and g.active[c.loop_id] for c in wrong + agreeing)
    assert np.array_equal(g.poses, kept)


def test_a_corridor_match_off_only_along_its_corridor_is_off_only_when_that_counts():
    """`loops_off(..., free_along=...)`: a corridor match (sigma 10 m along x) 17 m off along
    the corridor is off by its covariance, and not off where its along direction is free; 1 m
    off across it is off either way."""
    truth = np.column_stack([np.arange(40) * 0.5, np.zeros(40), np.zeros(40)])
    g = PoseGraph(truth[0], GraphNoise(0.01, 0.02, 0.005, 0.02, 0.03, 0.01, "cauchy", 0.5))
    for k in range(1, len(truth)):
        g.add_node(se2_between(truth[k - 1], truth[k]))
    along = np.diag([100.0, 1e-3, 1e-4])
    ids = np.array([g.add_loop(0, 30, np.array([15.0 - 17.0, 0.0, 0.0]), along), g.add_loop(0, 30, np.array([15.0, 1.0, 0.0]), along)])
    g.update()
    assert list(g.loops_off(ids, 0.5, 0.15)) == [True, True]
    assert list(g.loops_off(ids, 0.5, 0.15, free_along=np.array([True, True]))) == [False, True]


# ---- end to end -------------------------------------------------------------------------------
def _l_shaped_path(k: int = 40) -> np.ndarray:
    """(k, 3) poses 0.5 m apart: east along a corridor, then north up another."""
    xy = np.array([[min(i, k // 2) * 0.5, max(i - k // 2, 0) * 0.5] for i in range(k)])
    yaw = np.where(np.arange(k) <= k // 2, 0.0, np.pi / 2)
    return np.column_stack([xy, yaw])


def test_a_turn_of_the_whole_map_redraws_it_in_place_in_the_online_frame_and_only_once():
    """`filter.redraw_frame`: a graph that holds the online map's path turned 2 degrees about
    the start (an early heading it undid) redraws it turned (`graph`) or where it is (`online`),
    and in the online frame the turn is laid aside: the same graph does not redraw it again."""
    on_map, none = _l_shaped_path(), np.zeros(3)
    turned = se2_compose(np.array([0.0, 0.0, np.radians(2.0)]), on_map)
    at, laid = redraw_poses(turned, on_map, none, "graph", 0.15, 0.035)
    np.testing.assert_array_equal(at, turned)
    assert not laid.any()
    at, laid = redraw_poses(turned, on_map, none, "online", 0.15, 0.035)
    np.testing.assert_allclose(at, on_map, atol=1e-9)
    np.testing.assert_allclose(laid, [0.0, 0.0, np.radians(-2.0)], atol=1e-12)
    assert redraw_poses(turned, at, laid, "online", 0.15, 0.035) is None
    assert redraw_poses(turned, turned, none, "graph", 0.15, 0.035) is None


def test_a_redraw_in_the_online_frame_moves_the_online_path_by_what_the_graph_bent_only():
    on_map = _l_shaped_path()
    bent = on_map.copy()
    bent[-5:, 0] -= np.linspace(0.1, 0.5, 5)  # the last metres pulled 0.1-0.5 m west (a loop closing)
    graph = se2_compose(np.array([3.0, -1.0, 0.3]), bent)  # in the graph's frame, turned and moved
    at, _ = redraw_poses(graph, on_map, np.zeros(3), "online", 0.15, 0.035)
    # laid on the online map (least squares over all nodes: the bend's mean shift spreads over them): the path the graph
    # bent moves west, the rest a few centimetres; in the graph's frame every node would have moved metres
    moved = np.hypot(*(at[:, :2] - on_map[:, :2]).T)
    assert -0.5 < at[-1, 0] - on_map[-1, 0] < -0.3 and moved[:-5].max() < 0.15
    assert np.hypot(*(graph[:, :2] - on_map[:, :2]).T).min() > 1.0
    # and the shape is the graph's: every node's pose relative to the first as the graph has it
    np.testing.assert_allclose(se2_between(at[0], at), se2_between(graph[0], graph), atol=1e-9)


@pytest.fixture(scope="module")
def loop_log(tmp_path_factory):
    """The 3x `loops` building's log (sim_carmen: 656 m, corridors of ~100 m), as a sequence."""
    out = tmp_path_factory.mktemp("graph-log")
    clf = sim_carmen.write_log(out, scale=3.0, world_seed=0, seed=0, n_loop=300, yaw_bias_deg_per_m=sim_carmen.ODOM["yaw_bias_deg_per_m"])
    return load_carmen(clf)


def _run(seq, *overrides: str):
    return run_slam(seq, build_components(_cfg(*GRAPH, *overrides)))


@contextlib.contextmanager
def _instances_of(cls: type):
    """Every instance of `cls` made inside the block, in the list it yields."""
    made: list = []
    init = cls.__init__

    def keep(self, *args, **kwargs):
        init(self, *args, **kwargs)
        made.append(self)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(cls, "__init__", keep)
        yield made


@pytest.fixture(scope="module")
def graph_run(loop_log):
    """The graph filter's run on the log (shared by the tests below), and the pose graph it
    ended with."""
    with _instances_of(PoseGraph) as graphs:
        result = _run(loop_log)
    return result, graphs[-1]


@pytest.mark.slow
def test_the_graph_closes_the_loops_that_local_slam_alone_leaves_metres_off(loop_log, graph_run):
    graph = graph_run[0]
    # no loop search at all (a node searches when its index is a multiple of search_every: only node 0, before any
    # submap is finished). min_score=1.0 is not enough: a scan in the robot's own fresh submap can score 1.0
    alone = _run(loop_log, f"filter.search_every={10**9}")
    assert alone.extras["graph"]["searches"] == alone.extras["graph"]["search_bounds"] == 0
    err = relation_errors(graph.times, graph.trajectory, loop_log.relations, loop_min_dt_s=sim_carmen.LOOP_MIN_DT_S)
    err_alone = relation_errors(alone.times, alone.trajectory, loop_log.relations, loop_min_dt_s=sim_carmen.LOOP_MIN_DT_S)
    assert err_alone["loop"]["trans_abs_mean_m"] > 1.0
    # the loop relations at least three times closer, the whole path within a fifth of a metre
    assert err["loop"]["trans_abs_mean_m"] < err_alone["loop"]["trans_abs_mean_m"] / 3 and err["trans_abs_mean_m"] < 0.2
    g = graph.extras["graph"]
    assert g["accepted"] > 100 and g["nodes"] == len(graph.extras["step_scans"])
    assert g["search_bounds"] > g["searches"] > 0  # each search bounds its window's top level at least
    loops = graph.extras["loops"]
    assert (loops["status"] == ACCEPTED).sum() == g["accepted"] and len(loops) == g["candidates"]


@pytest.mark.slow
def test_a_run_cut_short_gives_the_same_online_poses_up_to_its_end(loop_log, graph_run):
    full = graph_run[0]
    n = len(loop_log.scans) // 2
    cut = _run(loop_log, f"steps.max_scans={n}")
    assert len(cut.causal) == n
    assert cut.causal.tobytes() == full.causal[:n].tobytes()


@pytest.mark.parametrize("wall_at", ["centre", "hits"])
def test_filter_wall_at_reaches_the_online_map_and_the_submaps(loop_log, wall_at):
    """`filter.wall_at` picks where every grid with a likelihood field for matching puts its walls:
    the online map, each submap and the final match's map (the final map, drawn once, keeps no
    hit offsets)."""
    with _instances_of(OccupancyGrid) as made:
        _run(loop_log, f"filter.wall_at={wall_at}", "steps.max_scans=400")
    online = [g for g in made if g.bank is not None and g.s.initial_size_m > 1.0]
    subs = [g for g in made if g.s.initial_size_m == 1.0]  # submaps start at 1 m (`Submaps._submap_settings`)
    assert online and len(subs) >= 2
    assert all(g.walls_at_hits == (wall_at == "hits") for g in online + subs)
    assert all((g.hit_n.size > 0) == (wall_at == "hits") for g in online + subs if g.hit_n is not None)


@pytest.mark.slow
def test_the_same_config_gives_the_same_bytes(loop_log, graph_run):
    a, b = graph_run[0], _run(loop_log)
    assert a.trajectory.tobytes() == b.trajectory.tobytes() and a.causal.tobytes() == b.causal.tobytes()
    assert a.log_odds.data.tobytes() == b.log_odds.data.tobytes()


def test_the_graph_filter_needs_the_likelihood_matcher():
    from slamlab.frames import Sequence
    from test_slam_engine import _room_sequence

    seq: Sequence = _room_sequence()
    with pytest.raises(ConfigError, match="matcher"):
        run_slam(seq, build_components(_cfg("filter=graph", "matcher=grid")))


@pytest.mark.slow
def test_a_wrong_closure_added_to_a_runs_graph_leaves_its_optimum_within_2_cm(graph_run):
    """The pose graph the run on the simulated log ends with, optimised again as it is and with
    one closure 2 m and 20 degrees off added half way (no pruning: the robust loss alone)."""
    g = graph_run[1]
    g.optimise_batch()
    without = g.poses.copy()
    k = g.n // 2
    g.add_loop(k - 60, k, se2_compose(se2_between(without[k - 60], without[k]), np.array([2.0, 0.0, math.radians(20)])))
    g.optimise_batch()
    assert sum(g.active) > 100  # a graph held together by many closures
    assert np.hypot(*(g.poses[:, :2] - without[:, :2]).T).max() <= 0.02


# ---- the loop search's screen -----------------------------------------------------------------------
def _wall_points(segments, pose, step_m=0.05, max_r=30.0):
    """Points every `step_m` along wall `segments` ((x0, y0, x1, y1), m) within `max_r` of
    `pose`, in its body frame (no occlusion: enough for a submap's walls)."""
    out = []
    for x0, y0, x1, y1 in segments:
        n = max(int(math.hypot(x1 - x0, y1 - y0) / step_m), 1)
        t = np.linspace(0.0, 1.0, n + 1)
        out.append(np.column_stack([x0 + t * (x1 - x0), y0 + t * (y1 - y0)]))
    xy = np.vstack(out)
    xy = xy[np.hypot(xy[:, 0] - pose[0], xy[:, 1] - pose[1]) < max_r]
    return se2_between(np.asarray(pose, dtype=float), np.column_stack([xy, np.zeros(len(xy))]))[:, :2]


def _two_place_submaps():
    """Two finished submaps of two nodes each: a 12 x 8 m room with a pillar around (0, 0) and
    an L-shaped corridor junction around (60, 0)."""
    from slamlab.slam.graph.submaps import Submaps
    from slamlab.slam.grid import MapSettings
    from slamlab.slam.scan import ScanPoints

    room = [(-6, -4, 6, -4), (6, -4, 6, 4), (6, 4, -6, 4), (-6, 4, -6, -4), (1, 0, 2, 0), (2, 0, 2, 1), (2, 1, 1, 1), (1, 1, 1, 0)]
    junction = [(50, -1, 70, -1), (50, 1, 58, 1), (60, 1, 70, 1), (58, 1, 58, 12), (60, 1, 60, 12)]
    submaps = Submaps(MapSettings(resolution_m=0.05), 2, 0.1, 0.3, overlap=False, field_when_finished=True)
    poses = [(-2.0, -1.0, 0.3), (0.0, -2.0, 0.5), (55.0, 0.0, 0.0), (59.0, 0.0, 1.2)]
    for node, (walls, pose) in enumerate(zip((room, room, junction, junction), poses)):
        submaps.insert(node, np.array(pose), ScanPoints(_wall_points(walls, pose), np.zeros(2)))
    return submaps, junction


def test_the_screen_scores_the_submap_a_scan_was_taken_in_above_another_place():
    """A scan taken in the junction, searched over a 10 m window at every yaw: the junction's
    submap scores near 1 on the coarse grid, the room's clearly less, whichever is nearer."""
    submaps, junction = _two_place_submaps()
    pose = np.array([57.0, 0.2, 2.0])
    query = _wall_points(junction, pose)
    search = LoopSearch(SearchSettings(0.1, 6, 0.3, 0.5, 0.9, 1.0, 0.35, 2, 30.0, screen_resolution_m=0.4), 0.05, 4, 0.03, 0.01)
    room_sm, junction_sm = submaps.finished
    # the estimate 4 m off in the junction, and where the room is for the room (the robot lost: both plausible)
    scores = search.screen(query, submaps, [(room_sm, np.array([0.0, 0.0, 0.0]), 10.0, math.pi),
                                            (junction_sm, pose + np.array([3.0, -2.0, 0.4]), 10.0, math.pi)])
    assert search.screened == 2
    assert scores[1] > 0.85 and scores[1] > scores[0] + 0.2
    # the targets' searches run side by side (`side_by_side`): each its own score, as on one thread
    import numba

    threads = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        alone = [search.screen(query, submaps, [target])[0] for target in ((room_sm, np.array([0.0, 0.0, 0.0]), 10.0, math.pi),
                                                                           (junction_sm, pose + np.array([3.0, -2.0, 0.4]), 10.0, math.pi))]
    finally:
        numba.set_num_threads(threads)
    assert list(scores) == alone
    assert len(search.screen(query[:5], submaps, [(junction_sm, pose, 10.0, math.pi)])) == 1  # too few points: no score
    assert search.screen(query[:5], submaps, [(junction_sm, pose, 10.0, math.pi)])[0] == -1.0


@pytest.mark.parametrize("shift_m, half_m, status", [(3.0, 3.0, EDGE), (3.0, 4.0, PENDING), (0.0, 3.0, PENDING)])
def test_a_match_on_the_edge_of_its_window_is_set_aside(shift_m, half_m, status):
    """A scan taken in the junction at (57, 0.2), the estimate `shift_m` behind along the
    corridor, searched +-`half_m`: the true place is found in every case, but where it lies on
    the window's edge the search cannot tell it from a score still rising beyond the window,
    and the candidate is set aside (`edge`); inside the window it waits for its group."""
    submaps, junction = _two_place_submaps()
    truth = np.array([57.0, 0.2, 0.0])
    poses = np.array([(-2.0, -1.0, 0.3), (0.0, -2.0, 0.5), (55.0, 0.0, 0.0), (59.0, 0.0, 1.2)])
    query = _wall_points(junction, truth)
    estimate = truth - np.array([shift_m, 0.0, 0.0])
    search = LoopSearch(SearchSettings(0.1, 6, 0.3, 0.5, 0.9, 1.0, 0.35, 2, 30.0), 0.05, 4, 0.03, 0.01)
    anchors = submaps.finished_anchor
    reach = search.submaps_in_reach(estimate, submaps, poses[anchors], np.tile([half_m, 0.3], (len(anchors), 1)), np.full(len(anchors), 100.0))
    [found] = search.search(9, estimate, query, query, np.zeros(2), submaps, reach, poses)
    assert found.submap == 1 and np.hypot(*(found.match_pose[:2] - truth[:2])) < 0.1
    assert found.status == status


def test_a_loop_search_over_several_submaps_side_by_side_finds_what_one_thread_finds(monkeypatch):
    """`LoopSearch.search` evaluates each submap in reach on its own (`_candidate`), side by side
    when the searches are large (`side_by_side`): the same candidates, in the same order, with
    the same bound count as one after the other on one thread. Here the junction's scan over
    both submaps at every yaw, the estimate in the room: both searched, the junction's found."""
    import numba

    from slamlab.slam.graph import loops

    submaps, junction = _two_place_submaps()
    truth = np.array([57.0, 0.2, 0.0])
    poses = np.array([(-2.0, -1.0, 0.3), (0.0, -2.0, 0.5), (55.0, 0.0, 0.0), (59.0, 0.0, 1.2)])
    query = _wall_points(junction, truth)
    settings = SearchSettings(0.1, 6, 0.3, 0.5, 0.9, 1.0, 0.35, 2, 30.0)

    def run() -> tuple[list, int, int]:
        search = LoopSearch(settings, 0.05, 4, 0.03, 0.01)
        # the room searched around its middle, the junction around an estimate 2 m off (submap frames: the world here)
        guesses = {0: np.array([0.5, 0.5, 0.0]), 1: truth + np.array([2.0, 0.5, 0.3])}
        reach = [(sm, guesses[sm.index], (10.0, math.pi), 100.0) for sm in submaps.finished]
        found = search.search(9, truth, query, query, np.zeros(2), submaps, reach, poses)
        return found, search.searches, search.nodes_scored

    monkeypatch.setattr(loops, "SIDE_BY_SIDE_READS", 0)  # every search large: side by side on all threads
    both = run()
    threads = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        alone = run()
    finally:
        numba.set_num_threads(threads)
    assert both[1:] == alone[1:] and both[1] == 2
    assert [c.submap for c in both[0]] == [c.submap for c in alone[0]] and 1 in [c.submap for c in both[0]]
    for a, b in zip(both[0], alone[0]):
        assert (a.status, a.score, a.refined, a.second, a.anchor) == (b.status, b.score, b.refined, b.second, b.anchor)
        assert np.array_equal(a.relative, b.relative) and np.array_equal(a.covariance, b.covariance)


def test_the_window_edge_is_the_drift_windows_not_the_submaps_area():
    """`at_window_edge`: within one search cell of the window +-5 m around (10, 10) in x or y,
    on a side the submap's area (x and y 0..40 m, or x 0..12 m) did not cut."""
    wide = SimpleNamespace(shape=(800, 800), origin=np.zeros(2), resolution_m=0.05)
    narrow = SimpleNamespace(shape=(800, 240), origin=np.zeros(2), resolution_m=0.05)  # x 0..12 m
    guess = np.array([10.0, 10.0, 0.0])
    assert at_window_edge(np.array([14.95, 10.0]), wide, guess, 5.0, 0.1)
    assert at_window_edge(np.array([10.0, 5.05]), wide, guess, 5.0, 0.1)
    assert not at_window_edge(np.array([14.85, 10.0]), wide, guess, 5.0, 0.1)
    assert not at_window_edge(np.array([11.95, 10.0]), narrow, guess, 5.0, 0.1)  # the map's edge, not the window's
    assert at_window_edge(np.array([5.0, 10.0]), narrow, guess, 5.0, 0.1)
    # the area ending where the window does (x 0..15 m, or 5..45 m): a best there lies on the map's edge, not the drift's
    flush_hi = SimpleNamespace(shape=(800, 300), origin=np.zeros(2), resolution_m=0.05)
    flush_lo = SimpleNamespace(shape=(800, 800), origin=np.array([5.0, 0.0]), resolution_m=0.05)
    assert not at_window_edge(np.array([14.95, 10.0]), flush_hi, guess, 5.0, 0.1)
    assert not at_window_edge(np.array([5.05, 10.0]), flush_lo, guess, 5.0, 0.1)
    assert at_window_edge(np.array([10.0, 14.95]), flush_hi, guess, 5.0, 0.1)  # y is not cut there


def test_a_wide_search_takes_the_untied_submaps_the_screen_scores_best_not_the_nearest(monkeypatch):
    # four untied submaps in reach, nearest first 0, 1, 2, 3 (by where each was seen from); the screen
    # says 3, then 2. Ties go to the nearer; without the screen's points, the nearest as before (one loop
    # candidate: the nearest both ways, then the nearest others, three in all)
    submaps = _finished([(1, 0), (2, 0), (3, 0), (4, 0)], [(1, 0), (2, 0), (3, 0), (4, 0)], [5, 5, 5, 5])
    search = LoopSearch(SearchSettings(0.1, 6, 0.55, 0.5, 0.9, 1.0, 0.35, 3, 30.0, screen_resolution_m=0.4, screen_keep=2), 0.05, 4, 0.03, 0.01)
    monkeypatch.setattr(search, "screen", lambda query, sm, targets: np.array([0.6, -1.0, 0.8, 0.9])[: len(targets)])
    windows = np.tile([20.0, math.pi], (4, 1))
    pose, tied = np.zeros(3), np.full(4, 200.0)

    def reach(screen):
        return [sm for sm, *_ in search.submaps_in_reach(pose, submaps, np.zeros((4, 3)), windows, tied, None, screen)]

    assert reach(np.zeros((30, 2))) == ["submap 3", "submap 2", "submap 0", "submap 1"]  # two screened in, then the nearest others
    assert reach(None) == ["submap 0", "submap 1", "submap 2"]
    monkeypatch.setattr(search, "screen", lambda query, sm, targets: np.full(len(targets), 0.7))
    assert reach(np.zeros((30, 2))) == ["submap 0", "submap 1", "submap 2", "submap 3"]


# ---- the final match ----------------------------------------------------------------------------
def _lidar_points(walls, pose, n_beams: int = 360, max_r: float = 30.0) -> np.ndarray:
    """The hits (body frame, m) of a noiseless lidar at `pose` among wall segments
    ((x0, y0, x1, y1), m): each beam's nearest wall."""
    a = np.linspace(-np.pi, np.pi, n_beams, endpoint=False)
    d = np.column_stack([np.cos(a + pose[2]), np.sin(a + pose[2])])
    r = np.full(n_beams, np.inf)
    for x0, y0, x1, y1 in walls:
        e = np.array([x1 - x0, y1 - y0])
        den = d[:, 0] * e[1] - d[:, 1] * e[0]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((x0 - pose[0]) * e[1] - (y0 - pose[1]) * e[0]) / den
            u = ((x0 - pose[0]) * d[:, 1] - (y0 - pose[1]) * d[:, 0]) / den
        r = np.where((t > 0) & (u >= 0) & (u <= 1) & (t < r), t, r)
    ok = r < max_r
    return np.column_stack([r[ok] * np.cos(a[ok]), r[ok] * np.sin(a[ok])])


def test_the_final_match_puts_scans_back_where_they_fit_the_map_of_the_nodes(monkeypatch):
    """Scans of an L-shaped room with a pillar: the nodes (1, 3, 5) at their true poses draw the
    map; scans 2 and 4, placed 3-4 cm and ~0.6 degrees off, are matched back to within 5 mm and
    0.1 degrees of where they were taken; scan 6 has no points and keeps its pose, and so do the
    first node and scan 0 before it, even placed off (the start fixes the map's frame). Each
    scan's result is its own: any chunking of the scans gives the same bytes."""
    from slamlab.slam.graph import final_match
    from slamlab.slam.grid import MapSettings
    from slamlab.slam.scan import ScanBatch, ScanPoints

    room = [(-6, -4, 6, -4), (6, -4, 6, 1), (6, 1, 2, 1), (2, 1, 2, 4), (2, 4, -6, 4), (-6, 4, -6, -4),
            (-2, 0, -1, 0), (-1, 0, -1, 1), (-1, 1, -2, 1), (-2, 1, -2, 0), (4, -4, 4, -3), (-6, 2, -5, 2)]
    room = [tuple(v + 0.025 for v in w) for w in room]  # walls on cell centres, where the map draws them (5 cm cells)
    truth = np.array([(-3.0, -1.0, 0.3), (-3.0, -1.0, 0.3), (-2.6, -1.2, 0.35), (-2.0, -1.5, 0.4), (-1.5, -1.8, 0.5), (-1.0, -2.0, 0.5),
                      (-0.6, -2.0, 0.55)])
    off = np.zeros_like(truth)
    off[0], off[2], off[4] = (0.02, 0.01, 0.005), (0.03, -0.02, 0.01), (-0.02, 0.03, -0.01)

    def points(i: int) -> ScanPoints:
        return ScanPoints(np.zeros((0, 2)) if i == 6 else _lidar_points(room, truth[i]), np.zeros(2))

    def project(a: int, b: int) -> ScanBatch:
        return ScanBatch.of([points(i) for i in range(a, b)])

    matcher = build_components(_cfg(*GRAPH)).matcher
    nodes = np.array([1, 3, 5])
    out = final_match.match_on_final_map(truth + off, nodes, points, project, matcher, MapSettings(resolution_m=0.05))
    d = out - truth
    assert np.hypot(d[[2, 4], 0], d[[2, 4], 1]).max() < 0.005 and np.degrees(np.abs(d[[2, 4], 2])).max() < 0.1
    assert np.array_equal(out[[0, 1, 6]], (truth + off)[[0, 1, 6]])
    monkeypatch.setattr(final_match, "CHUNK_SCANS", 2)
    assert final_match.match_on_final_map(truth + off, nodes, points, project, matcher, MapSettings(resolution_m=0.05)).tobytes() == out.tobytes()


def test_the_final_match_runs_where_the_scans_between_steps_are_matched_and_nowhere_else():
    from test_slam_engine import _room_sequence

    seq = _room_sequence()
    room = ("filter=graph", "matcher=likelihood", "steps.min_distance_m=0.1")
    on, off = (run_slam(seq, build_components(_cfg(*room, f"filter.final_match={v}", "steps.between=odometry"))) for v in ("true", "false"))
    assert on.trajectory.tobytes() == off.trajectory.tobytes() and on.extras["graph"]["final_match_s"] == 0
    on, off = (run_slam(seq, build_components(_cfg(*room, f"filter.final_match={v}", "steps.between=match"))) for v in ("true", "false"))
    assert on.extras["graph"]["final_match_s"] > 0 and on.trajectory.tobytes() != off.trajectory.tobytes()
    assert on.causal.tobytes() == off.causal.tobytes()


@pytest.mark.slow
def test_the_final_match_changes_the_smoothed_path_only_and_brings_it_closer(loop_log, graph_run):
    """`filter.final_match` (on in the preset) leaves the online path to the byte; on the simulated
    log the smoothed path's relation error is lower with it than without."""
    on = graph_run[0]
    off = _run(loop_log, "filter.final_match=false")
    assert on.causal.tobytes() == off.causal.tobytes()
    assert on.extras["graph"]["final_match_s"] > 0 and off.extras["graph"]["final_match_s"] == 0
    err = [relation_errors(r.times, r.trajectory, loop_log.relations, loop_min_dt_s=sim_carmen.LOOP_MIN_DT_S)["trans_abs_mean_m"] for r in (on, off)]
    assert err[0] < err[1]


def test_hits_near_the_lidar_stay_out_of_the_online_map_and_its_redraw_but_not_out_of_the_submaps():
    # A person 0.5 m beside the robot and a wall 3 m ahead, each a dense row of hits.
    from slamlab.slam.graph.local import LocalSlam
    from slamlab.slam.graph.submaps import Submaps
    from slamlab.slam.grid import MapSettings
    from slamlab.slam.matcher import LikelihoodFieldMatcher
    from slamlab.slam.scan import ScanPoints

    person = np.stack([np.linspace(-0.2, 0.2, 9), np.full(9, -0.5)], axis=1)
    wall = np.stack([np.full(41, 3.0), np.linspace(-1.0, 1.0, 41)], axis=1)
    scan = ScanPoints(xy=np.concatenate([person, wall]), origin=np.zeros(2))
    matcher, ms = LikelihoodFieldMatcher(), MapSettings()

    def online_and_submap(near_hits_m: float) -> tuple[LocalSlam, OccupancyGrid]:
        submaps = Submaps(ms, 4, matcher.field_sigma_m, matcher.field_radius_m)
        local = LocalSlam(matcher, ms, submaps, "map", np.zeros(3), near_hits_m=near_hits_m)
        local.insert(0, scan)
        return local, submaps.matching().grid

    def occupied_at(grid: OccupancyGrid, xy: np.ndarray) -> np.ndarray:
        grid.unpark_all()  # a redraw leaves its rows parked (`slam/parked_rows.py`): read them back first
        r, c = grid.cells(xy)
        return grid.log_odds[r, c] > ms.occupied_threshold

    local, submap = online_and_submap(0.0)  # off: every hit in every map
    assert occupied_at(local.grid, person).all() and occupied_at(local.grid, wall).all()
    local, submap = online_and_submap(0.7)
    assert not occupied_at(local.grid, person).any() and occupied_at(local.grid, wall).all()
    assert occupied_at(submap, person).all()  # the submaps (the loop search's targets) keep them
    local.redraw([scan], np.zeros((1, 3)))  # drawn again from the node: the same hits left out
    assert not occupied_at(local.grid, person).any() and occupied_at(local.grid, wall).all()
    from slamlab.config.slam import GraphFilterConfig  # a negative distance is the user's mistake, named

    with pytest.raises(ConfigError, match="filter.near_hits_m"):
        GraphFilterConfig(near_hits_m=-0.5)


def test_a_learnt_yaw_drift_is_the_simulated_odometrys_and_lands_in_the_metrics(loop_log):
    # sim_carmen's odometry turns 1 degree a metre (and ~0.1 more from its time drift) more than the robot did
    learnt = _run(loop_log, "filter.yaw_drift_gain_per_m=0.05", "steps.max_scans=3000").extras["graph"]
    assert -1.4 < math.degrees(learnt["yaw_drift_rad_per_m"]) < -0.8
    assert "yaw_drift_rad_per_m" not in _run(loop_log, "steps.max_scans=300").extras["graph"]  # absent when off


def test_a_map_of_nodes_made_one_scan_at_a_time_is_the_map_of_the_list_and_released_submaps_keep_their_counts():
    """The online map's redraw and the final match pass their scans as a generator (each let go
    once its points are placed): the same log-odds and field as from a list. After the last node
    the submaps let their maps go (`Submaps.release`) and keep what the metrics read."""
    from slamlab.slam.graph.local import map_of_nodes
    from slamlab.slam.grid import MapSettings
    from slamlab.slam.matcher import LikelihoodFieldMatcher
    from slamlab.slam.scan import ScanPoints

    submaps, junction = _two_place_submaps()
    poses = np.array([(55.0, 0.0, 0.0), (59.0, 0.0, 1.2), (57.0, 0.5, 0.4)])
    scans = [ScanPoints(_wall_points(junction, p), np.array([0.1, 0.0])) for p in poses]
    matcher, ms = LikelihoodFieldMatcher(), MapSettings(resolution_m=0.05)
    from_list = map_of_nodes(scans, poses, matcher, ms, walls_at_hits=True)
    made = []
    from_generator = map_of_nodes((made.append(i) or scans[i] for i in range(3)), poses, matcher, ms, walls_at_hits=True)
    assert made == [0, 1, 2] and np.count_nonzero(from_list.log_odds) > 100
    for name in ("log_odds", "field", "hit_dx", "hit_dy", "hit_n"):
        assert np.array_equal(getattr(from_list, name), getattr(from_generator, name)), name
    assert np.array_equal(from_list.origin, from_generator.origin)

    peak, anchors = submaps.peak_mb, list(submaps.anchors)
    submaps.screen_grid(submaps.finished[0], 0.3, 3)
    assert submaps.memory_mb() > 0
    submaps.release()
    assert submaps.memory_mb() == 0 and not submaps.finished and submaps.anchors == anchors and submaps.peak_mb == peak > 0


@pytest.mark.slow
def test_the_online_map_parked_behind_the_robot_gives_the_bytes_of_a_run_that_parks_nothing(loop_log, monkeypatch):
    """Rows of the online map, of its redraws and of the final match's map parked as soon as the
    robot is a band away (instead of its reach and more): every read puts back what it reaches,
    so the run is the one whose maps are all resident, to the bit (`slam/parked_rows.py`)."""
    import slamlab.slam.graph.final_match as final_match
    import slamlab.slam.graph.local as local

    with monkeypatch.context() as mp:
        mp.setattr(OccupancyGrid, "start_parking", lambda self: None)
        resident = _run(loop_log)
    assert resident.extras["graph"]["redraws"] > 0 and resident.extras["graph"]["final_match_s"] > 0
    monkeypatch.setattr(local, "park_distance", lambda reach_m, margin_m: 0.0)
    monkeypatch.setattr(final_match, "park_distance", lambda reach_m, margin_m: 0.0)
    with _instances_of(OccupancyGrid) as made:
        tight = _run(loop_log)
    parked = [g for g in made if g.parked is not None]
    assert len(parked) >= 2 + resident.extras["graph"]["redraws"]  # the online map, each redraw, the final match's map
    assert all(g.parked.parks > 10 for g in parked) and sum(g.parked.unparks for g in parked) > 100
    assert tight.trajectory.tobytes() == resident.trajectory.tobytes() and tight.causal.tobytes() == resident.causal.tobytes()
    assert tight.log_odds.data.tobytes() == resident.log_odds.data.tobytes()


def _room_scan() -> np.ndarray:
    """A room's walls seen from (0, 0), body frame (m): an end wall, two side walls of different reach
    and a stub, so that the match pins the yaw."""
    t = np.linspace(0.0, 1.0, 81)
    return np.concatenate([np.stack([np.full(81, 3.0), -1.5 + 3.5 * t], axis=1), np.stack([-1.0 + 4.0 * t, np.full(81, 2.0)], axis=1),
                           np.stack([-1.0 + 4.0 * t[:61], np.full(61, -1.5)], axis=1), np.stack([np.full(21, -1.0), 1.0 + t[:21]], axis=1)])


ROBOT_CHAIN = np.array([2.0, 1.0, 0.3])  # the node before, in the submaps' frame ...
ROBOT_ONLINE = np.array([7.0, -3.0, 1.1])  # ... and on the online map, redrawn in another frame since


def _misplaced_room(check_rad: float, recent: str = "room"):
    """A LocalSlam whose online map holds two of the room's walls 0.12 rad turned about the robot (a place mapped
    long ago, before its loop closed, where the drifted estimate put it then) and whose submap holds the room as
    the recent scans saw it, -0.04 rad turned (`recent`: "room", or "far wall": the end wall alone); and the scan."""
    from slamlab.slam.graph.local import LocalSlam
    from slamlab.slam.graph.submaps import Submaps
    from slamlab.slam.grid import MapSettings
    from slamlab.slam.matcher import LikelihoodFieldMatcher
    from slamlab.slam.scan import ScanPoints, points_to_world

    scan = ScanPoints(xy=_room_scan(), origin=np.zeros(2))
    matcher, ms = LikelihoodFieldMatcher(), MapSettings()
    submaps = Submaps(ms, 20, matcher.field_sigma_m, matcher.field_radius_m, field_when_finished=True)
    local = LocalSlam(matcher, ms, submaps, "map", ROBOT_CHAIN, step_matcher=matcher.with_yaw_window(0.2), check_rad=check_rad)
    local.online = ROBOT_ONLINE.copy()
    old = se2_compose(ROBOT_ONLINE, np.array([0.0, 0.0, 0.12]))
    for _ in range(3):
        local.grid.insert(points_to_world(np.zeros((1, 2)), ROBOT_ONLINE)[0], points_to_world(scan.xy[:162], old))
    submaps.insert(0, se2_compose(ROBOT_CHAIN, np.array([0.0, 0.0, -0.04])), scan if recent == "room" else ScanPoints(xy=scan.xy[:81], origin=np.zeros(2)))
    return local, scan


@pytest.mark.parametrize(("turn", "check_rad", "recent", "taken"), [
    (0.0, 0.0, "room", 0), (0.0, 0.1, "room", 1), (0.12, 0.1, "room", 0), (0.0, 0.2, "room", 0), (0.08, 0.07, "room", 0),
    (0.0, 0.1, "far wall", 0),
])  # fmt: skip
def test_a_node_turned_by_an_old_misplaced_map_keeps_the_recent_submaps_motion_when_they_clearly_fit_and_the_odometry_agrees(
        turn, check_rad, recent, taken):
    # The robot stands still (third case: the odometry says it turned 0.12 rad, as the online map's match does; fifth:
    # 0.08 rad, nearer the online map's 0.12 than the submap's -0.04): the online map's match turns it 0.12 rad, the
    # submap's -0.04. Off (0), within the tolerance (0.2) or where the odometry sides with the online map, its
    # match stands. In the last case the recent scans saw only the end wall: they fit the scan no better than the
    # online map does, and the online map's match stands.
    local, scan = _misplaced_room(check_rad, recent)
    motion = local.step(np.array([0.0, 0.0, turn]), scan)
    assert local.checks_taken == taken
    assert abs(float(motion[2]) - (-0.04 if taken else 0.12)) < 0.015  # the submap's turn or the online map's
    # both frames move by the one motion: the online pose on the online map, the chain pose in the submaps' frame
    assert np.allclose(local.online, se2_compose(ROBOT_ONLINE, motion)) and np.allclose(local.chain, se2_compose(ROBOT_CHAIN, motion))


@pytest.mark.parametrize(("submap_at_map_motion", "online_fit", "taken"), [(0.2, 0.2, 1), (0.85, 0.2, 0), (0.2, 0.85, 0)])
def test_the_submaps_motion_is_taken_only_where_the_recent_scans_clearly_fit_it_better(monkeypatch, submap_at_map_motion, online_fit, taken):
    # The fits stubbed: the recent scans fit 0.9 at their own match and `submap_at_map_motion` at the online map's
    # motion; the online map fits `online_fit` at its match. Both margins must exceed CHECK_FIT (0.1).
    from slamlab.slam.graph import local as local_module

    local, scan = _misplaced_room(0.1)
    submap_grid = local.submaps.matching().grid

    def fit(grid, pose, pts):
        if grid is submap_grid:  # its own match turns the chain's yaw -0.04; the online map's motion 0.12
            return 0.9 if abs(float(pose[2]) - ROBOT_CHAIN[2]) < 0.06 else submap_at_map_motion
        return online_fit

    monkeypatch.setattr(local_module, "_mean_fit", fit)
    local.step(np.zeros(3), scan)
    assert local.checks_taken == taken


def test_the_local_check_is_on_by_default_and_read_only_on_the_map_of_everything(loop_log):
    from slamlab.config.slam import GraphFilterConfig  # the user's mistakes, named

    with pytest.raises(ConfigError, match="filter.local_check_rad"):
        GraphFilterConfig(local_check_rad=-0.1)
    assert GraphFilterConfig().local_check_rad == 0.03
    # the other local maps have no online map to check: the default is accepted there and not read
    assert GraphFilterConfig(local_map="submap").local_check_rad == 0.03
    assert "local_checks_taken" in _run(loop_log, "steps.max_scans=300").extras["graph"]
    assert "local_checks_taken" not in _run(loop_log, "steps.max_scans=300", "filter.local_map=submap").extras["graph"]
    assert "local_checks_taken" not in _run(loop_log, "steps.max_scans=300", "filter.local_check_rad=0").extras["graph"]
    assert "local_turns_held" in _run(loop_log, "steps.max_scans=300").extras["graph"]  # on by default too (`_held`)
    assert "local_turns_held" not in _run(loop_log, "steps.max_scans=300", "filter.local_weak_fit=0").extras["graph"]


@pytest.mark.parametrize(("turn", "weak_fit", "held"), [(0.0, 0.0, False), (0.0, 0.99, True), (0.0, 0.05, False), (0.1, 0.99, False)])
def test_a_large_turn_from_a_poor_fit_keeps_the_odometrys_yaw(turn, weak_fit, held):
    # The online map's match turns the robot 0.12 rad (it holds two of the room's walls turned so). The odometry says
    # `turn`. Where that is more than 0.07 rad from the match and the scan fits the online map below `weak_fit` at
    # the match, the node keeps the odometry's yaw, its x and y matched with the yaw held; otherwise the match stands
    # (off, a fit above the bar, or an odometry turn near the match's).
    local, scan = _misplaced_room(0.0)
    local.weak_fit = weak_fit
    local._turn_gaps = [0.003] * 20  # twenty nodes before, each within 0.003 rad of the odometry's turn
    motion = local.step(np.array([0.0, 0.0, turn]), scan)
    assert local.turns_held == int(held)
    if held:
        assert abs(float(motion[2]) - turn) < 1e-6  # the yaw exactly the odometry's: no yaw search, no turn in the refinement
    else:
        assert abs(float(motion[2]) - 0.12) < 0.015


def test_the_held_yaw_is_taken_only_below_the_fit_bar(monkeypatch):
    from slamlab.slam.graph import local as local_module

    local, scan = _misplaced_room(0.0)
    local.weak_fit, local._turn_gaps = 0.5, [0.003] * 20
    monkeypatch.setattr(local_module, "_mean_fit", lambda grid, pose, pts: 0.5)  # at the bar: the match stands
    assert abs(float(local.step(np.zeros(3), scan)[2]) - 0.12) < 0.015 and local.turns_held == 0
    local, scan = _misplaced_room(0.0)
    local.weak_fit, local._turn_gaps = 0.5, [0.003] * 20
    monkeypatch.setattr(local_module, "_mean_fit", lambda grid, pose, pts: 0.49)
    assert abs(float(local.step(np.zeros(3), scan)[2])) < 1e-6 and local.turns_held == 1


@pytest.mark.parametrize(("gaps", "held"), [([0.003] * 20, True), ([0.003] * 19, False), ([0.02] * 20, False)])
def test_the_odometrys_yaw_is_held_only_where_it_has_been_good(gaps, held):
    # The match turns 0.12 rad from the odometry. Held after 20 nodes within 0.003 rad of theirs; not before 20 nodes
    # have said how good the odometry is, nor where it has been off by 0.02 rad a node (0.12 is 6 times that, not 8).
    local, scan = _misplaced_room(0.0)
    local.weak_fit, local._turn_gaps = 0.99, list(gaps)
    local.step(np.zeros(3), scan)
    assert local.turns_held == int(held)


def test_the_weak_fit_bar_is_a_fraction():
    from slamlab.config.slam import GraphFilterConfig

    for bad in (-0.1, 1.5):
        with pytest.raises(ConfigError, match="filter.local_weak_fit"):
            GraphFilterConfig(local_weak_fit=bad)
    assert GraphFilterConfig().local_weak_fit == 0.5 and GraphFilterConfig(local_weak_fit=0).local_weak_fit == 0  # 0: off
