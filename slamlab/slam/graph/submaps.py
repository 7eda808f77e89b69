"""Submaps: small occupancy grids built from a run of consecutive nodes (Hess et al. 2016).

Local SLAM works in its own frame (the local frame, where the matched poses drift freely);
a submap is a log-odds grid with its likelihood field in that frame, built from the scans of
`submap_nodes` consecutive nodes. Two are active at once: a new submap starts every
`submap_nodes / 2` nodes, every node goes into both active ones, and scans are matched against
the older (fuller) one, so the robot is always inside a submap with at least half its scans.
When a submap has all its nodes it is finished: its field is kept as one-byte codes over
the cells it knows, with each cell's state (unknown, free, occupied), compressed (a few per
cent of its float32 log-odds and field), and it becomes a target of the loop search.

(With `overlap` off, one is active at a time: when local SLAM matches against a map of
everything, the submaps are only the loop search's targets, and half the insertions do.)

A submap is rigid: its global placement is that of its first node (its anchor) in the pose
graph, G = X_anchor (+) inv(L_anchor), L the anchor's local pose. Re-placing submaps after an
optimisation is therefore free: they follow their anchors.
"""

from __future__ import annotations

import zlib
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from slamlab.geometry import FloatArray
from slamlab.slam.grid import MapSettings, OccupancyGrid
from slamlab.slam.graph.branch_bound import SearchGrid
from slamlab.slam.scan import ScanPoints, points_to_world

FIELD_CODES = 255.0  # a finished submap's field value v in [0, 1] is kept as round(255 v)
# the value of each of those codes, float32 (code / 255), for the field readers (`field_cells`)
FIELD_LUT = np.arange(256, dtype=np.float32) * np.float32(1.0 / FIELD_CODES)
UNKNOWN, FREE, OCCUPIED = 0, 1, 2  # a finished submap's cell states
UNPACKED = 8  # finished submaps kept unpacked at once (and their search grids)


@dataclass(slots=True)
class FinishedSubmap:
    """A finished submap, as the loop search reads it: over its known cells ([H, W], row = y;
    origin (m, local frame), cell size (m)) the likelihood field as one-byte codes and the
    cells' states (UNKNOWN, FREE, OCCUPIED), kept zlib-compressed (`packed`: a building's
    submaps are mostly unknown cells; `Submaps.arrays` unpacks the few in use); `anchor` its
    first node and `anchor_local` that node's local pose; `nodes` the nodes it holds;
    `center` / `radius` (m, local frame) a circle around its known cells."""

    index: int
    anchor: int
    anchor_local: FloatArray
    nodes: tuple[int, int]
    node_ids: np.ndarray  # (K,) the nodes whose scans it holds ...
    node_local: FloatArray  # (K, 3) ... and their local poses (its frame)
    shape: tuple[int, int]
    packed: bytes
    origin: FloatArray
    resolution_m: float
    center: FloatArray
    radius: float

    @property
    def nbytes(self) -> int:
        return len(self.packed)

    @staticmethod
    def pack(field_u8: np.ndarray, state_u8: np.ndarray) -> bytes:
        return zlib.compress(np.stack([field_u8, state_u8]).tobytes(), 1)

    def unpack(self) -> tuple[np.ndarray, np.ndarray]:
        """(field codes, cell states), each uint8 [H, W]."""
        both = np.frombuffer(zlib.decompress(self.packed), dtype=np.uint8).reshape(2, *self.shape)
        return both[0], both[1]


class _Recent(OrderedDict):
    """A dict keeping its `size` most recently used entries."""

    def __init__(self, size: int) -> None:
        super().__init__()
        self.size = size

    def get_or_make(self, key: object, make: Callable[[], object]) -> object:
        if key in self:
            self.move_to_end(key)
            return self[key]
        value = make()
        self[key] = value
        while len(self) > self.size:
            self.popitem(last=False)
        return value

    @property
    def nbytes(self) -> int:
        return sum(sum(a.nbytes for a in v) if isinstance(v, tuple) else v.nbytes for v in self.values())


def search_grid_of(field_u8: np.ndarray, origin: FloatArray, res_m: float, search_res_m: float, levels: int) -> SearchGrid:
    """The branch-and-bound grid of a submap's field: max-pooled over blocks of whole cells to
    about `search_res_m` (the largest value in each block: a point the search places in a block
    scores what its best spot in the block would), with its `levels` precomputed grids."""
    f = max(int(round(search_res_m / res_m)), 1)
    H, W = field_u8.shape
    Hc, Wc = -(-H // f), -(-W // f)
    padded = np.zeros((Hc * f, Wc * f), dtype=np.uint8)
    padded[:H, :W] = field_u8
    # the block maxima as the max of f x f strided views: the same values as reshaping to
    # (Hc, f, Wc, f) and reducing over axes 1 and 3, which numpy does ~20x slower
    coarse = padded[0::f, 0::f].copy()
    for i in range(f):
        for j in range(f):
            np.maximum(coarse, padded[i::f, j::f], out=coarse)
    return SearchGrid.of(coarse, (float(origin[0]), float(origin[1])), f * res_m, levels)


@dataclass(slots=True)
class ActiveSubmap:
    """A submap still taking scans: its grid (local frame) and the nodes inserted so far."""

    index: int
    anchor: int
    anchor_local: FloatArray
    grid: OccupancyGrid
    count: int = 0
    node_ids: list = field(default_factory=list)
    node_local: list = field(default_factory=list)


class Submaps:
    """The active submaps and the finished ones (see module doc)."""

    def __init__(self, settings: MapSettings, nodes_per_submap: int, field_sigma_m: float, field_radius_m: float, overlap: bool = True,
                 field_when_finished: bool = False, walls_at_hits: bool = False) -> None:
        self.settings = settings
        self.n = int(nodes_per_submap)
        # two active at once (a new one every n / 2 nodes), or one (a new one every n nodes: when
        # no scan is matched against them, they are only the loop search's targets)
        self.start_every = max(self.n // 2, 1) if overlap else self.n
        self.sigma = field_sigma_m
        self.radius = field_radius_m
        # when no scan is matched against an active submap (local_map=map), its likelihood field is
        # computed once when it is finished instead of scan by scan (the same values: grid.start_field)
        self.field_when_finished = field_when_finished
        self.walls_at_hits = walls_at_hits  # each wall's field peak at its hits' mean (`grid.OccupancyGrid`)
        self.active: list[ActiveSubmap] = []
        self.finished: list[FinishedSubmap] = []
        self.anchors: list[int] = []  # submap index -> anchor node
        self.peak_mb = 0.0
        self._settings: MapSettings | None = None
        # the finished submaps' anchors (S,), anchor local poses (S, 3), centres (S, 2) and radii (S,)
        self.finished_anchor = np.zeros(0, dtype=np.int64)
        self.finished_anchor_local = np.zeros((0, 3))
        self.finished_center = np.zeros((0, 2))
        self.finished_radius = np.zeros(0)
        self.finished_view = np.zeros((0, 2))  # where each was seen from: the mean of its nodes' positions (m, local frame)
        # the few finished submaps in use, unpacked, and their search grids (a revisit searches
        # the same few submaps node after node)
        self._arrays = _Recent(UNPACKED)
        self._grids = _Recent(UNPACKED)
        self._packed_bytes = 0
        self._screen: dict[tuple[int, float, int], SearchGrid] = {}
        self._screen_bytes = 0

    def arrays(self, sm: FinishedSubmap) -> tuple[np.ndarray, np.ndarray]:
        """A finished submap's (field codes, cell states), unpacked (kept for the last few)."""
        return self._arrays.get_or_make(sm.index, sm.unpack)  # type: ignore[return-value]

    def search_grid(self, sm: FinishedSubmap, search_res_m: float, levels: int) -> SearchGrid:
        """A finished submap's branch-and-bound grid (`search_grid_of`; kept for the last few)."""
        return self._grids.get_or_make((sm.index, search_res_m, levels),  # type: ignore[return-value]
                                       lambda: search_grid_of(self.arrays(sm)[0], sm.origin, sm.resolution_m, search_res_m, levels))

    def screen_grid(self, sm: FinishedSubmap, screen_res_m: float, levels: int) -> SearchGrid:
        """A finished submap's coarse search grid for the loop search's screen (`search_grid_of`
        at `screen_res_m`): made once and kept (a few kB: the screen reads every untied submap)."""
        key = (sm.index, screen_res_m, levels)
        grid = self._screen.get(key)
        if grid is None:
            grid = self._screen[key] = search_grid_of(self.arrays(sm)[0], sm.origin, sm.resolution_m, screen_res_m, levels)
            self._screen_bytes += grid.nbytes
        return grid

    def matching(self) -> ActiveSubmap:
        """The submap scans are matched against: the oldest active one."""
        return self.active[0]

    def insert(self, node: int, local_pose: FloatArray, scan: ScanPoints) -> list[FinishedSubmap]:
        """Add node `node`'s scan, seen from `local_pose`, to the active submaps (starting a
        new one when due); returns the submaps this finished."""
        if not self.active or self.active[-1].count >= self.start_every:
            index = len(self.anchors)
            grid = OccupancyGrid(self._submap_settings(), (float(local_pose[0]), float(local_pose[1])),
                                 0.0 if self.field_when_finished else self.sigma, self.radius, self.walls_at_hits)
            self.active.append(ActiveSubmap(index, node, np.asarray(local_pose, dtype=np.float64).copy(), grid))
            self.anchors.append(node)
        if len(scan.xy):
            sensor = points_to_world(scan.origin.reshape(1, 2), local_pose)[0]
            world = points_to_world(scan.xy, local_pose)
            for s in self.active:
                s.grid.insert(sensor, world)
        for s in self.active:
            s.count += 1
            s.node_ids.append(node)
            s.node_local.append(np.asarray(local_pose, dtype=np.float64).copy())
        done = []
        while self.active and self.active[0].count >= self.n:
            done.append(self._finish(self.active.pop(0), node))
        self.peak_mb = max(self.peak_mb, self.memory_mb())
        return done

    def _submap_settings(self) -> MapSettings:
        """The map settings for a submap: a small start that the first scan grows to its own
        extent, and a few metres of margin whenever it grows (a submap sees a few metres of
        travel; a run's map settings are sized for the whole building)."""
        if self._settings is None:
            self._settings = replace(self.settings, initial_size_m=1.0, growth_margin_m=min(self.settings.growth_margin_m, 4.0))
        return self._settings

    def _finish(self, s: ActiveSubmap, last_node: int) -> FinishedSubmap:
        g = s.grid
        if g.field is None:
            g.start_field(self.sigma, self.radius)
        assert g.field is not None
        known = np.flatnonzero(g.log_odds.any(axis=1)), np.flatnonzero(g.log_odds.any(axis=0))
        R = g.field_radius
        H, W = g.shape
        if len(known[0]):
            r0, r1 = max(int(known[0][0]) - R, 0), min(int(known[0][-1]) + R + 1, H)
            c0, c1 = max(int(known[1][0]) - R, 0), min(int(known[1][-1]) + R + 1, W)
        else:
            r0, r1, c0, c1 = 0, 1, 0, 1
        codes = np.rint(g.field_lut * FIELD_CODES).astype(np.uint8)[g.field[r0:r1, c0:c1]]  # each grid code's byte, then looked up
        lo = g.log_odds[r0:r1, c0:c1]
        state = np.where(lo > g.s.occupied_threshold, OCCUPIED, np.where(lo < 0, FREE, UNKNOWN)).astype(np.uint8)
        origin = g.origin + np.array([c0, r0]) * g.res
        size = np.array([c1 - c0, r1 - r0]) * g.res
        f = FinishedSubmap(
            index=s.index, anchor=s.anchor, anchor_local=s.anchor_local, nodes=(s.anchor, last_node),
            node_ids=np.array(s.node_ids, dtype=np.int64), node_local=np.array(s.node_local), shape=codes.shape,
            packed=FinishedSubmap.pack(codes, state), origin=origin, resolution_m=g.res,
            center=origin + size / 2, radius=float(np.hypot(*size) / 2),
        )
        self.finished.append(f)
        self._packed_bytes += f.nbytes
        self.finished_anchor = np.append(self.finished_anchor, f.anchor)
        self.finished_anchor_local = np.vstack([self.finished_anchor_local, f.anchor_local])
        self.finished_center = np.vstack([self.finished_center, f.center])
        self.finished_radius = np.append(self.finished_radius, f.radius)
        self.finished_view = np.vstack([self.finished_view, f.node_local[:, :2].mean(axis=0)])
        return f

    def release(self) -> None:
        """After the last node no scan is matched or searched against a submap again: their
        maps and search grids go before the final map is drawn (the hospital log's: ~50 MB);
        the anchors and the peak stay for the metrics."""
        self.active.clear()
        self.finished.clear()
        self._arrays.clear()
        self._grids.clear()
        self._screen.clear()
        self._packed_bytes = self._screen_bytes = 0

    def memory_mb(self) -> float:
        """MB held: the active submaps' grids, the finished ones packed, and those unpacked."""
        active = sum(s.grid.nbytes for s in self.active)
        return (active + self._packed_bytes + self._arrays.nbytes + self._grids.nbytes + self._screen_bytes) / 1e6
