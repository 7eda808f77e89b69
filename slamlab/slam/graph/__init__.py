"""Graph SLAM (`filter=graph`): one trajectory, no particles, loops closed explicitly.

The stages, each its own module (Hess et al. 2016, "Real-time loop closure in 2D LIDAR SLAM",
for the shape; Olson 2009 for the search):
- `submaps`: local SLAM's maps, two active at once, finished ones kept for the loop search;
- `branch_bound`: the exact correlative search over x, y, yaw on max-pooled grids;
- `loops`: a node's scan against the finished submaps within a window that grows with the
  distance since the last closure, refined, with an ambiguity test;
- `verify`: which candidates enter the graph (alone in a narrow window, in pairwise-consistent
  groups from a wide one);
- `pose_graph`: the nodes and edges, optimised with GTSAM under a robust loss;
- `run`: the loop that drives them and returns the same `SlamResult` as the particle filters.
`GraphFilter` is the `filter=graph` choice: its knobs, checked by
`slamlab.config.slam.GraphFilterConfig`.
"""

from __future__ import annotations

from slamlab.config.slam import GraphFilterConfig
from slamlab.slam.filters import FilterKind


class GraphFilter(FilterKind):
    """`filter=graph` (see the package doc); `settings` holds every knob, typed and checked."""

    name = "graph"
    family = "graph"

    def __init__(self, **knobs: object) -> None:
        self.settings = GraphFilterConfig(**knobs)  # type: ignore[arg-type]
