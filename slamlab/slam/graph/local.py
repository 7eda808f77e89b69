"""Local SLAM: where each processed scan is, relative to what was mapped before it.

The odometry increment predicts each node and the run's likelihood-field matcher (with its
motion prior) moves it to where the scan fits the local map (`filter.local_map`):
- `map`: one map of everything mapped so far, drawn at the online poses (the course filter's
  shared map with one pose). A scan in a place seen before fits that place at once, not only
  after a loop closure and an optimisation, so the online pose does not drift between
  closures (measured: `conf/filter/graph.yaml`). When the graph puts the robot far from where
  this map has it (a long loop closed), the map is drawn again from every node's optimised
  pose (`redraw`) and the online pose becomes the graph's. The same holds a place mapped long
  ago, before its loop closed, where the drifted estimate put it then, and a return there can
  turn the robot: with `filter.local_check_rad` > 0 a node whose match turns it away from the
  odometry is matched once more on the older active submap alone (`LocalSlam._checked`).
- `submap`: the older of the two active submaps (Cartographer's local SLAM); the online pose
  is then the graph's estimate of the newest node.
The matched motion between consecutive nodes is the pose graph's local edge, and the chain
of those motions (the local frame, never redrawn) is where the submaps are built. With
`motion.scale_gain_per_m` > 0 the odometry's translation is scaled by a scale learnt from the
matches, as each particle of the particle filters learns its own (`slam.odometry_scale`); with
`filter.yaw_drift_gain_per_m` > 0 its turn is corrected by a yaw drift per metre learnt the
same way (`slam.odometry_yaw`).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable

import numpy as np

from slamlab.geometry import FloatArray, se2_between, se2_compose, wrap_angle
from slamlab.slam.graph.loops import match_covariance
from slamlab.slam.graph.small_linalg import from_eig, sym_eig
from slamlab.slam.graph.submaps import FinishedSubmap, Submaps
from slamlab.slam.grid import MapSettings, OccupancyGrid
from slamlab.slam.matcher import LikelihoodFieldMatcher, MatchPoints, score_field, voxel_filter
from slamlab.slam.odometry_scale import learn_scales, scaled_start
from slamlab.slam.odometry_yaw import learn_yaw_drift
from slamlab.slam.scan import ScanBatch, ScanPoints, place, points_to_world


def map_points(matcher: LikelihoodFieldMatcher, scan: ScanPoints, near_hits_m: float = 0.0) -> FloatArray:
    """The points of `scan` (body frame) a map is drawn from: those the matcher matches (lone far
    hits left out: seen at a grazing angle they map a wall as a comb of blobs, which holds the next
    matches back along it), without the hits nearer than `near_hits_m` (m) to the lidar
    (`filter.near_hits_m`; 0 = all)."""
    if not len(scan.xy):
        return scan.xy
    walls = matcher.fine_points(scan)
    if near_hits_m > 0:
        walls = walls[np.hypot(walls[:, 0] - scan.origin[0], walls[:, 1] - scan.origin[1]) >= near_hits_m]
    return walls


def map_of_nodes(scans: Iterable[ScanPoints], poses: FloatArray, matcher: LikelihoodFieldMatcher, settings: MapSettings,
                 walls_at_hits: bool = False, near_hits_m: float = 0.0, park: bool = False) -> OccupancyGrid:
    """The map (with its likelihood field) of nodes' scans at `poses` (K, 3), drawn as the
    online map is: `map_points` of each scan, ray-cast in order, walls at their cells'
    centres or (`walls_at_hits`, `filter.wall_at=hits`) at their hits. The online map's redraw
    and the final match's map (`final_match`). `scans` may be made one at a time (a generator):
    each is let go once its map points are placed. `park` (not with `walls_at_hits`): the map
    drawn a group of rows at a time and left with its rows held compressed
    (`OccupancyGrid.park_beyond`; its readers must ask for their rows, `need_rows`)."""
    grid = OccupancyGrid(settings, (float(poses[0, 0]), float(poses[0, 1])), matcher.field_sigma_m, matcher.field_radius_m, walls_at_hits)
    # a scan at a time: only its map points are kept, in the world frame with its lidar centre
    placed = [ScanPoints(points_to_world(map_points(matcher, pts, near_hits_m), pose), points_to_world(pts.origin.reshape(1, 2), pose)[0])
              for pts, pose in zip(scans, poses)]
    batch = ScanBatch.of(placed)
    del placed  # the joined copy is what is cast: not both through the ray-casting (the hospital's ~2 x 30 MB)
    if park:
        grid.start_parking()
    grid.insert_joined(batch.origins, batch.xy, batch.ends, park)
    return grid


REACH_MARGIN_M = 3.0  # beyond a scan's farthest point: at least what a match may move its pose (`match_margin_m`)
PARK_HYSTERESIS_M = 10.0  # rows are parked this much farther out than they are needed, so a robot pacing does not churn them


def match_margin_m(*matchers: LikelihoodFieldMatcher) -> float:
    """How far (m) beyond a scan's farthest point a match may read the map: what it may move a
    pose from its prediction (the coarse offsets' reach, then the hill climb's at most 16 moves
    a level, from half the offsets' step and halving: under 16 steps; Gauss-Newton's under 12),
    plus a metre; `REACH_MARGIN_M` at least."""
    move = max(float(np.abs(m.offsets[:, :2]).max(initial=0.0)) + 16.0 * m.xy_step_m for m in matchers)
    return max(REACH_MARGIN_M, move + 1.0)


def park_distance(reach_m: float, margin_m: float) -> float:
    """How far (m, in y) from the robot the online map's rows stay resident, for scans whose
    farthest point is `reach_m` from the robot and matches that read `margin_m` beyond it."""
    return reach_m + margin_m + PARK_HYSTERESIS_M


def reach_of(body_xy: FloatArray) -> float:
    """The farthest of points (robot frame, m) from the robot (0 for none)."""
    return float(np.sqrt((body_xy ** 2).sum(axis=1).max())) if len(body_xy) else 0.0


CHECK_FIT = 0.1  # `LocalSlam._checked`: how much better (mean field value, 0..1) the recent scans must fit their own match
# `LocalSlam._held`: a match turning the node this far (rad) from the odometry's turn is one a poor fit cannot carry.
# Intel's matches differ from its odometry by 1.6 degrees a step in the median, ACES's by 0.5, the hospital's by 0.2
WEAK_TURN_RAD = 0.07
WEAK_TURN_TIMES = 8.0  # ... and this many times the median of the nodes' before it (the odometry's own yaw noise),
WEAK_TURN_NODES = 20  # ... once this many nodes have told it


def _mean_fit(grid: OccupancyGrid, pose: FloatArray, pts: FloatArray) -> float:
    """The mean likelihood-field value (0..1) of the points `pts` (body frame, m) at `pose` on `grid`."""
    if not len(pts):
        return 0.0
    return float(score_field(grid.field_cells, float(grid.origin[0]), float(grid.origin[1]), 1.0 / grid.res, float(pose[0]), float(pose[1]),
                             float(pose[2]), pts)) / len(pts)


class LocalSlam:
    """The chain poses, the submaps and (local_map=map) the online map (see module doc)."""

    def __init__(self, matcher: LikelihoodFieldMatcher, settings: MapSettings, submaps: Submaps, local_map: str,
                 start: FloatArray, scale_gain_per_m: float = 0.0, step_matcher: LikelihoodFieldMatcher | None = None,
                 walls_at_hits: bool = False, near_hits_m: float = 0.0, yaw_drift_gain_per_m: float = 0.0,
                 check_rad: float = 0.0, weak_fit: float = 0.0) -> None:
        self.matcher = matcher
        self.weak_fit = float(weak_fit)  # `filter.local_weak_fit`: 0 = a match's turn is taken however poorly it fits
        self.turns_held = 0  # nodes whose yaw the odometry kept (`_held`)
        self._yaw_held: LikelihoodFieldMatcher | None = None
        self._turn_gaps: list[float] = []  # |match's turn - odometry's turn| of every node so far (rad; `_held`)
        self.check_rad = float(check_rad)  # `filter.local_check_rad`: 0 = the online map's match alone
        self.checks_taken = 0  # nodes whose motion came from the submap's match (`step`)
        self.yaw_drift_gain_per_m = float(yaw_drift_gain_per_m)  # `filter.yaw_drift_gain_per_m`: 0 = the odometry's turns as they are
        self.yaw_drift = 0.0  # the learnt odometry yaw drift (rad per metre; `slam.odometry_yaw`)
        self.near_hits_m = float(near_hits_m)  # the online map leaves out hits this near the lidar (`filter.near_hits_m`)
        self.step_matcher = step_matcher or matcher  # each node's own match (`step`): `filter.local_yaw_half_width_rad`
        self.scale_gain_per_m = float(scale_gain_per_m)  # `motion.scale_gain_per_m`: 0 = the odometry as it is
        self.scale = np.ones(1)  # the learnt odometry scale (`slam.odometry_scale`)
        self.settings = settings
        self.walls_at_hits = walls_at_hits  # the online map's walls at their hits' mean (`filter.wall_at`)
        self.submaps = submaps
        self.grid = self._new_grid((float(start[0]), float(start[1]))) if local_map == "map" else None
        self.chain = np.asarray(start, dtype=np.float64).copy()  # the newest node's chain pose (local frame)
        self.online = self.chain.copy()  # its online pose (the online map's frame)
        self.redraws = 0
        # the online map's far rows held compressed (`OccupancyGrid.park_beyond`); reach_m: the farthest point seen (m)
        self.park_far = self.grid is not None and not walls_at_hits
        self.reach_m = 0.0
        self.margin_m = match_margin_m(self.matcher, self.step_matcher)
        if self.park_far:
            self.grid.start_parking()
        self._recent: deque = deque()  # (path m, chain pose, scan points) of the last nodes (`remember`)

    @property
    def whole(self) -> bool:
        """Whether the online pose is matched against a map of everything (local_map=map)."""
        return self.grid is not None

    @property
    def reference(self) -> FloatArray:
        """The pose scans between steps are matched from (`match_online`)."""
        return self.online

    def finish_step(self) -> None:
        """After the scans between steps: nothing here (the particle tracker resamples)."""

    def _new_grid(self, start_xy: tuple[float, float]) -> OccupancyGrid:
        return OccupancyGrid(self.settings, start_xy, self.matcher.field_sigma_m, self.matcher.field_radius_m, self.walls_at_hits)

    def _match(self, grid: OccupancyGrid, predicted: FloatArray, scan: ScanPoints) -> FloatArray:
        return self.step_matcher.match_scans_on(grid, predicted.reshape(1, 3), ScanBatch.of([scan]))[0][0]

    def step(self, odometry_increment: FloatArray, scan: ScanPoints) -> FloatArray:
        """The next node: the odometry increment (robot frame) predicts it and the scan is
        matched against the online map (local_map=map) or the older active submap
        (local_map=submap); the chain pose (the submaps' frame) follows by the same motion.
        Returns that motion: the pose graph's local edge."""
        start = self.online if self.grid is not None else self.chain
        if self.scale_gain_per_m > 0:  # the learnt odometry scale, as the particle filters learn theirs
            start = scaled_start(start.reshape(1, 3), self.scale, odometry_increment)[0]
        d = float(np.hypot(odometry_increment[0], odometry_increment[1]))
        predicted = se2_compose(start, odometry_increment)
        if self.yaw_drift_gain_per_m > 0:  # the learnt yaw drift turns the prediction by b x d
            predicted[2] = wrap_angle(predicted[2] + self.yaw_drift * d)
        grid = self.grid if self.grid is not None else (self.submaps.matching().grid if self.submaps.active else None)
        if self.grid is not None:
            self._need(np.array([start[1], predicted[1]]), scan.xy)
        matches = grid is not None and len(scan.xy) > 0  # a map to match on and points to match: the learnt models learn only then
        matched = self._match(grid, predicted, scan) if matches else predicted
        if matches and self.grid is not None and self.weak_fit > 0:
            matched = self._held(predicted, matched, scan)
        before = self.online if self.grid is not None else self.chain
        if matches and self.grid is not None and self.check_rad > 0 and self.submaps.active:
            matched = self._checked(before, predicted, matched, scan)
        if self.scale_gain_per_m > 0 and matches:
            self.scale = learn_scales(self.scale, before.reshape(1, 3), matched.reshape(1, 3), odometry_increment, self.scale_gain_per_m)
        motion = se2_between(before, matched)
        if self.yaw_drift_gain_per_m > 0 and matches:
            self.yaw_drift = learn_yaw_drift(self.yaw_drift, float(motion[2]), float(odometry_increment[2]), d, self.yaw_drift_gain_per_m)
        if self.grid is not None:
            self.online = matched
            self.chain = se2_compose(self.chain, motion)
        else:
            self.chain = self.online = matched
        return motion

    def _held(self, predicted: FloatArray, matched: FloatArray, scan: ScanPoints) -> FloatArray:
        """The online map's match `matched` of the node predicted at `predicted`, or, when it
        turns the node more than WEAK_TURN_RAD from the odometry's turn and more than
        WEAK_TURN_TIMES the median of the nodes' before it (how far this odometry's turns are
        from the matches' as a rule), while the scan fits the map there below
        `filter.local_weak_fit` (mean field value), the match with the yaw held at the
        odometry's (x and y matched as usual). Why: a scan that fits the map that poorly (a turn
        into a hall seen from one side, glass, people) is weak evidence, and a large turn it asks
        for against a good odometry can stay in the path for good (the hospital log at 1.25 m
        steps: a turn's match 10.6 degrees past the odometry's at a mean fit of 0.075, where its
        odometry is within 0.2 degrees of the matches a node in the median). Intel's odometry is
        1.6 degrees off a node in the median: there a turn of 4 degrees is the odometry's error."""
        gap = abs(float(wrap_angle(matched[2] - predicted[2])))
        gaps = self._turn_gaps
        small = gap <= WEAK_TURN_RAD or len(gaps) < WEAK_TURN_NODES or gap <= WEAK_TURN_TIMES * float(np.median(gaps))
        gaps.append(gap)
        if small:
            return matched
        pts = np.ascontiguousarray(self.matcher.fine_points(scan), dtype=np.float64)
        if _mean_fit(self.grid, matched, pts) >= self.weak_fit:
            return matched
        if self._yaw_held is None:
            self._yaw_held = self.step_matcher.with_yaw_held()
        self.turns_held += 1
        return self._yaw_held.match_scans_on(self.grid, predicted.reshape(1, 3), ScanBatch.of([scan]))[0][0]

    def _checked(self, before: FloatArray, predicted: FloatArray, matched: FloatArray, scan: ScanPoints) -> FloatArray:
        """The online map's match `matched` of the node predicted at `predicted` (from
        `before`), checked against the same scan matched on the older active submap (recent
        scans only, in the chain's frame; `filter.local_check_rad`). The submap's motion is
        taken instead when the two differ in yaw by more than `check_rad`, the odometry's turn
        is nearer the submap's, and the recent scans fit the scan clearly better (by CHECK_FIT
        of the mean field value) at their own match than at the online map's motion and than
        the online map fits it at its match: the online map there is not what the robot sees now."""
        by_map = se2_between(before, matched)
        by_odometry = se2_between(before, predicted)
        turn = float(by_odometry[2])
        off_map = abs(float(wrap_angle(by_map[2] - turn)))
        if off_map <= self.check_rad / 2:
            return matched  # the submap's could differ by check_rad only by being farther from the odometry: not needed
        grid = self.submaps.matching().grid
        if grid.field is None:  # local_map=map draws the submaps' fields when they are finished: this one's now
            grid.start_field(self.submaps.sigma, self.submaps.radius)
        by_submap = se2_between(self.chain, self._match(grid, se2_compose(self.chain, by_odometry), scan))
        if abs(float(wrap_angle(by_map[2] - by_submap[2]))) <= self.check_rad or off_map <= abs(float(wrap_angle(by_submap[2] - turn))):
            return matched
        pts = np.ascontiguousarray(self.matcher.fine_points(scan), dtype=np.float64)
        sub_own = _mean_fit(grid, se2_compose(self.chain, by_submap), pts)
        if sub_own - _mean_fit(grid, se2_compose(self.chain, by_map), pts) <= CHECK_FIT or sub_own - _mean_fit(self.grid, matched, pts) <= CHECK_FIT:
            return matched
        self.checks_taken += 1
        return se2_compose(before, by_submap)

    def slack(self, scan: ScanPoints, step_m: float, slip_per_m: float) -> FloatArray:
        """(3, 3) what the newest node's match did not pin, for its local edge (node frame):
        the match's covariance (`loops.match_covariance`, from the score's curvature on the map
        it was matched against) with every direction capped at (slip_per_m x step_m)^2. Down a
        bare corridor the match pins nothing along it and the step's length there is the
        odometry's, whose scale may be off by a few per cent: the edge may stretch that much,
        so that a loop closure at the corridor's end moves the corridor, not the rest."""
        cap = (slip_per_m * step_m) ** 2
        if cap <= 0 or not len(scan.xy):
            return np.zeros((3, 3))
        grid, pose = (self.grid, self.online) if self.grid is not None else (self.submaps.matching().grid if self.submaps.active else None, self.chain)
        if grid is None:
            return np.zeros((3, 3))
        if self.grid is not None:
            self._need(pose[1:2], scan.xy)
        cov = match_covariance(grid.field_cells, grid.origin, grid.res, pose, self.matcher.fine_points(scan), 0.0, 0.0)
        w, v = sym_eig(np.ascontiguousarray(cov[:2, :2]))
        out = np.zeros((3, 3))
        out[:2, :2] = from_eig(np.minimum(w, cap), v)
        return out

    def remember(self, node: int, path_m: float, points_xy: FloatArray, span_m: float) -> None:
        """Keep node `node`'s scan points (body frame; path `path_m` m) with its chain pose for
        `query`, dropping the nodes more than `span_m` of path behind it."""
        self._recent.append((path_m, self.chain.copy(), np.asarray(points_xy, dtype=np.float64)))
        while self._recent and path_m - self._recent[0][0] > span_m:
            self._recent.popleft()

    def query(self, voxel_m: float) -> FloatArray:
        """The remembered scans (`remember`) in the newest node's frame, one point per `voxel_m`
        square: what the robot saw over the last few metres, as one scan. A single scan down a
        corridor of repeating doors matches a few doors off as well as where it is; the last few
        metres' scans together see the corridor's irregular features (a junction behind, a door
        that is not on the beat) and rarely fit anywhere else."""
        here = self._recent[-1][1]
        kept = [(pose, pts) for _, pose, pts in self._recent if len(pts)]
        if not kept:
            return np.zeros((0, 2))
        # every scan's pose seen from the newest node's, then each point moved by its scan's (one pass, not one per scan)
        rel = se2_between(here, np.array([pose for pose, _ in kept]))
        per_point = np.repeat(np.arange(len(kept)), [len(pts) for _, pts in kept])
        xy = place(np.concatenate([pts for _, pts in kept]), rel[per_point, 0], rel[per_point, 1],
                   np.cos(rel[:, 2])[per_point], np.sin(rel[:, 2])[per_point])
        return np.ascontiguousarray(voxel_filter(xy, voxel_m))

    def match_online(self, predicted: FloatArray, scans: ScanBatch | MatchPoints) -> FloatArray:
        """The poses (S, 3) where scans (none empty) fit the online map as it is now (the
        older active submap with local_map=submap), predicted in its frame."""
        grid = self.grid if self.grid is not None else self.submaps.matching().grid
        if self.grid is not None:
            self._need(predicted[:, 1], *((scans.xy,) if isinstance(scans, ScanBatch) else (scans.coarse, scans.fine)))
        return self.matcher.match_scans_on(grid, predicted, scans)[0]

    def _need(self, ys: FloatArray, *body_xy: FloatArray) -> None:
        """Before the online map is read at poses whose y are `ys` (m) with points `body_xy`
        (robot frame, m; one array or more): its parked rows (`park_beyond`) within the points'
        reach put back. A match reads at most `margin_m` beyond (`match_margin_m`)."""
        reach = max(reach_of(xy) for xy in body_xy)
        self.grid.need_rows(float(ys.min()) - reach - self.margin_m, float(ys.max()) + reach + self.margin_m)

    def insert(self, node: int, scan: ScanPoints) -> list[FinishedSubmap]:
        """Add node `node`'s scan at its poses: the online map's and the submaps'; returns the
        submaps it finished."""
        if self.grid is not None and len(scan.xy):
            # lone far hits left out (probe: mean relation error 0.095 -> 0.075 m at 2x, 0.17 -> 0.10 m at 3x)
            walls = map_points(self.matcher, scan, self.near_hits_m)
            self.grid.insert(points_to_world(scan.origin.reshape(1, 2), self.online)[0], points_to_world(walls, self.online))
            if self.park_far:
                # the rows no scan from here can reach held compressed; `_need` puts them back on the way there
                self.reach_m = max(self.reach_m, reach_of(scan.xy))
                keep = park_distance(self.reach_m, self.margin_m)
                self.grid.park_beyond(float(self.online[1]) - keep, float(self.online[1]) + keep)
        return self.submaps.insert(node, self.chain, scan)

    def redraw(self, scans: Iterable[ScanPoints], poses: FloatArray) -> None:
        """After the graph moved the robot far from where the online map has it: the online map
        drawn again from every node's scan at its optimised pose (`scans`, `poses` (K, 3):
        nodes 0..K-1), the newest node's online pose becoming its optimised one."""
        assert self.grid is not None, "local_map=submap keeps no online map"
        self.redraws += 1
        self.grid = None  # let the old map go first: on a building the size of the hospital log it is ~300 MB
        self.grid = map_of_nodes(scans, poses, self.matcher, self.settings, self.walls_at_hits, self.near_hits_m, park=self.park_far)
        self.online = np.asarray(poses[-1], dtype=np.float64).copy()

    def drop_online_map(self) -> None:
        """After the last node: the online map is not read again (the final map is drawn anew
        from the optimised poses), so its memory goes before that map is made."""
        self.grid = None

    def memory_mb(self) -> float:
        own = 0 if self.grid is None else self.grid.nbytes
        return own / 1e6 + self.submaps.memory_mb()
