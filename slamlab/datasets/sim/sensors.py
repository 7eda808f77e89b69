"""Simulated proprioception and lidar: drifting walking odometry, IMU attitude, and the
Hokuyo UTM-30LX on the head (40 Hz, 1081 beams over +-135 deg)."""

from __future__ import annotations

import numpy as np

from slamlab import geometry, robot
from slamlab.geometry import FloatArray
from slamlab.datasets.sim.raycast import cast_scans
from slamlab.datasets.sim.trajectory import FINE_DT_S, Motion

N_BEAMS = 1081
BEAM_RES_RAD = np.deg2rad(0.25)
BEAM_ANGLES = np.linspace(-np.deg2rad(135.0), np.deg2rad(135.0), N_BEAMS)
LIDAR_MAX_M = 30.0
LIDAR_MIN_M = 0.1


def sensor_poses(state: dict[str, FloatArray], sensor: str) -> np.ndarray:
    """(N, 4, 4) world poses of the lidar (`sensor="lidar"`) or the Kinect IR optical frame
    (`"camera"`) from sampled true states, through the robot's head chain (slamlab.robot)."""
    mount = robot.lidar_to_body if sensor == "lidar" else robot.camera_to_body
    pose = state["pose"]
    out = np.empty((pose.shape[0], 4, 4))
    for i in range(pose.shape[0]):
        T_wb = geometry.body_to_world(pose[i, 0], pose[i, 1], pose[i, 2], state["roll"][i], state["pitch"][i], robot.COM_HEIGHT_M)
        out[i] = T_wb @ mount(state["neck_yaw"][i], state["head_pitch"][i])
    return out


def simulate_odometry(motion: Motion, seed: int, scale_bias: float = 0.025, yaw_drift_deg_per_min: float = 2.0,
                      yaw_bias_deg_per_m: float = 0.0, noise_m_per_sqrt_s: float = 0.005,
                      noise_deg_per_sqrt_s: float = 0.3) -> FloatArray:
    """Walking odometry (N, 3) on the fine grid, integrated from [0, 0, 0].

    The robot's own estimate of its body velocity is wrong in the ways a legged robot's is:
    distance over-counted by `scale_bias` (2.5 % = 2.5 cm per metre), a heading drift of
    `yaw_drift_deg_per_min` per minute of stepping that itself wanders slowly, an optional
    per-distance yaw bias, and white velocity noise (`noise_*` are the 1-second random-walk
    sigmas). While the robot stands still the odometry does not change (as on the real robot).
    """
    rng = np.random.default_rng([seed, 303])
    n = motion.v.size
    dt = FINE_DT_S
    moving = (np.abs(motion.v) > 1e-9) | (np.abs(motion.w) > 1e-9)
    # yaw drift rate wanders by ~30 % over a minute: a bias, not just noise
    wander = np.cumsum(rng.normal(0.0, 1.0, n)) * np.sqrt(dt) * (0.3 / np.sqrt(60.0))
    drift_rps = np.deg2rad(yaw_drift_deg_per_min) / 60.0 * (1.0 + wander)
    sig_v = noise_m_per_sqrt_s / np.sqrt(dt)
    sig_w = np.deg2rad(noise_deg_per_sqrt_s) / np.sqrt(dt)
    v = motion.v * (1.0 + scale_bias) + rng.normal(0.0, sig_v, n) * moving
    vy = rng.normal(0.0, sig_v, n) * moving  # sideways slip
    w = motion.w + (drift_rps + rng.normal(0.0, sig_w, n)) * moving + np.deg2rad(yaw_bias_deg_per_m) * np.abs(motion.v)
    theta = np.concatenate([[0.0], np.cumsum(w[:-1]) * dt])
    th_mid = theta + 0.5 * w * dt
    c, s = np.cos(th_mid), np.sin(th_mid)
    x = np.concatenate([[0.0], np.cumsum((v * c - vy * s)[:-1]) * dt])
    y = np.concatenate([[0.0], np.cumsum((v * s + vy * c)[:-1]) * dt])
    return np.stack([x, y, theta], axis=1)


def simulate_scans(lidar_to_world: np.ndarray, boxes: np.ndarray, cylinders: np.ndarray, seed: int,
                   range_noise_m: float = 0.01, dropout_fraction: float = 0.005) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ranges (N, 1081) float32 in metres as the sensor reports them: true range + Gaussian
    noise (`range_noise_m`), a random `dropout_fraction` of beams 0, and 0 for no return
    (nothing within 30 m) or below 0.1 m. Also returns the noiseless ranges (float64, inf for
    no return) and hit ids, for ground truth and tests."""
    rng = np.random.default_rng([seed, 404])
    if cylinders.ndim != 3:
        cylinders = np.zeros((lidar_to_world.shape[0], 0, 4))
    true_r, ids = cast_scans(np.ascontiguousarray(lidar_to_world), BEAM_ANGLES, boxes, np.ascontiguousarray(cylinders), LIDAR_MAX_M)
    true_r[ids == -1] = np.inf
    noisy = true_r + rng.normal(0.0, range_noise_m, true_r.shape)
    bad = ~np.isfinite(noisy) | (noisy > LIDAR_MAX_M) | (noisy < LIDAR_MIN_M) | (rng.random(true_r.shape) < dropout_fraction)
    noisy[bad] = 0.0
    return noisy.astype(np.float32), true_r, ids
