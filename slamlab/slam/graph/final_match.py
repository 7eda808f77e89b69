"""The smoothed trajectory's last pass: every scan matched once more on the finished map.

    match_on_final_map(trajectory, node_scans, points, project, matcher, settings, walls_at_hits) -> trajectory

The graph places its nodes; a scan between two nodes takes its node's pose (+) the motion
matched on the online map of that moment, which was drawn at the online poses, before any
loop closure straightened it. Once the graph is optimised, a map drawn from every node's
scan at its optimised pose is the best map the run has: each scan (nodes included) is
matched on it once, from its smoothed pose and with the matcher's motion prior around that
pose. The first node keeps its pose (the start, which fixes the map's frame), and so do the
scans before it (the robot standing at the start: they follow it by odometry, as
`steps.fill_between_steps` places them). The causal (online) trajectory is not touched: this
pass uses the whole log. It runs when the run matched the scans between its nodes
(`steps.between=match`, the `lidar2d` preset); with `steps.between=odometry` the run leaves
them to odometry, and matching the nodes alone measured worse (below).

Measured (2026-11-30, `lidar2d`, smoothed relation error, before -> after): ACES 0.0373 ->
0.0357 m at 0.5 m steps, 0.0368 -> 0.0353 at 0.25, 0.0373 -> 0.0358 at 0.52; Intel 0.0185 ->
0.0180, 0.0189 -> 0.0189, 0.0203 -> 0.0185. Matching only the nodes (the scans between
keeping their offsets) was worse (ACES 0.0381, Intel 0.0197), and so was it on `sim_loops`
(`steps.between=odometry`; worst ATE at world scale 2.0 0.435 -> 0.445 m, every scan matched
0.445 too, at 14 s for its 27,560 THOR scans); a second pass on a map drawn from the refined
nodes gave nothing more (ACES 0.0358, Intel 0.0190).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from slamlab.geometry import FloatArray
from slamlab.slam.graph.local import map_of_nodes, match_margin_m, park_distance, reach_of
from slamlab.slam.grid import MapSettings
from slamlab.slam.matcher import LikelihoodFieldMatcher
from slamlab.slam.scan import ScanBatch, ScanPoints

CHUNK_SCANS = 512  # scans projected and matched per kernel call: ~3 MB of points on a 361-beam log (and the matcher's copies)


def match_on_final_map(trajectory: FloatArray, node_scans: np.ndarray, points: Callable[[int], ScanPoints],
                       project: Callable[[int, int], ScanBatch], matcher: LikelihoodFieldMatcher, settings: MapSettings,
                       walls_at_hits: bool = False) -> FloatArray:
    """`trajectory` (N, 3: every scan's smoothed pose) with each scan after the first node that
    has points moved to where it matches best on the map of the nodes `node_scans` (increasing
    scan indices) at their poses there (`local.map_of_nodes`, with `walls_at_hits`); `points(i)` gives
    scan i's points, `project(a, b)` scans a..b-1 as a batch. The first node, the scans before
    it and scans without points keep their pose. Returns a new array."""
    node_scans = np.asarray(node_scans, dtype=np.int64)
    park = not walls_at_hits  # the map's rows far from the scans being matched held compressed (`map_of_nodes`)
    grid = map_of_nodes((points(int(i)) for i in node_scans), trajectory[node_scans], matcher, settings, walls_at_hits, park=park)
    out = np.array(trajectory, dtype=np.float64, copy=True)
    margin = match_margin_m(matcher)
    for a in range(int(node_scans[0]) + 1, len(out), CHUNK_SCANS):
        b = min(a + CHUNK_SCANS, len(out))
        batch = project(a, b)
        has = np.flatnonzero(batch.counts > 0) + a
        if len(has):
            ys, reach = trajectory[has, 1], reach_of(batch.xy)
            if park:
                grid.need_rows(float(ys.min()) - reach - margin, float(ys.max()) + reach + margin)
            out[has] = matcher.match_scans_on(grid, trajectory[has], batch.nonempty())[0]
            if park:
                keep = park_distance(reach, margin)
                grid.park_beyond(float(ys.min()) - keep, float(ys.max()) + keep)
    return out
