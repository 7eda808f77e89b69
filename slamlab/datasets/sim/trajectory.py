"""The true motion of the walking robot: a route around the corridor loop, the gait's body
sway and the neck/head motion, as smooth functions of time.

The route is a list of primitives (stand, walk, turn in place) with trapezoidal velocity
profiles (0.5 s ramps, so velocity is continuous); the pose is integrated from those
velocities on a fine 1 ms grid and interpolated at any sample time (joint 100 Hz, lidar
40 Hz, Kinect). Walking repeats the loop until the requested duration, so every lap passes
through the start again (a loop closure through a known place).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slamlab.geometry import FloatArray

FINE_DT_S = 0.001
RAMP_S = 0.5


@dataclass(frozen=True, slots=True)
class Motion:
    """True state on the fine grid. `t` (s, relative to the sequence start); `pose` (N, 3)
    x, y (m), theta (rad, unwrapped); `v` (m/s) forward and `w` (rad/s) yaw rate in the body
    frame; `roll`, `pitch` body attitude (rad); `neck_yaw`, `head_pitch` (rad, positive
    pitch looks down)."""

    t: FloatArray
    pose: FloatArray
    v: FloatArray
    w: FloatArray
    roll: FloatArray
    pitch: FloatArray
    neck_yaw: FloatArray
    head_pitch: FloatArray

    def sample(self, t: FloatArray) -> dict[str, FloatArray]:
        """Linear interpolation of every field at times `t` (s, relative); theta unwrapped."""
        t = np.asarray(t, dtype=np.float64)
        out = {"pose": np.stack([np.interp(t, self.t, self.pose[:, k]) for k in range(3)], axis=1)}
        for name in ("v", "w", "roll", "pitch", "neck_yaw", "head_pitch"):
            out[name] = np.interp(t, self.t, getattr(self, name))
        return out


def _trapezoid(n: int, dt: float, peak: float) -> FloatArray:
    """A velocity profile over n samples ramping up and down over RAMP_S each."""
    tt = (np.arange(n) + 0.5) * dt
    total = n * dt
    ramp = min(RAMP_S, total / 2)
    return peak * np.clip(np.minimum(tt, total - tt) / ramp, 0.0, 1.0)


def route_commands(duration_s: float, loop_min: tuple[float, float], loop_max: tuple[float, float],
                   start_xy: tuple[float, float], walk_speed_mps: float, turn_rate_rps: float,
                   stand_s: float) -> tuple[FloatArray, FloatArray]:
    """Body velocities (v m/s, w rad/s) on the fine grid: stand still for `stand_s`, then walk
    the rectangle counter-clockwise from `start_xy` (on its south edge, facing +x), turning
    90 degrees in place at each corner, until `duration_s`."""
    n_total = int(round(duration_s / FINE_DT_S))
    v = np.zeros(n_total)
    w = np.zeros(n_total)
    i = int(round(stand_s / FINE_DT_S))
    width = loop_max[0] - loop_min[0]
    height = loop_max[1] - loop_min[1]
    # legs after the start: to the SE corner, then N, W, S, E edges forever
    legs = [loop_max[0] - start_xy[0]]
    pattern = [height, width, height, width]
    k = 0
    while i < n_total:
        dist = legs[0] if k == 0 else pattern[(k - 1) % 4]
        # distance = peak * (T - ramp) for a trapezoid, so T = dist / v + ramp
        n = int(round((dist / walk_speed_mps + RAMP_S) / FINE_DT_S))
        seg = _trapezoid(n, FINE_DT_S, walk_speed_mps)
        seg *= dist / (seg.sum() * FINE_DT_S)  # exact distance despite rounding
        m = min(n, n_total - i)
        v[i : i + m] = seg[:m]
        i += n
        if i >= n_total:
            break
        angle = np.pi / 2
        n = int(round((angle / turn_rate_rps + RAMP_S) / FINE_DT_S))
        seg = _trapezoid(n, FINE_DT_S, turn_rate_rps)
        seg *= angle / (seg.sum() * FINE_DT_S)
        m = min(n, n_total - i)
        w[i : i + m] = seg[:m]
        i += n
        k += 1
    return v, w


def _bumps(rng: np.random.Generator, t: FloatArray, first_s: float, gap_s: tuple[float, float],
           amp: tuple[float, float], dur_s: tuple[float, float], signed: bool) -> FloatArray:
    """Sum of smooth raised-cosine-edged plateaus at random times: head movements."""
    out = np.zeros_like(t)
    s = first_s
    end = t[-1] if t.size else 0.0
    while s < end:
        a = rng.uniform(*amp) * (rng.choice([-1.0, 1.0]) if signed else 1.0)
        d = rng.uniform(*dur_s)
        edge = min(0.8, d / 3)
        u = t - s
        up = 0.5 - 0.5 * np.cos(np.pi * np.clip(u / edge, 0, 1))
        down = 0.5 - 0.5 * np.cos(np.pi * np.clip((d - u) / edge, 0, 1))
        out += a * np.minimum(up, down)
        s += d + rng.uniform(*gap_s)
    return out


def simulate_motion(seed: int, duration_s: float, loop_min: tuple[float, float], loop_max: tuple[float, float],
                    walk_speed_mps: float = 0.45, turn_rate_rps: float = 0.6, stand_s: float = 2.5,
                    step_freq_hz: float = 1.6, roll_amp_deg: float = 2.5, pitch_amp_deg: float = 1.5,
                    head_pitch_down_deg: tuple[float, float] = (17.0, 30.0), first_head_down_s: float = 4.0) -> Motion:
    """True motion for `duration_s` seconds starting at the origin facing +x.

    Gait: body roll sways at the stride frequency (`step_freq_hz` / 2, `roll_amp_deg`) and
    pitch at the step frequency (`pitch_amp_deg`), scaled by how fast the robot moves (no sway
    while standing). Head: the head pitches down by `head_pitch_down_deg` every 10-16 s
    (first at `first_head_down_s`), so lidar beams reach the floor; the neck yaws +-17..40
    deg now and then.
    """
    rng = np.random.default_rng([seed, 202])
    v, w = route_commands(duration_s, loop_min, loop_max, (0.0, 0.0), walk_speed_mps, turn_rate_rps, stand_s)
    n = v.size
    t = np.arange(n) * FINE_DT_S
    theta = np.concatenate([[0.0], np.cumsum(w[:-1]) * FINE_DT_S])
    # midpoint heading per step: second-order accurate integration of the unicycle
    th_mid = theta + 0.5 * w * FINE_DT_S
    x = np.concatenate([[0.0], np.cumsum(v[:-1] * np.cos(th_mid[:-1])) * FINE_DT_S])
    y = np.concatenate([[0.0], np.cumsum(v[:-1] * np.sin(th_mid[:-1])) * FINE_DT_S])
    pose = np.stack([x, y, theta], axis=1)

    activity = np.clip(np.maximum(v / max(walk_speed_mps, 1e-9), np.abs(w) / max(turn_rate_rps, 1e-9)), 0, 1)
    # the gait phase advances only while stepping
    phase = 2 * np.pi * step_freq_hz * np.cumsum(activity) * FINE_DT_S
    phi_r, phi_p = rng.uniform(0, 2 * np.pi, size=2)
    roll = np.deg2rad(roll_amp_deg) * activity * np.sin(0.5 * phase + phi_r)
    pitch = np.deg2rad(pitch_amp_deg) * activity * np.sin(phase + phi_p) + np.deg2rad(0.5) * activity
    head_pitch = np.deg2rad(_bumps(rng, t, first_head_down_s, (6.0, 10.0), head_pitch_down_deg, (2.5, 4.0), signed=False))
    neck_yaw = np.deg2rad(_bumps(rng, t, first_head_down_s + 4.0, (8.0, 14.0), (17.0, 40.0), (2.0, 4.0), signed=True))
    return Motion(t=t, pose=pose, v=v, w=w, roll=roll, pitch=pitch, neck_yaw=neck_yaw, head_pitch=head_pitch)
