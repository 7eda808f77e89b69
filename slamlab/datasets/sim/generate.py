"""Generate a simulated THOR-OP sequence into a folder, and `load_sim`: the cached default
dataset of slamlab.

A generated folder looks exactly like a real THOR recording (`train_lidar0.mat`,
`train_joint0.mat`, `DEPTH_0.mat`, `RGB_0_1.mat`, `cameraParam/`) plus `truth/` (see
`truth.py`) and `sim.json` (the parameters). Files are written through
`slamlab.datasets.thor_write`, so any course-style loader reads them.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import shutil
import uuid
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from slamlab import robot
from slamlab.io.tum import write_tum
from slamlab.datasets.sim import calib as simcalib
from slamlab.datasets.sim import truth as simtruth
from slamlab.datasets.sim.kinect import camera_rays, render_depth, render_rgb, rgb_to_ir
from slamlab.datasets.sim.people import walking_people
from slamlab.datasets.sim.sensors import (
    BEAM_RES_RAD,
    sensor_poses,
    simulate_odometry,
    simulate_scans,
)
from slamlab.datasets.sim.trajectory import Motion, simulate_motion
from slamlab.datasets.sim.world import World, build_world, occupancy_grid
from slamlab.config.sim import SimParams
from slamlab.frames import KinectCalibration, Sequence
from slamlab.geometry import wrap_angle

# Bump whenever the generator's output changes for the same parameters: it is part of the
# cache key, so stale cached sequences are never reused.
SIM_VERSION = "3"  # 3: truth trajectory written by slamlab.io.tum.write_tum
# The loops layout's own version, appended to SIM_VERSION for it (so bumping it leaves every
# ring sequence's cache key alone). Bump whenever the loops world or route changes.
LOOPS_VERSION = "1"
T0_UNIX_S = 1426800000.0  # March 2015, like the course logs
LIDAR_HZ = 40.0
JOINT_HZ = 100.0
SEQUENCE = 0  # file number: train_lidar0.mat, DEPTH_0.mat, ...

# Knobs added after sequences were already cached: at their defaults they are left out of the
# cache key and of sim.json, so every earlier configuration keeps its key and its bytes.
OMITTED_AT_DEFAULT = ("layout", "jerk_deg", "jerk_every_s", "neck_sweep_deg", "neck_sweep_period_s")


def params_record(params: SimParams) -> dict:
    """The parameters as recorded in the cache key and sim.json: every field, except those of
    OMITTED_AT_DEFAULT that are at their default."""
    out = dataclasses.asdict(params)
    defaults = {f.name: f.default for f in dataclasses.fields(SimParams)}
    for name in OMITTED_AT_DEFAULT:
        if out[name] == defaults[name]:
            del out[name]
    return out


def sim_version(params: SimParams) -> str:
    """The generator version recorded for these params: SIM_VERSION, plus LOOPS_VERSION for
    the loops layout."""
    return SIM_VERSION if params.layout == "ring" else f"{SIM_VERSION}+{params.layout}{LOOPS_VERSION}"


def _cache_key(params: SimParams, calib: KinectCalibration) -> str:
    # The calibration's numbers, not its folder path, go into the key.
    blob = json.dumps(
        {
            "version": sim_version(params),
            "params": params_record(params),
            "calib": [np.asarray(a, dtype=np.float64).round(12).tolist() for a in (calib.ir.fc, calib.ir.cc, calib.rgb.fc, calib.rgb.cc, calib.R, calib.T_mm)],
        },
        sort_keys=True,
    )
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def _people(params: SimParams, world: World, t_rel: np.ndarray) -> np.ndarray:
    """The sequence's `n_people` walking people at the times `t_rel` (`people.walking_people`)."""
    return walking_people(world, params.n_people, params.seed, t_rel)


def simulate_truth(params: SimParams) -> tuple[World, Motion, np.ndarray]:
    """The world, the true motion on the fine 1 ms grid and the odometry (N, 3) on the same
    grid, without rendering any sensor: what `generate_sequence` draws everything from."""
    seed = params.seed
    world = build_world(seed, n_clutter=params.n_clutter, texture_res_m=params.texture_res_m, scale=params.world_scale, layout=params.layout)
    motion: Motion = simulate_motion(
        seed, params.duration_s, world.loop_min, world.loop_max,
        walk_speed_mps=params.walk_speed_mps, turn_rate_rps=np.deg2rad(params.turn_rate_dps), stand_s=params.stand_s,
        step_freq_hz=params.step_freq_hz, roll_amp_deg=params.roll_amp_deg, pitch_amp_deg=params.pitch_amp_deg,
        waypoints=world.route, jerk_deg=params.jerk_deg, jerk_every_s=params.jerk_every_s,
        neck_sweep_deg=params.neck_sweep_deg, neck_sweep_period_s=params.neck_sweep_period_s,
    )  # fmt: skip
    odo_fine = simulate_odometry(
        motion, seed, scale_bias=params.odom_scale_bias, yaw_drift_deg_per_min=params.odom_yaw_drift_deg_per_min,
        yaw_bias_deg_per_m=params.odom_yaw_bias_deg_per_m, noise_m_per_sqrt_s=params.odom_noise_m_per_sqrt_s,
        noise_deg_per_sqrt_s=params.odom_noise_deg_per_sqrt_s,
    )  # fmt: skip
    return world, motion, odo_fine


def generate_sequence(folder: str | Path, params: SimParams = SimParams(), calibration_dir: str | Path | None = None) -> dict:
    """Write a complete simulated sequence into `folder` (created; existing files with the
    same names are overwritten). Returns a summary dict (counts, sizes in pixels).

    Not atomic by itself: `load_sim` and the CLI generate into a temporary folder and rename.
    """
    from slamlab.datasets import thor_write as tw  # the shared THOR writer

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    truth_dir = folder / simtruth.TRUTH_DIR
    truth_dir.mkdir(exist_ok=True)
    seed = params.seed
    calib = simcalib.sim_calibration(params.kinect_scale, calibration_dir)
    world, motion, odo_fine = simulate_truth(params)
    rng_imu = np.random.default_rng([seed, 606])
    imu_sigma = np.deg2rad(params.imu_noise_deg)

    def odom_at(t_rel: np.ndarray) -> np.ndarray:
        o = np.stack([np.interp(t_rel, motion.t, odo_fine[:, k]) for k in range(3)], axis=1)
        o[:, 2] = wrap_angle(o[:, 2])
        return o

    def imu_at(state: dict, odom: np.ndarray) -> np.ndarray:
        # IMU: true roll/pitch plus noise; its yaw is the (drifting) odometry heading.
        n = odom.shape[0]
        return np.stack([state["roll"] + rng_imu.normal(0, imu_sigma, n), state["pitch"] + rng_imu.normal(0, imu_sigma, n), odom[:, 2]], axis=1)

    # ---- lidar (40 Hz) ----
    n_scans = int(np.floor(params.duration_s * LIDAR_HZ + 1e-9))
    t_lidar = np.arange(n_scans) / LIDAR_HZ
    s_lidar = motion.sample(t_lidar)
    lidar_poses = sensor_poses(s_lidar, "lidar")
    scans, _, _ = simulate_scans(lidar_poses, world.boxes, _people(params, world, t_lidar), seed,
                                 range_noise_m=params.range_noise_m, dropout_fraction=params.dropout_fraction)
    odom_lidar = odom_at(t_lidar)
    tw.write_lidar_mat(folder / f"train_lidar{SEQUENCE}.mat", T0_UNIX_S + t_lidar, odom_lidar, imu_at(s_lidar, odom_lidar), scans,
                       res=round(float(BEAM_RES_RAD), 4))

    # ---- joints (100 Hz, starting a little before the first scan and ending after the last) ----
    t_joint = np.arange(-0.05, params.duration_s + 0.05, 1.0 / JOINT_HZ)
    s_joint = motion.sample(t_joint)
    odom_joint = odom_at(t_joint)
    tw.write_joint_mat(folder / f"train_joint{SEQUENCE}.mat", T0_UNIX_S + t_joint, np.stack([s_joint["neck_yaw"], s_joint["head_pitch"]]),
                       imu_at(s_joint, odom_joint).T)

    # ---- Kinect (depth + colour at the same instants) ----
    n_rgbd = 0
    labels: dict[str, np.ndarray] = {}
    if params.rgbd:
        t_k = np.arange(0.25, params.duration_s, 1.0 / params.kinect_rate_hz)
        n_rgbd = t_k.size
        s_k = motion.sample(t_k)
        ir_poses = sensor_poses(s_k, "camera")
        odom_k = odom_at(t_k)
        imu_k = imu_at(s_k, odom_k)
        heads = np.stack([s_k["neck_yaw"], s_k["head_pitch"]], axis=1)
        people_k = _people(params, world, t_k)
        rng_depth = np.random.default_rng([seed, 707])
        ir_rays = camera_rays(calib.ir)

        def depth_frames() -> Iterator:
            for k in range(n_rgbd):
                depth, floor = render_depth(ir_poses[k], calib.ir, ir_rays, world.boxes, people_k[k], rng_depth, params.depth_noise_mm)
                if params.label_every > 0 and k % params.label_every == 0:
                    labels[f"frame_{k:05d}"] = floor
                yield tw.DepthRecord(T0_UNIX_S + t_k[k], depth, imu_k[k], odom_k[k], heads[k], robot.COM_HEIGHT_M)

        tw.write_depth_mat(folder / f"DEPTH_{SEQUENCE}.mat", depth_frames())
        if params.rgb:
            rgb_rays = camera_rays(calib.rgb)
            rgb_in_ir = rgb_to_ir(calib)

            def rgb_frames() -> Iterator:
                for k in range(n_rgbd):
                    img = render_rgb(ir_poses[k] @ rgb_in_ir, calib.rgb, rgb_rays, world.boxes, world.colors, people_k[k], world.floor)
                    yield tw.RGBRecord(T0_UNIX_S + t_k[k], img, imu_k[k], odom_k[k], heads[k], robot.COM_HEIGHT_M)

            tw.write_rgb_mats(folder, SEQUENCE, rgb_frames())
        simcalib.write_camera_params(folder / "cameraParam", calib)

    # ---- ground truth ----
    write_tum(truth_dir / simtruth.TRAJECTORY_FILE, T0_UNIX_S + t_lidar, np.column_stack([s_lidar["pose"][:, :2], wrap_angle(s_lidar["pose"][:, 2])]))
    simtruth.write_grid_png(truth_dir, simtruth.OCCUPANCY_FILE, occupancy_grid(world, params.occupancy_res_m))
    simtruth.write_grid_png(truth_dir, simtruth.TEXTURE_FILE, world.floor)
    if labels:
        simtruth.write_npz(truth_dir / simtruth.LABELS_FILE, labels)
    simtruth.write_npz(
        truth_dir / simtruth.STATES_FILE,
        {"t": T0_UNIX_S + t_lidar, "pose": s_lidar["pose"], "roll": s_lidar["roll"], "pitch": s_lidar["pitch"],
         "neck_yaw": s_lidar["neck_yaw"], "head_pitch": s_lidar["head_pitch"]},
    )  # fmt: skip
    simtruth.write_npz(
        truth_dir / simtruth.JOINT_STATES_FILE,
        {"t": T0_UNIX_S + t_joint, "pose": s_joint["pose"], "roll": s_joint["roll"], "pitch": s_joint["pitch"],
         "neck_yaw": s_joint["neck_yaw"], "head_pitch": s_joint["head_pitch"]},
    )  # fmt: skip
    summary = {
        "sim_version": sim_version(params),
        "params": params_record(params),
        "scans": int(n_scans),
        "rgbd_frames": int(n_rgbd),
        "depth_size": [calib.ir.width, calib.ir.height] if params.rgbd else None,
        "rgb_size": [calib.rgb.width, calib.rgb.height] if params.rgbd and params.rgb else None,
        "world_boxes": world.boxes.round(6).tolist(),
        "world_box_kind": world.kind.tolist(),
        "world_box_rgb": world.colors.tolist(),
    }
    (folder / "sim.json").write_text(json.dumps(summary, indent=1, sort_keys=True) + "\n")
    return summary


def generate_atomic(target: str | Path, params: SimParams, calibration_dir: str | Path | None = None, replace: bool = False) -> Path:
    """Generate into a temporary sibling folder, then rename it to `target` in one step, so
    parallel jobs never see a half-written sequence. If `target` appeared meanwhile (another
    job won the race) it is kept and ours discarded, unless `replace`."""
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    _remove_stale_temps(target)
    tmp = target.parent / f".tmp-{target.name}-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    try:
        generate_sequence(tmp, params, calibration_dir)
        if replace and target.exists():
            trash = target.parent / f".old-{target.name}-{uuid.uuid4().hex[:8]}"
            os.rename(target, trash)
            shutil.rmtree(trash, ignore_errors=True)
        try:
            os.rename(tmp, target)
        except OSError:
            if not target.is_dir():
                raise
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return target


def _remove_stale_temps(target: Path, older_than_s: float = 3600.0) -> None:
    """Delete temporary folders of killed generations of `target` (older than an hour, so a
    job that is still writing is never disturbed)."""
    import time

    now = time.time()
    for p in target.parent.glob(f".tmp-{target.name}-*"):
        try:
            if now - p.stat().st_mtime > older_than_s:
                shutil.rmtree(p, ignore_errors=True)
        except OSError:
            pass


def sim_folder(params: SimParams, calibration_dir: str | Path | None = None, cache_dir: str | Path | None = None) -> Path:
    """Where `load_sim` keeps the sequence for these parameters:
    `cache_dir or paths.cache_dir()/sim`, then a hash of the params, calibration and SIM_VERSION."""
    from slamlab import paths

    base = Path(cache_dir).expanduser() if cache_dir is not None else paths.cache_dir() / "sim"
    return base / f"sim-s{params.seed}-{_cache_key(params, simcalib.sim_calibration(params.kinect_scale, calibration_dir))}"


def load_sim(
    calibration_dir: str | None = None,
    cache_dir: str | None = None,
    regenerate: bool = False,
    **knobs: object,
) -> Sequence:
    """The simulated THOR-OP sequence for these `knobs` (any `SimParams` field, e.g.
    `seed=3, duration_s=60`; see `SimParams` for units and defaults), with `ground_truth`
    attached. Generated once into the cache (`cache_dir`, default `paths.cache_dir()/sim`;
    atomic), then read back through `load_thor` like real data. `calibration_dir`: a real
    `cameraParam/` folder to take the Kinect numbers from (default: the built-in copy of the
    THOR calibration). `regenerate`: rebuild even if cached."""
    from slamlab.errors import ConfigError

    fields = {f.name: f for f in dataclasses.fields(SimParams)}
    unknown = sorted(set(knobs) - set(fields))
    if unknown:
        raise ConfigError(f"dataset.{unknown[0]}", f"is not a simulator setting (known: {', '.join(fields)})")
    params = SimParams(**{k: _typed(k, fields[k].type, v) for k, v in knobs.items()})
    validate_params(params)
    folder = sim_folder(params, calibration_dir, cache_dir)
    if regenerate or not folder.is_dir():
        generate_atomic(folder, params, calibration_dir, replace=regenerate)
    return read_sim_folder(folder, name=f"sim-seed{params.seed}")


def read_sim_folder(folder: str | Path, name: str | None = None) -> Sequence:
    """Read a generated folder with the THOR reader and attach its ground truth."""
    from slamlab.datasets.thor import load_thor
    from slamlab.errors import DataError

    folder = Path(folder)
    seq = load_thor(folder, sequence=SEQUENCE, name=name or f"sim-{folder.name}")
    gt = simtruth.load_ground_truth(folder)
    if gt.poses.shape[0] != len(seq):
        raise DataError(folder / simtruth.TRUTH_DIR / simtruth.TRAJECTORY_FILE, f"{gt.poses.shape[0]} poses for {len(seq)} scans")
    seq.ground_truth = gt
    seq.sources.append(str((folder / "sim.json").resolve()))
    return seq


def _typed(key: str, kind: object, value: object) -> object:
    """Convert a config value to the SimParams field's type, or name the key (`dataset.*`)."""
    from slamlab.errors import ConfigError

    kind_name = kind if isinstance(kind, str) else getattr(kind, "__name__", str(kind))
    if kind_name == "str":
        if isinstance(value, str):
            return value
        raise ConfigError(f"dataset.{key}", f"must be a string, got {value!r}")
    if kind_name == "bool":
        if isinstance(value, bool):
            return value
        raise ConfigError(f"dataset.{key}", f"must be true or false, got {value!r}")
    try:
        number = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ConfigError(f"dataset.{key}", f"must be a number, got {value!r}") from None
    if kind_name == "int":
        if not number.is_integer():
            raise ConfigError(f"dataset.{key}", f"must be an integer, got {value!r}")
        return int(number)
    return number


def validate_params(p: SimParams) -> None:
    """Raise ConfigError (naming the `dataset.*` key) for impossible values."""
    from slamlab.datasets.sim.world import LAYOUTS
    from slamlab.errors import ConfigError

    scale_lo, scale_hi = (0.7, 2.0) if p.layout == "loops" else (0.85, 3.0)
    checks = [
        ("layout", p.layout in LAYOUTS, f"must be one of {', '.join(LAYOUTS)}"),
        ("duration_s", p.duration_s > 0.5, "must be > 0.5 s"),
        ("stand_s", p.stand_s >= 0, "must be >= 0 s (longer than duration_s: the robot never moves)"),
        ("walk_speed_mps", 0 < p.walk_speed_mps <= 2.0, "must be in (0, 2] m/s"),
        ("turn_rate_dps", 0 < p.turn_rate_dps <= 180, "must be in (0, 180] deg/s"),
        ("n_clutter", p.n_clutter >= 0, "must be >= 0"),
        ("world_scale", scale_lo <= p.world_scale <= scale_hi, f"must be in [{scale_lo:g}, {scale_hi:g}] for layout {p.layout} (the plan's rooms need room)"),
        ("n_people", p.n_people >= 0, "must be >= 0"),
        ("jerk_deg", 0 <= p.jerk_deg <= 20, "must be in [0, 20] deg"),
        ("jerk_every_s", p.jerk_every_s > 0, "must be > 0 s"),
        ("neck_sweep_deg", 0 <= p.neck_sweep_deg <= 90, "must be in [0, 90] deg"),
        ("neck_sweep_period_s", p.neck_sweep_period_s > 0, "must be > 0 s"),
        ("range_noise_m", p.range_noise_m >= 0, "must be >= 0"),
        ("dropout_fraction", 0 <= p.dropout_fraction < 1, "must be in [0, 1)"),
        ("kinect_rate_hz", p.kinect_rate_hz > 0, "must be > 0"),
        ("kinect_scale", 0.02 <= p.kinect_scale <= 1.0, "must be in [0.02, 1]"),
        ("texture_res_m", 0.002 <= p.texture_res_m <= 0.5, "must be in [0.002, 0.5] m"),
        ("occupancy_res_m", 0.01 <= p.occupancy_res_m <= 1.0, "must be in [0.01, 1] m"),
    ]
    for key, ok, msg in checks:
        if not ok:
            raise ConfigError(f"dataset.{key}", f"{msg}, got {getattr(p, key)!r}")
