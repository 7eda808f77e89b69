"""Where the particles' map lives: the `filter/` config group.

- `course` (`SharedMapFilter`): the course's filter. All particles match against one shared
  map, built from the highest-weight particle's pose at every step. Fast and precise while
  tracking holds, but no particle carries an alternative map, so a slipped match corrupts
  the only map and loops close only if tracking never slipped.
- `rbpf` (`RaoBlackwellFilter`): a Rao-Blackwellised particle filter in the GMapping sense.
  Every particle carries its own occupancy map (and likelihood field) in copy-on-write tiles
  (`tiles.TiledMaps`), updated with its own pose; each particle is matched against its own
  map (the scan-matched proposal), and resampling hands a child its parent's map by sharing
  tiles. The final map is the best particle's.

Both present the engine the same small interface (`ParticleMaps`): match, update, resample,
the final image and memory figures.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

from slamlab.frames import GridImage
from slamlab.geometry import FloatArray
from slamlab.slam.grid import MapSettings, OccupancyGrid
from slamlab.slam.matcher import MatchPoints, Matcher
from slamlab.slam.replay import reduce_map, reduce_tiled_map
from slamlab.slam.scan import ScanBatch, ScanPoints, points_to_world
from slamlab.slam.tiles import TiledMaps


def _field(matcher: Matcher | None) -> tuple[float, float]:
    """(sigma m, radius m) of the likelihood field the matcher reads (0, 0: none)."""
    if matcher is None:
        return 0.0, 0.0
    return matcher.field_sigma_m, matcher.field_radius_m


class ParticleMaps(ABC):
    """The map(s) of N particles, as the engine sees them."""

    @abstractmethod
    def match(self, matcher: Matcher, poses: FloatArray, scan: ScanPoints, step_scale: float = 1.0) -> tuple[FloatArray, FloatArray]:
        """Scan-match every particle; returns (poses (N, 3), scores (N,)). `step_scale`: see
        `FilterKind.step_scale`."""

    def prepare_scans(self, matcher: Matcher, scans: ScanBatch) -> ScanBatch | MatchPoints:
        """Scans as `match_scans` takes them, prepared many at a time (here as they are)."""
        return scans

    @abstractmethod
    def match_scans(self, matcher: Matcher, p: int, poses: FloatArray, scans: ScanBatch | MatchPoints) -> FloatArray:
        """Scan-match scans[i] (none empty; from `prepare_scans`), predicted at poses[i] (S,
        3), against particle p's map (the maps stay as they are); returns the matched poses (S, 3)."""

    @abstractmethod
    def update(self, poses: FloatArray, scan: ScanPoints, best: int) -> None:
        """Add the scan to the map(s), seen from `poses` (N, 3); `best` is the top particle."""

    @abstractmethod
    def resample(self, idx: np.ndarray) -> None:
        """Particle j continues old particle idx[j]."""

    @abstractmethod
    def image(self, best: int) -> GridImage:
        """The map of particle `best` as stored: log-odds (float32), or integer codes whose
        log-odds are `decode_image(image, self.unit)` (the RBPF's one-byte tiles: a quarter
        of the memory while the particles' maps are still held)."""

    @property
    def unit(self) -> float:
        """Log-odds of one step of `image`'s values (1.0: they are log-odds)."""
        return 1.0

    def snapshot(self, best: int) -> tuple[np.ndarray, tuple[float, float, float, float]]:
        """Particle `best`'s map reduced for the replay (`replay.reduce_map`)."""
        return reduce_map(self.image(best), unit=self.unit)

    @abstractmethod
    def memory(self) -> dict:
        """MB held by the maps now and at peak, and how (tiles, cells)."""


class SharedMap(ParticleMaps):
    """One log-odds grid for all particles, updated from the best one (the course filter)."""

    def __init__(self, settings: MapSettings, start_xy: tuple[float, float], matcher: Matcher | None) -> None:
        self.grid = OccupancyGrid(settings, start_xy, *_field(matcher))
        self.peak_mb = 0.0

    def match(self, matcher: Matcher, poses: FloatArray, scan: ScanPoints, step_scale: float = 1.0) -> tuple[FloatArray, FloatArray]:
        return matcher.match(self.grid, poses, scan)

    def match_scans(self, matcher: Matcher, p: int, poses: FloatArray, scans: ScanBatch | MatchPoints) -> FloatArray:
        assert isinstance(scans, ScanBatch), "the shared map matches scans as they are"
        out = np.empty((len(scans), 3))
        for i in range(len(scans)):
            out[i] = matcher.match(self.grid, poses[i:i + 1], scans.points(i))[0][0]
        return out

    def update(self, poses: FloatArray, scan: ScanPoints, best: int) -> None:
        bp = poses[best]
        sensor = points_to_world(scan.origin.reshape(1, 2), bp)[0]
        self.grid.insert(sensor, points_to_world(scan.xy, bp))
        self.peak_mb = max(self.peak_mb, self._mb())

    def resample(self, idx: np.ndarray) -> None:
        pass  # the one map belongs to no particle

    def image(self, best: int) -> GridImage:
        return self.grid.to_image()

    def _mb(self) -> float:
        g = self.grid
        return g.nbytes / 1e6

    def memory(self) -> dict:
        H, W = self.grid.shape
        return {"map_mb": self._mb(), "map_peak_mb": self.peak_mb, "map_cells": int(H * W), "map_grow_count": self.grid.grow_count}


class PerParticleMaps(ParticleMaps):
    """A map per particle in shared copy-on-write tiles (the RBPF)."""

    def __init__(self, settings: MapSettings, n: int, start_xy: tuple[float, float], matcher: Matcher | None) -> None:
        self.maps = TiledMaps(settings, n, start_xy, *_field(matcher))
        self._identical = True  # all particles hold the same map (at the start)
        self.peak_mb = 0.0

    def match(self, matcher: Matcher, poses: FloatArray, scan: ScanPoints, step_scale: float = 1.0) -> tuple[FloatArray, FloatArray]:
        # a shorter step than the reference gets a proportionally narrower prior (sigma)
        return matcher.match_each(self.maps, poses, scan, prior_scale=step_scale**2)

    def prepare_scans(self, matcher: Matcher, scans: ScanBatch) -> ScanBatch | MatchPoints:
        return matcher.prepare_scans(scans)

    def match_scans(self, matcher: Matcher, p: int, poses: FloatArray, scans: ScanBatch | MatchPoints) -> FloatArray:
        return matcher.match_scans(self.maps, p, poses, scans)

    def update(self, poses: FloatArray, scan: ScanPoints, best: int) -> None:
        if len(scan.xy) == 0:
            return
        if self._identical and np.all(poses == poses[0]):
            # same map, same pose: insert once and share it (the first step)
            self.maps.insert_scan(poses, scan.xy, scan.origin, which=np.array([0]))
            self.maps.share_all_from(0)
        else:
            self.maps.insert_scan(poses, scan.xy, scan.origin)
        self._identical = False
        self.peak_mb = max(self.peak_mb, self.maps.memory_mb(self.maps.peak_tiles))

    def resample(self, idx: np.ndarray) -> None:
        self.maps.resample(idx)

    def image(self, best: int) -> GridImage:
        return self.maps.to_image(best, decoded=False)

    @property
    def unit(self) -> float:
        return self.maps.lo_unit

    def snapshot(self, best: int) -> tuple[np.ndarray, tuple[float, float, float, float]]:
        return reduce_tiled_map(self.maps, best)  # from the tiles, without gathering the map

    def memory(self) -> dict:
        m = self.maps
        return {
            "map_mb": m.memory_mb(),
            "map_peak_mb": self.peak_mb,
            "map_tiles": m.tiles_in_use,
            "map_tiles_peak": m.peak_tiles,
            "map_tiles_taken": m.tiles_taken,
            "map_table_tiles": int(m.table.shape[1] * m.table.shape[2]),  # per particle, incl. empty
            "map_grow_count": m.grow_count,
        }


class FilterKind(ABC):
    """A `filter/` choice. `family` names the loop that runs it: `particles` (the particle
    filters' loop, `slam.engine`, which asks `maps` for the particles' maps) or `graph`
    (`slam.graph.run`: submaps and a pose graph, one trajectory)."""

    name: str = ""
    family: str = "particles"
    # the online (causal) pose at each step: "best" = the highest-weight particle, "mean" =
    # the weighted mean of all particles (`geometry.weighted_mean_pose`)
    online: str = "best"

    def step_scale(self, increment: FloatArray) -> float:
        """The step in reference steps, at most 1 (1 = the prior as configured): see
        `RaoBlackwellFilter`."""
        return 1.0

    def maps(self, settings: MapSettings, n: int, start_xy: tuple[float, float], matcher: Matcher | None) -> ParticleMaps:
        """The particles' maps for a run (`family` particles; also for mode odometry / predict,
        which the particle loop runs whatever the filter)."""
        return SharedMap(settings, start_xy, matcher)


class SharedMapFilter(FilterKind):
    """`filter=course`: one map from the best particle (see module doc)."""

    name = "course"

    def __init__(self, online: str = "best") -> None:  # checked by CourseFilterConfig
        self.online = online

    def maps(self, settings: MapSettings, n: int, start_xy: tuple[float, float], matcher: Matcher | None) -> ParticleMaps:
        return SharedMap(settings, start_xy, matcher)


class RaoBlackwellFilter(FilterKind):
    """`filter=rbpf`: a map per particle in copy-on-write tiles (see module doc).

    `step_ref_m` / `step_ref_rad` (> 0, or null = off): the length of the step the matcher's
    motion prior was set for. A step of odometry length d and turn a counts
    s = d / step_ref_m + |a| / step_ref_rad reference steps; when s < 1 the prior's sigma
    shrinks by s, so that shorter steps (lower step thresholds) cannot move the robot
    further per metre than reference steps do (each step's correction is bounded by the
    prior, and there are 1/s times as many). Longer steps keep the reference prior.
    Off in every preset: with +experiment=lidar2d on ACES at 0.1 m / 0.1 rad thresholds it made
    things worse (3 of 5 seeds lost a loop with it, 1 of 5 without; worst 0.117 vs 0.114 m)."""

    name = "rbpf"

    # defaults and checks: `slamlab.config.slam.RbpfFilterConfig` (both null = off)
    def __init__(self, step_ref_m: float | None = None, step_ref_rad: float | None = None, online: str = "best") -> None:
        self.online = online
        self.step_ref_m = None if step_ref_m is None else float(step_ref_m)
        self.step_ref_rad = None if step_ref_rad is None else float(step_ref_rad)

    def step_scale(self, increment: FloatArray) -> float:
        if self.step_ref_m is None or self.step_ref_rad is None:
            return 1.0
        s = float(np.hypot(increment[0], increment[1]) / self.step_ref_m + abs(increment[2]) / self.step_ref_rad)
        return min(max(s, 1e-3), 1.0)

    def maps(self, settings: MapSettings, n: int, start_xy: tuple[float, float], matcher: Matcher | None) -> ParticleMaps:
        return PerParticleMaps(settings, n, start_xy, matcher)
