"""Texture mapping, start to finish: RGB-D frames + a trajectory -> a coloured floor grid.

Per RGB-D frame (streamed: memory is bounded by what the reader holds, one RGB file, plus
the fixed-size accumulator; no frame is kept):
1. depth (m, un-mirrored by the reader) -> 3D points in the IR optical frame (`backproject`);
2. IR frame -> world: camera -> head (neck yaw, head pitch at the frame's time, already in
   `frame.camera_to_body`) -> body (roll, pitch) -> world, the body's world pose being
   Txyz(x, y, body_height_m) Rz(theta) Ry(pitch) Rx(roll) with (x, y, theta) the trajectory
   interpolated at the frame's time;
3. the `ground/` detector picks the floor points;
4. floor points -> RGB frame (R, T) -> RGB pixel -> colour (`align`);
5. colour added to the texture cell under each point (`texture_map`).

Public entry points: `run_texture`, `save_texture_outputs`, `texture_enabled`,
`TextureResult` (scored by `slamlab.eval.texture.texture_metrics`).

Bad input never crashes a run half-way: missing calibration or no RGB-D raise a clear
`DataError` before any work; a bad frame (no valid depth, no colour, colour too far in time,
outside the trajectory's time span, wrong shapes) is skipped and counted in
`TextureResult.skipped`; a reader error part-way stops the stream and keeps what was built
(`TextureResult.messages`).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from slamlab.camera import scaled_intrinsics
from slamlab.config import SCHEMAS, construct
from slamlab.config.texture import TextureConfig
from slamlab.io.atomic import atomic_path
from slamlab.io.rundir import TextureFiles
from slamlab.errors import ConfigError, DataError, SlamlabError
from slamlab.frames import GridImage, KinectCalibration, RGBDFrame, Sequence
from slamlab import geometry
from slamlab.texture.align import sample_colors, unmirror_calibration
from slamlab.texture.backproject import Backprojector, DepthPoints
from slamlab.texture.detection import DetectionCounts
from slamlab.texture.ground import GroundDetector, GroundQuery
from slamlab.texture.open3d_lite import import_open3d
from slamlab.texture.samples import FrameSample, sample_frame, sample_ordinals
from slamlab.texture.texture_map import TextureAccumulator, resample_to_grid

__all__ = [
    "TextureResult",
    "run_texture",
    "run_textures",
    "save_texture_outputs",
    "texture_enabled",
    "interpolate_poses",
    "PoseTrack",
    "build_detector",
]

log = logging.getLogger("slamlab")

# Why a frame was not used (keys of TextureResult.skipped).
SKIP_REASONS = (
    "bad_depth",  # depth is not a 2-D array
    "no_valid_depth",  # no pixel within [min_depth_m, max_depth_m]
    "outside_trajectory",  # frame time further than max_pose_gap_s from the trajectory's span
    "no_rgb",  # the reader found no colour image for this depth frame
    "rgb_time_mismatch",  # colour further than max_rgb_dt_s from the depth time
    "bad_rgb",  # colour image is not (H, W, 3) uint8
    "bad_frame",  # anything else the frame's own data made impossible (message logged)
)


@dataclass(slots=True)
class TextureResult:
    """What `run_texture` builds (in memory; `save_texture_outputs` writes it).

    - `color` (H, W, 3) uint8: the floor colour per cell of the occupancy grid (0 where unobserved);
    - `count` (H, W) int64: floor points averaged into each cell (0 = unobserved);
    - `resolution_m`, `origin_xy`: the occupancy grid's, so cell (r, c) is the same place in both;
    - `floor_points` (K, 3) float64 m and `floor_colors` (K, 3) uint8: one point per observed
      cell (the mean of its points): a voxel-downsampled coloured floor cloud;
    - `detector`: the ground detector's name;
    - `frames_total`: frames read from the stream, `frames_used`: frames that went through the
      detector and colouring, `skipped`: {reason: count} (see SKIP_REASONS), `frames_thinned`:
      frames left out on purpose by `frame_every` / `max_frames`;
    - `frame_time_s` (F,): wall time of each used frame (s), from depth to accumulation;
      `detect_time_s` (F,): the detector's part of it;
    - `points_added`: floor points averaged into cells; `points_outside_grid`, `points_rejected`;
    - `detection`: {detector name: DetectionCounts} on frames with ground labels (may be empty);
    - `messages`: human-readable notes (e.g. a reader error that stopped the stream);
    - `samples`: the frames kept for the report when `run_texture(sample_frames=k)` (`samples.py`).
    """

    color: np.ndarray
    count: np.ndarray
    resolution_m: float
    origin_xy: tuple[float, float]
    floor_points: np.ndarray
    floor_colors: np.ndarray
    detector: str
    frames_total: int = 0
    frames_used: int = 0
    frames_thinned: int = 0
    skipped: dict[str, int] = field(default_factory=dict)
    frame_time_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    detect_time_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    points_added: int = 0
    points_outside_grid: int = 0
    points_rejected: int = 0
    detection: dict[str, DetectionCounts] = field(default_factory=dict)
    messages: list[str] = field(default_factory=list)
    samples: list[FrameSample] = field(default_factory=list)

    @property
    def covered(self) -> np.ndarray:
        """(H, W) bool: cells with at least one floor point."""
        return self.count > 0

    @property
    def covered_area_m2(self) -> float:
        """Observed floor area (m^2)."""
        return float(np.count_nonzero(self.count)) * self.resolution_m**2

    @property
    def grid(self) -> GridImage:
        """The colour grid as a GridImage (row 0 = lowest y)."""
        return GridImage(self.color, self.resolution_m, self.origin_xy)

    def summary(self) -> dict:
        """JSON-friendly counters and timings (no arrays)."""
        ft = self.frame_time_s
        dt = self.detect_time_s
        return {
            "detector": self.detector,
            "frames_total": self.frames_total,
            "frames_used": self.frames_used,
            "frames_thinned": self.frames_thinned,
            "frames_skipped": int(sum(self.skipped.values())),
            "skipped": dict(self.skipped),
            "points_added": self.points_added,
            "points_outside_grid": self.points_outside_grid,
            "points_rejected": self.points_rejected,
            "covered_cells": int(np.count_nonzero(self.count)),
            "covered_area_m2": self.covered_area_m2,
            "frame_ms_median": float(np.median(ft) * 1e3) if ft.size else None,
            "frame_ms_max": float(np.max(ft) * 1e3) if ft.size else None,
            "detect_ms_median": float(np.median(dt) * 1e3) if dt.size else None,
            "messages": list(self.messages),
        }


# ---- poses --------------------------------------------------------------------------------
class PoseTrack:
    """A trajectory (x m, y m, theta rad) at times (s), queried at any time: linear in x, y and
    UNWRAPPED theta (so a turn through +-pi interpolates the short way).

    `times` need not be sorted: THOR and simulated logs are monotonic, but CARMEN clocks can
    step back, so samples are sorted by time (stable) once; duplicate times keep the first.
    Queries outside [min(times), max(times)] are clamped to the end pose and report how far
    (s) they lie outside, for the caller to reject."""

    def __init__(self, times: np.ndarray, poses: np.ndarray):
        times = np.asarray(times, dtype=np.float64).reshape(-1)
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
        if times.size == 0 or times.size != poses.shape[0]:
            raise ValueError(f"times ({times.size}) and poses ({poses.shape[0]}) must be equal, non-empty")
        order = np.argsort(times, kind="stable")
        t, p = times[order], poses[order]
        first = np.concatenate([[True], np.diff(t) > 0])
        self.t = t[first]
        self.xy = p[first, :2]
        self.theta = np.unwrap(p[first, 2])

    def __call__(self, t_query: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """(poses (M, 3), gap_s (M,)), or ((3,), scalar) for a scalar query."""
        q = np.asarray(t_query, dtype=np.float64)
        scalar = q.ndim == 0
        q = q.reshape(-1)
        t = self.t
        out = np.stack([np.interp(q, t, self.xy[:, 0]), np.interp(q, t, self.xy[:, 1]), np.interp(q, t, self.theta)], axis=-1)
        out[:, 2] = (out[:, 2] + np.pi) % (2.0 * np.pi) - np.pi
        gap = np.maximum(t[0] - q, 0.0) + np.maximum(q - t[-1], 0.0)
        if scalar:
            return out[0], gap[0]
        return out, gap


def interpolate_poses(times: np.ndarray, poses: np.ndarray, t_query: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """One-off `PoseTrack(times, poses)(t_query)`: the trajectory at `t_query` (s) and how far
    (s) each query lies outside the trajectory's time span (0 inside)."""
    return PoseTrack(times, poses)(t_query)


# ---- config -------------------------------------------------------------------------------
def build_detector(ground: object) -> GroundDetector:
    """A fresh ground detector from a `ground/` schema object (`slamlab.config.texture`: its
    `_target_` and knobs). Fresh, because a detector may carry state (`plane`'s RANSAC
    generator): every texture run starts from the configured seed."""
    return construct(ground, GroundDetector, "ground")


def evaluated_detector(name: str) -> GroundDetector:
    """The detector of the `ground/` choice `name` at its schema's values (the detectors
    `texture.evaluate_detectors` compares on labelled frames)."""
    schema = SCHEMAS["ground"].get(str(name))
    if schema is None:
        raise ConfigError("texture.evaluate_detectors", f"no ground detector named {name!r} (known: {', '.join(SCHEMAS['ground'])})")
    return build_detector(schema())


def texture_enabled(sequence: Sequence, texture: TextureConfig) -> bool:
    """Texture runs only when the dataset has RGB-D and the config is not `texture=none`."""
    return sequence.rgbd is not None and texture.enabled


# ---- the run ------------------------------------------------------------------------------
def run_texture(
    sequence: Sequence,
    times: np.ndarray,
    poses: np.ndarray,
    grid: GridImage,
    ground: object,
    texture: TextureConfig,
    progress: Callable[[int, int], None] | None = None,
    sample_frames: int = 0,
) -> TextureResult:
    """Colour the floor cells of `grid` from the sequence's RGB-D frames placed with `poses`.

    - `times` (N,) scan times (s) and `poses` (N, 3) the trajectory at those times (x m, y m,
      theta rad; the SLAM estimate or the odometry) - interpolated at each frame's depth time;
    - `grid`: the occupancy map; the texture grid has its shape, resolution and origin;
    - `ground`: a `ground/` schema object (`slamlab.config.texture`), the detector to use;
      `texture`: the `texture/` settings (checked when they were made);
    - `progress(done, total)`: optional, called after each frame (total = sequence.rgbd_count);
    - `sample_frames`: keep this many used frames spread over the stream for the report
      (every evaluated detector's floor mask and the registered colour; `samples.py`).

    Raises DataError (before any work) if the sequence has no RGB-D, no Kinect calibration or
    no body height, and ConfigError for impossible config values. Never raises for a bad frame.
    """
    return run_textures(sequence, times, {"only": poses}, grid, ground, texture, progress, sample_frames)["only"]


@dataclass
class _Pass:
    """One trajectory's share of a texture run: where it places the frames, its own detector
    (a detector may carry state, so every trajectory gets the sequence of calls a run of its
    own would make) and what it has built so far."""

    track: PoseTrack
    detector: GroundDetector
    name: str  # the detector's, as results and detection scores report it
    acc: TextureAccumulator
    compare: dict[str, GroundDetector]  # other detectors scored on labelled frames (first pass only)
    sample_detectors: dict[str, GroundDetector]  # detectors drawn on report frames (first pass only)
    skipped: dict[str, int] = field(default_factory=dict)
    detection: dict[str, DetectionCounts] = field(default_factory=dict)
    samples: list[FrameSample] = field(default_factory=list)
    frame_times: list[float] = field(default_factory=list)
    detect_times: list[float] = field(default_factory=list)
    frames_used: int = 0
    thinned: int = 0  # frames left out because this trajectory already used `max_frames`

    def skip(self, reason: str, frame: RGBDFrame | None = None, detail: str = "") -> None:
        self.skipped[reason] = self.skipped.get(reason, 0) + 1
        if detail and self.skipped[reason] <= 3:  # say why, but do not flood the log
            log.warning("texture: frame %s skipped (%s): %s", getattr(frame, "index", "?"), reason, detail)


def run_textures(
    sequence: Sequence,
    times: np.ndarray,
    trajectories: dict[str, np.ndarray],
    grid: GridImage,
    ground: object,
    texture: TextureConfig,
    progress: Callable[[int, int], None] | None = None,
    sample_frames: int = 0,
) -> dict[str, TextureResult]:
    """`run_texture` for several trajectories (e.g. {"slam": ..., "odometry": ...}) in ONE pass
    over the RGB-D stream: each frame is read and back-projected once, then placed, detected
    and coloured with each trajectory. Each result equals a `run_texture` of that trajectory
    alone; only the first trajectory scores `texture.evaluate_detectors` and keeps the
    report's `sample_frames` (as the pipeline asked of the SLAM pass before)."""
    if sequence.rgbd is None:
        raise DataError(sequence.name, "has no RGB-D frames: texture mapping needs a sequence with Kinect data")
    if sequence.calibration is None:
        raise DataError(
            sequence.name, "has RGB-D frames but no Kinect calibration (cameraParam/ IRcam, RGBcamera, exParams .pkl)"
        )
    if sequence.body_height_m is None:
        raise DataError(sequence.name, "has no body height: cannot place the camera above the floor")
    tracks: dict[str, PoseTrack] = {}
    for name, poses in trajectories.items():
        try:
            tracks[name] = PoseTrack(times, poses)
        except ValueError as exc:
            raise ConfigError("texture", f"trajectory: {exc}") from None

    calib: KinectCalibration = sequence.calibration
    if texture.calibration_mirrored:
        calib = unmirror_calibration(calib)
    frame_every = texture.frame_every
    max_frames = texture.max_frames
    max_rgb_dt = float(texture.max_rgb_dt_s)
    max_gap = float(texture.max_pose_gap_s)
    distort_rgb = texture.distort_rgb
    body_height_m = float(sequence.body_height_m)

    backproject = Backprojector(
        calib.ir,
        stride=texture.stride,
        undistort=texture.undistort_depth,
        min_depth_m=float(texture.min_depth_m),
        max_depth_m=float(texture.max_depth_m),
    )
    labels = sequence.ground_truth.ground_labels if sequence.ground_truth is not None else {}
    total = int(sequence.rgbd_count or 0)
    # which frames the report sees: labelled ones when there are labels (so precision and
    # recall can be shown), matched by frame index; otherwise by position in the stream
    sample_by_index = bool(labels)
    pool = sorted(labels) if labels else None
    sample_at = set() if sample_frames <= 0 else (
        {pool[i] for i in sample_ordinals(len(pool), sample_frames)} if pool else sample_ordinals(total, sample_frames))

    passes: dict[str, _Pass] = {}
    for k, (name, track) in enumerate(tracks.items()):
        detector = build_detector(ground)
        det_name = str(getattr(detector, "name", type(detector).__name__))
        compare: dict[str, GroundDetector] = {}
        sample_detectors: dict[str, GroundDetector] = {}
        if k == 0:  # detection quality on labelled frames: the chosen detector, plus others
            if labels:
                for other in texture.evaluate_detectors:
                    if str(other) != det_name:
                        compare[str(other)] = evaluated_detector(str(other))
            if sample_at:  # the run's detector and every evaluated one, labels or not
                sample_detectors = {det_name: detector}
                for other in texture.evaluate_detectors:
                    sample_detectors.setdefault(str(other), compare.get(str(other)) or evaluated_detector(str(other)))
        acc = TextureAccumulator.like(
            grid, average=texture.average, robust_reject=float(texture.robust_reject), robust_min_count=int(texture.robust_min_count),
        )
        passes[name] = _Pass(track, detector, det_name, acc, compare, sample_detectors)

    messages: list[str] = []
    frames_total = thinned = 0
    stream = iter(sequence.rgbd())
    while True:
        try:
            frame = next(stream)
        except StopIteration:
            break
        except SlamlabError as exc:
            # A corrupt RGB/DEPTH file part-way: keep the texture built so far.
            messages.append(f"RGB-D stream stopped after {frames_total} frames: {exc}")
            log.error("texture: %s", messages[-1])
            break
        frames_total += 1
        if progress is not None:
            progress(frames_total, max(total, frames_total))
        if (frames_total - 1) % frame_every != 0:
            thinned += 1
            continue
        # `max_frames` counts each trajectory's own used frames (as a run of its own would)
        active: list[tuple[int, _Pass]] = []
        for k, ps in enumerate(passes.values()):
            if max_frames is not None and ps.frames_used >= int(max_frames):
                ps.thinned += 1
            else:
                active.append((k, ps))
        if not active:
            continue
        t0 = time.perf_counter()
        try:
            pts = _frame_points(frame, backproject, [ps for _, ps in active])
        except (ValueError, IndexError, DataError) as exc:
            for _, ps in active:
                ps.skip("bad_frame", frame, f"{type(exc).__name__}: {exc}")
            continue
        dt_points = time.perf_counter() - t0
        if pts is None:
            continue
        for k, ps in active:
            t1 = time.perf_counter()
            try:
                used, dt_detect, dt_eval = _place_frame(
                    frame, pts, calib, ps, labels, max_gap, max_rgb_dt, distort_rgb, body_height_m)
            except (ValueError, IndexError, DataError) as exc:
                # The frame's own data is inconsistent (e.g. odd shapes): skip it, keep going.
                ps.skip("bad_frame", frame, f"{type(exc).__name__}: {exc}")
                continue
            if not used:
                continue
            ps.frames_used += 1
            # Evaluation-only work (other detectors on labelled frames) is not the mapper's cost.
            ps.frame_times.append(dt_points + time.perf_counter() - t1 - dt_eval)
            ps.detect_times.append(dt_detect)
            if k == 0 and (frame.index if sample_by_index else frames_total - 1) in sample_at:
                # after the timing: the report's cost, not the mapper's
                kept = sample_frame(frame, calib, backproject, _camera_to_world(frame, ps.track(frame.t)[0], body_height_m),
                                    ps.sample_detectors, labels.get(frame.index) if labels else None, distort_rgb)
                if kept is not None:
                    ps.samples.append(kept)

    # one pass at a time, each let go (its sums: ~90 MB resident on the 2x `sim_loops` building) before the next
    # one's averages are made: popped from `passes`, and the frame loop's list of them dropped first
    active = []
    return {name: _result(passes.pop(name), grid, messages, frames_total, thinned) for name in list(passes)}


def _result(ps: _Pass, grid: GridImage, stream_messages: list[str], frames_total: int, thinned: int) -> TextureResult:
    """One trajectory's TextureResult once the stream is done (`thinned`: the stream's frames
    left out for every trajectory; its own `max_frames` ones are added)."""
    messages = list(stream_messages)
    if frames_total == 0:
        messages.append("the RGB-D stream was empty")
    elif ps.frames_used == 0:
        messages.append(f"no usable RGB-D frame out of {frames_total}: skipped {ps.skipped}")
    if messages:
        for m in messages[-1:]:
            log.warning("texture: %s", m)
    color, pts, cols = ps.acc.finish()
    return TextureResult(
        color=color,
        count=ps.acc.counts,
        resolution_m=float(grid.resolution_m),
        origin_xy=(float(grid.origin_xy[0]), float(grid.origin_xy[1])),
        floor_points=pts,
        floor_colors=cols,
        detector=ps.name,
        frames_total=frames_total,
        frames_used=ps.frames_used,
        frames_thinned=thinned + ps.thinned,
        skipped=ps.skipped,
        frame_time_s=np.asarray(ps.frame_times),
        detect_time_s=np.asarray(ps.detect_times),
        points_added=int(ps.acc.count.sum()),
        points_outside_grid=ps.acc.points_outside,
        points_rejected=ps.acc.points_rejected,
        detection=ps.detection,
        messages=messages,
        samples=ps.samples,
    )


def _camera_to_world(frame: RGBDFrame, pose: np.ndarray, body_height_m: float) -> np.ndarray:
    """4x4 pose of the IR optical frame in the world, the body at `pose` (x m, y m, theta rad:
    the trajectory at the frame's depth time)."""
    x, y, th = (float(v) for v in np.asarray(pose, dtype=np.float64).reshape(3))
    T_wb = geometry.body_to_world(x, y, th, frame.roll, frame.pitch, body_height_m)
    return T_wb @ np.asarray(frame.camera_to_body, dtype=np.float64).reshape(4, 4)


def _frame_points(frame: RGBDFrame, backproject: Backprojector, passes: list[_Pass]) -> DepthPoints | None:
    """The frame's valid depth pixels as IR-frame points (`Backprojector`), or None (the skip
    is counted in every pass) when the depth is unusable. Shared by all trajectories."""
    depth = np.asarray(frame.depth_m)
    if depth.ndim != 2 or depth.size == 0:
        for ps in passes:
            ps.skip("bad_depth", frame, f"depth shape {depth.shape}")
        return None
    pts = backproject(depth)
    if len(pts) == 0:
        for ps in passes:
            ps.skip("no_valid_depth")
        return None
    return pts


def _place_frame(
    frame: RGBDFrame,
    pts: DepthPoints,
    calib: KinectCalibration,
    ps: _Pass,
    labels: dict[int, np.ndarray],
    max_gap: float,
    max_rgb_dt: float,
    distort_rgb: bool,
    body_height_m: float,
) -> tuple[bool, float, float]:
    """One frame's points placed with one trajectory, through its detector into its texture.
    Returns (used, detector s, evaluation-only s); skips are counted in `ps`."""
    depth = np.asarray(frame.depth_m)
    pose, gap = ps.track(frame.t)
    if gap > max_gap:
        ps.skip("outside_trajectory", frame, f"t={frame.t:.3f} is {gap:.2f} s outside the trajectory")
        return False, 0.0, 0.0
    T_wc = _camera_to_world(frame, pose, body_height_m)
    query = GroundQuery(pts, T_wc, scaled_intrinsics(calib.ir, depth.shape[1], depth.shape[0]))

    t0 = time.perf_counter()
    floor = ps.detector(query)
    dt_detect = time.perf_counter() - t0

    dt_eval = 0.0
    truth = labels.get(frame.index) if labels else None
    if truth is not None:
        t1 = time.perf_counter()
        truth = np.asarray(truth, dtype=bool)
        if truth.shape == depth.shape:
            truth_at = truth[pts.v, pts.u]
            ps.detection.setdefault(ps.name, DetectionCounts()).add(floor, truth_at)
            for name, det in ps.compare.items():
                ps.detection.setdefault(name, DetectionCounts()).add(det(query), truth_at)
        dt_eval = time.perf_counter() - t1

    rgb = frame.rgb
    if rgb is None:
        ps.skip("no_rgb")
        return False, dt_detect, dt_eval
    if not np.isfinite(frame.rgb_t) or abs(frame.rgb_t - frame.t) > max_rgb_dt:
        ps.skip("rgb_time_mismatch", frame, f"colour {frame.rgb_t - frame.t:+.3f} s from depth")
        return False, dt_detect, dt_eval
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        ps.skip("bad_rgb", frame, f"colour image {rgb.shape} {rgb.dtype}")
        return False, dt_detect, dt_eval

    idx = np.flatnonzero(floor)
    if idx.size:
        colors, keep = sample_colors(pts.cam[idx], rgb, calib, distort=distort_rgb)
        idx = idx[keep]
        ps.acc.add(query.world_at(idx), colors)
    return True, dt_detect, dt_eval


# ---- outputs ------------------------------------------------------------------------------
def _write_png(path: Path, image: np.ndarray) -> None:
    """A uint8 RGB(A) image as PNG, atomically (`io.png`: the bytes plt.imsave wrote before)."""
    from slamlab.io.png import as_rgba, write_png

    with atomic_path(path) as tmp:
        write_png(tmp, as_rgba(image))


def texture_image(result: TextureResult) -> np.ndarray:
    """(H, W, 4) uint8 RGBA for people: top row = highest y, unobserved cells transparent."""
    rgba = np.zeros(result.color.shape[:2] + (4,), dtype=np.uint8)
    rgba[..., :3] = result.color
    rgba[..., 3] = np.where(result.covered, 255, 0)
    return np.flipud(rgba)


def texture_over_map_image(result: TextureResult, occupancy_prob: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8: the occupancy map in grey (white free, black occupied, grey unknown)
    with the texture over it where observed; top row = highest y."""
    occ = np.asarray(occupancy_prob, dtype=np.float64)
    if occ.shape != result.count.shape:
        raise ValueError(f"occupancy {occ.shape} and texture {result.count.shape} grids differ")
    grey = np.clip(np.rint((1.0 - occ) * 255.0), 0, 255).astype(np.uint8)
    img = np.repeat(grey[..., None], 3, axis=2)
    img[result.covered] = result.color[result.covered]
    return np.flipud(img)


def save_truth_texture(result: TextureResult, floor_texture: GridImage, path: Path,
                       truth_on_grid: tuple[np.ndarray, np.ndarray] | None = None) -> None:
    """The true floor colour (simulated data) on `result`'s grid, shown only on the cells the
    texture covers, as RGBA like texture.png: the two images compare cell for cell.
    `truth_on_grid`: `floor_texture` already averaged into that grid, when the caller has it."""
    colour, has = truth_on_grid or resample_to_grid(floor_texture, result.count.shape, result.resolution_m, result.origin_xy)
    rgba = np.zeros(result.count.shape + (4,), dtype=np.uint8)
    shown = has & result.covered
    rgba[shown, :3] = np.clip(np.rint(colour[shown]), 0, 255).astype(np.uint8)  # hidden cells all 0, as in texture.png
    rgba[..., 3] = np.where(shown, 255, 0)
    _write_png(path, np.flipud(rgba))


def save_texture_outputs(
    result: TextureResult, occupancy_prob: np.ndarray, files: TextureFiles, voxel_m: float | None = None
) -> dict[str, Path]:
    """Write `files` (names from the run directory contract, `RunDirectory.texture_files`):
    the texture (RGBA, unobserved transparent), the texture over the occupancy map and the
    coloured floor cloud (Open3D, voxel-downsampled to `voxel_m`, default the grid
    resolution). Every file goes to a temporary name beside it and is renamed when complete.
    Returns {kind: path}."""
    files.texture.parent.mkdir(parents=True, exist_ok=True)
    written: dict[str, Path] = {}
    p = files.texture
    _write_png(p, texture_image(result))
    written["texture"] = p
    p = files.over_map
    _write_png(p, texture_over_map_image(result, occupancy_prob))
    written["over_map"] = p

    o3d = import_open3d()  # without its web visualiser (0.7 s, ~40 MB): open3d_lite

    p = files.cloud
    pcd = o3d.geometry.PointCloud()
    if result.floor_points.shape[0]:
        pcd.points = o3d.utility.Vector3dVector(np.asarray(result.floor_points, dtype=np.float64))
        pcd.colors = o3d.utility.Vector3dVector(np.asarray(result.floor_colors, dtype=np.float64) / 255.0)
        pcd = pcd.voxel_down_sample(float(voxel_m or result.resolution_m))
    # atomic_path keeps the suffix: Open3D picks the format from it
    with atomic_path(p) as tmp:
        if len(pcd.points) == 0:
            # Open3D refuses to write an empty cloud; an empty but valid PLY keeps the run
            # directory's file set fixed (nothing seen is a result, not an error).
            tmp.write_text(
                "ply\nformat ascii 1.0\nelement vertex 0\nproperty double x\nproperty double y\n"
                "property double z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
            )
        elif not o3d.io.write_point_cloud(str(tmp), pcd, write_ascii=False):
            raise OSError(f"Open3D could not write {tmp}")
    written["cloud"] = p
    return written
