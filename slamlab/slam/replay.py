"""Snapshots of the filter for the report's replay (`replay.npz`, `record.replay`).

Design: the report scrubs through about 100 moments of the run, so the engine keeps only
those moments, not every step: at each snapshot step it stores the best particle's map
cropped to its observed cells and block-reduced to at most `MAX_MAP_PX` cells a side (one
byte per cell), every particle's pose, and the current scan's points at the best pose
(at most `MAX_SCAN_POINTS`). The best path and N_eff at that moment come from files the run
writes anyway (trajectory_causal.tum, steps.csv). Cost: one map copy and a block reduction
per snapshot (100 per run, a few ms each), and well under 1 MB compressed on disk.
The recorder reads the filter's state and never touches its random generator, so recording
does not change a trajectory.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from slamlab.frames import GridImage
from slamlab.geometry import FloatArray
from slamlab.numeric import block_max, evenly_spaced  # noqa: F401  (block_max: shared with the reports)

if TYPE_CHECKING:
    from slamlab.slam.tiles import TiledMaps

SNAPSHOTS = 100
MAX_MAP_PX = 256
MAX_SCAN_POINTS = 240


def snapshot_steps(n_steps: int, count: int = SNAPSHOTS) -> np.ndarray:
    """Indices of `count` steps (or all of them) spread evenly over the run, last step included."""
    return evenly_spaced(n_steps, count)


def reduce_map(grid: GridImage, max_px: int = MAX_MAP_PX, unit: float = 1.0) -> tuple[np.ndarray, tuple[float, float, float, float]]:
    """The observed part of a log-odds grid as uint8 free-ness (255 free, 0 occupied, 128
    unknown), block-reduced to <= max_px a side keeping each block's most occupied cell
    (thin walls survive), and its extent (x0, x1, y0, y1) in metres (row 0 = lowest y).
    The grid may hold integer codes of log-odds in steps of `unit` (`tiles.decode_image`)."""
    from slamlab.slam.map_reduce import block_max_1pass, known_bounds  # numba: the engine's path only

    data = grid.data
    r0, r1, c0, c1 = known_bounds(data, data.dtype.type(1e-6))
    if r1 == 0:
        return _unknown(grid.resolution_m, grid.origin_xy)
    k = _block(r1 - r0, c1 - c0, max_px)
    return _free_ness(block_max_1pass(data[r0:r1, c0:c1], k), k, r0, c0, grid.resolution_m, grid.origin_xy, unit)


def reduce_tiled_map(maps: TiledMaps, p: int, max_px: int = MAX_MAP_PX) -> tuple[np.ndarray, tuple[float, float, float, float]]:
    """`reduce_map(maps.to_image(p, decoded=False), max_px, maps.lo_unit)`, the same bytes,
    read straight from particle p's tiles: no whole-map gather at each snapshot (on a
    building's map the gather and the reduction took 3.7 s of a 62 s run)."""
    from slamlab.slam.map_reduce import lowest_value, tiled_block_max, tiled_known_bounds
    from slamlab.slam.tiles import TILE

    tab = maps.table[p]
    pool = maps.pool_lo
    # `to_image`'s crop and origin, so extents match to the bit
    (tr0, _, tc0, _), origin = maps.written_tiles(p)
    crop_r, crop_c = tr0 * TILE, tc0 * TILE
    r0, r1, c0, c1 = tiled_known_bounds(tab, pool, TILE, pool.dtype.type(1e-6))
    if r1 == 0:
        return _unknown(maps.res, origin)
    k = _block(r1 - r0, c1 - c0, max_px)
    crop = tiled_block_max(tab, pool, TILE, r0, r1, c0, c1, k, lowest_value(pool.dtype))
    return _free_ness(crop, k, r0 - crop_r, c0 - crop_c, maps.res, origin, maps.lo_unit)


def _unknown(res: float, origin_xy: tuple[float, float]) -> tuple[np.ndarray, tuple[float, float, float, float]]:
    ox, oy = origin_xy
    return np.full((1, 1), 128, np.uint8), (ox, ox + res, oy, oy + res)


def _block(h: int, w: int, max_px: int) -> int:
    return max(1, int(math.ceil(max(h, w) / max_px)))


def _free_ness(crop: np.ndarray, k: int, r0: int, c0: int, res: float, origin_xy: tuple[float, float],
               unit: float) -> tuple[np.ndarray, tuple[float, float, float, float]]:
    """uint8 free-ness of a block-reduced crop whose first cell is (r0, c0) of a grid at
    `origin_xy`, and the crop's extent (m)."""
    ox, oy = origin_xy
    p_free = 1.0 - 1.0 / (1.0 + np.exp(-np.clip(crop.astype(np.float64) * unit, -30, 30)))
    extent = (ox + c0 * res, ox + (c0 + crop.shape[1] * k) * res, oy + r0 * res, oy + (r0 + crop.shape[0] * k) * res)
    return np.round(p_free * 255).astype(np.uint8), extent


@dataclass
class ReplayRecorder:
    """Collects snapshots during `run_slam`; `arrays()` packs them for `replay.npz`."""

    steps: np.ndarray
    _step: list[int] = field(default_factory=list)
    _poses: list[np.ndarray] = field(default_factory=list)
    _best: list[int] = field(default_factory=list)
    _scan: list[np.ndarray] = field(default_factory=list)
    _maps: list[np.ndarray] = field(default_factory=list)
    _extent: list[tuple[float, float, float, float]] = field(default_factory=list)

    _wanted: frozenset[int] = field(init=False)  # `steps` as a set: np.isin cost ~0.1 ms a step

    def __post_init__(self) -> None:
        self._wanted = frozenset(int(s) for s in self.steps)

    def wants(self, k: int) -> bool:
        return k in self._wanted

    def add(self, k: int, poses: FloatArray, best: int, scan_world: FloatArray,
            reduced: tuple[np.ndarray, tuple[float, float, float, float]]) -> None:
        """Step k after its map update: particle poses (N, 3), the best one's index, its scan
        points in the world frame (M, 2) and its map as `reduce_map` (or `reduce_tiled_map`)
        gives it."""
        img, extent = reduced
        keep = np.linspace(0, len(scan_world) - 1, min(len(scan_world), MAX_SCAN_POINTS)).round().astype(int) if len(scan_world) else []
        self._step.append(k)
        self._poses.append(np.asarray(poses, np.float32))
        self._best.append(int(best))
        self._scan.append(np.asarray(scan_world, np.float32)[keep].reshape(-1, 2))
        self._maps.append(img)
        self._extent.append(extent)

    def arrays(self) -> dict[str, np.ndarray]:
        """Ragged scans and maps flattened with their lengths/shapes (docs/RUN_DIRECTORY.md)."""
        return {
            "step": np.array(self._step, np.int64),
            "poses": np.stack(self._poses) if self._poses else np.zeros((0, 0, 3), np.float32),
            "best": np.array(self._best, np.int64),
            "scan_xy": np.concatenate(self._scan) if self._scan else np.zeros((0, 2), np.float32),
            "scan_count": np.array([len(s) for s in self._scan], np.int64),
            "map_pixels": np.concatenate([m.ravel() for m in self._maps]) if self._maps else np.zeros(0, np.uint8),
            "map_shape": np.array([m.shape for m in self._maps], np.int64).reshape(-1, 2),
            "map_extent": np.array(self._extent, np.float64).reshape(-1, 4),
        }
