"""The true motion of the walking robot: a route around the corridor loop (ring layout) or
along a polyline (loops layout), the gait's body sway and jerks and the neck/head motion, as
smooth functions of time.

The route is a list of primitives (stand, walk, turn in place) with trapezoidal velocity
profiles (0.5 s ramps, so velocity is continuous); the pose is integrated from those
velocities on a fine 1 ms grid and interpolated at any sample time (joint 100 Hz, lidar
40 Hz, Kinect). On the ring, walking repeats the loop until the requested duration, so every
lap passes through the start again (a loop closure through a known place); a polyline route
is walked to its end, then back again after a U-turn, until the duration.
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
        out = {"pose": interp_columns(t, self.t, self.pose)}
        for name in ("v", "w", "roll", "pitch", "neck_yaw", "head_pitch"):
            out[name] = np.interp(t, self.t, getattr(self, name))
        return out


def interp_columns(t: FloatArray, grid_t: FloatArray, values: FloatArray) -> FloatArray:
    """Each column of `values` (N, K), given at times `grid_t` (N,), linearly interpolated at
    times `t` (M,): (M, K). Angles must be unwrapped."""
    return np.stack([np.interp(t, grid_t, values[:, k]) for k in range(values.shape[1])], axis=1)


def integrate_commands(v: FloatArray, w: FloatArray) -> FloatArray:
    """Poses (N, 3: x m, y m, theta rad unwrapped) on the fine grid from forward speed `v`
    (m/s) and yaw rate `w` (rad/s), starting at the origin facing +x."""
    theta = np.concatenate([[0.0], np.cumsum(w[:-1]) * FINE_DT_S])
    # midpoint heading per step: second-order accurate integration of the unicycle
    th_mid = theta + 0.5 * w * FINE_DT_S
    x = np.concatenate([[0.0], np.cumsum(v[:-1] * np.cos(th_mid[:-1])) * FINE_DT_S])
    y = np.concatenate([[0.0], np.cumsum(v[:-1] * np.sin(th_mid[:-1])) * FINE_DT_S])
    return np.stack([x, y, theta], axis=1)


def _trapezoid(n: int, dt: float, peak: float) -> FloatArray:
    """A velocity profile over n samples ramping up and down over RAMP_S each."""
    tt = (np.arange(n) + 0.5) * dt
    total = n * dt
    ramp = min(RAMP_S, total / 2)
    return peak * np.clip(np.minimum(tt, total - tt) / ramp, 0.0, 1.0)


def _move(out: FloatArray, i: int, amount: float, peak: float) -> int:
    """Write into `out` from sample `i` a trapezoid profile (ramps of RAMP_S, then `peak`)
    that covers `amount` exactly (m at peak m/s, or rad at peak rad/s; negative = backwards),
    cut at the end of `out`. Returns the sample after the move (may be past the end)."""
    # amount = peak * (T - ramp) for a trapezoid, so T = |amount| / peak + ramp
    n = int(round((abs(amount) / peak + RAMP_S) / FINE_DT_S))
    seg = _trapezoid(n, FINE_DT_S, peak)
    seg *= amount / (seg.sum() * FINE_DT_S)  # exact amount despite rounding
    m = min(n, len(out) - i)
    out[i : i + m] = seg[:m]
    return i + n


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
        i = _move(v, i, dist, walk_speed_mps)
        if i >= n_total:
            break
        i = _move(w, i, np.pi / 2, turn_rate_rps)
        k += 1
    return v, w


def waypoint_commands(duration_s: float, waypoints: FloatArray, walk_speed_mps: float, turn_rate_rps: float,
                      stand_s: float) -> tuple[FloatArray, FloatArray]:
    """Body velocities (v m/s, w rad/s) on the fine grid: stand still for `stand_s`, then walk
    the polyline `waypoints` (K, 2) from its first point, which must be the origin with the
    first leg along +x (the robot starts there facing +x), turning in place at every corner
    by the smaller angle (a U-turn turns left). At the last point the robot turns round and
    walks the polyline backwards, and so on, until `duration_s`."""
    pts = np.asarray(waypoints, dtype=np.float64)
    legs = np.diff(pts, axis=0)
    lengths = np.hypot(legs[:, 0], legs[:, 1])
    if pts.shape[0] < 2 or np.any(lengths <= 0) or np.hypot(*pts[0]) > 1e-9 or abs(legs[0, 1]) > 1e-9 or legs[0, 0] <= 0:
        raise ValueError("waypoints must start at the origin, with distinct points and the first leg along +x")
    n_total = int(round(duration_s / FINE_DT_S))
    v = np.zeros(n_total)
    w = np.zeros(n_total)
    i = int(round(stand_s / FINE_DT_S))
    forward = [(float(d), float(np.arctan2(leg[1], leg[0]))) for d, leg in zip(lengths, legs)]
    backward = [(d, float(np.arctan2(-np.sin(h), -np.cos(h)))) for d, h in reversed(forward)]
    heading = 0.0
    k = 0
    while i < n_total:
        dist, target = (forward if (k // len(forward)) % 2 == 0 else backward)[k % len(forward)]
        angle = float(np.arctan2(np.sin(target - heading), np.cos(target - heading)))
        if abs(angle) > np.pi - 1e-9:
            angle = np.pi  # U-turn: to the left
        if abs(angle) > 1e-9:
            i = _move(w, i, angle, turn_rate_rps)
            if i >= n_total:
                break
        heading += angle
        i = _move(v, i, dist, walk_speed_mps)
        k += 1
    return v, w


def route_duration_s(waypoints: FloatArray, walk_speed_mps: float, turn_rate_rps: float, stand_s: float) -> float:
    """Seconds from the start until `waypoint_commands` reaches the last waypoint (standing
    start, every walk and turn), i.e. the `duration_s` that walks the polyline once."""
    pts = np.asarray(waypoints, dtype=np.float64)
    legs = np.diff(pts, axis=0)
    heads = np.arctan2(legs[:, 1], legs[:, 0])
    turns = np.abs(np.arctan2(np.sin(np.diff(heads)), np.cos(np.diff(heads))))
    n = round(stand_s / FINE_DT_S)
    n += sum(round((float(d) / walk_speed_mps + RAMP_S) / FINE_DT_S) for d in np.hypot(legs[:, 0], legs[:, 1]))
    n += sum(round((float(a) / turn_rate_rps + RAMP_S) / FINE_DT_S) for a in turns if a > 1e-9)
    return n * FINE_DT_S


def _jerks(rng: np.random.Generator, t: FloatArray, activity: FloatArray, amp_deg: float, every_s: float) -> tuple[FloatArray, FloatArray]:
    """Occasional larger roll and pitch jerks (a stumble, a hard foot strike): a quick tilt and
    back (one raised-cosine period of 0.25-0.6 s), up to `amp_deg` each, on average every
    `every_s` seconds, scaled by the gait's activity (none while standing). Radians."""
    roll = np.zeros_like(t)
    pitch = np.zeros_like(t)
    end = t[-1] if t.size else 0.0
    s = float(rng.uniform(0.3, 1.0)) * every_s
    while s < end:
        d = float(rng.uniform(0.25, 0.6))
        a_r, a_p = (float(rng.uniform(0.4, 1.0)) * amp_deg * float(rng.choice([-1.0, 1.0])) for _ in range(2))
        i0, i1 = int(s / FINE_DT_S), min(int((s + d) / FINE_DT_S) + 1, t.size)
        u = (t[i0:i1] - s) / d
        shape = (0.5 - 0.5 * np.cos(2 * np.pi * np.clip(u, 0.0, 1.0))) * activity[i0:i1]
        roll[i0:i1] += np.deg2rad(a_r) * shape
        pitch[i0:i1] += np.deg2rad(a_p) * shape
        s += d + float(rng.uniform(0.5, 1.5)) * every_s
    return roll, pitch


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
                    head_pitch_down_deg: tuple[float, float] = (17.0, 30.0), first_head_down_s: float = 4.0,
                    waypoints: FloatArray | None = None, jerk_deg: float = 0.0, jerk_every_s: float = 8.0,
                    neck_sweep_deg: float = 0.0, neck_sweep_period_s: float = 12.0) -> Motion:
    """True motion for `duration_s` seconds starting at the origin facing +x.

    Route: the rectangle `loop_min`..`loop_max` counter-clockwise, or, if `waypoints` is
    given, that polyline (`waypoint_commands`). Gait: body roll sways at the stride frequency
    (`step_freq_hz` / 2, `roll_amp_deg`) and pitch at the step frequency (`pitch_amp_deg`),
    scaled by how fast the robot moves (no sway while standing); with `jerk_deg` > 0, larger
    roll/pitch jerks now and then (`_jerks`). Head: the head pitches down by
    `head_pitch_down_deg` every 10-16 s (first at `first_head_down_s`), so lidar beams reach
    the floor; the neck yaws +-17..40 deg now and then, and with `neck_sweep_deg` > 0 it also
    sweeps +-`neck_sweep_deg` sinusoidally (period `neck_sweep_period_s`) once walking starts.
    The jerks and the sweep draw from their own random streams: switched off, the motion is
    exactly what it was without them.
    """
    rng = np.random.default_rng([seed, 202])
    if waypoints is None:
        v, w = route_commands(duration_s, loop_min, loop_max, (0.0, 0.0), walk_speed_mps, turn_rate_rps, stand_s)
    else:
        v, w = waypoint_commands(duration_s, waypoints, walk_speed_mps, turn_rate_rps, stand_s)
    n = v.size
    t = np.arange(n) * FINE_DT_S
    pose = integrate_commands(v, w)

    activity = np.clip(np.maximum(v / max(walk_speed_mps, 1e-9), np.abs(w) / max(turn_rate_rps, 1e-9)), 0, 1)
    # the gait phase advances only while stepping
    phase = 2 * np.pi * step_freq_hz * np.cumsum(activity) * FINE_DT_S
    phi_r, phi_p = rng.uniform(0, 2 * np.pi, size=2)
    roll = np.deg2rad(roll_amp_deg) * activity * np.sin(0.5 * phase + phi_r)
    pitch = np.deg2rad(pitch_amp_deg) * activity * np.sin(phase + phi_p) + np.deg2rad(0.5) * activity
    head_pitch = np.deg2rad(_bumps(rng, t, first_head_down_s, (6.0, 10.0), head_pitch_down_deg, (2.5, 4.0), signed=False))
    neck_yaw = np.deg2rad(_bumps(rng, t, first_head_down_s + 4.0, (8.0, 14.0), (17.0, 40.0), (2.0, 4.0), signed=True))
    if jerk_deg > 0:
        jr, jp = _jerks(np.random.default_rng([seed, 212]), t, activity, jerk_deg, jerk_every_s)
        roll = roll + jr
        pitch = pitch + jp
    if neck_sweep_deg > 0:
        phase0 = np.random.default_rng([seed, 222]).uniform(0, 2 * np.pi)
        onset = np.clip((t - stand_s) / 2.0, 0.0, 1.0)  # fades in over 2 s once the robot walks
        neck_yaw = neck_yaw + np.deg2rad(neck_sweep_deg) * onset * np.sin(2 * np.pi * t / neck_sweep_period_s + phase0)
    return Motion(t=t, pose=pose, v=v, w=w, roll=roll, pitch=pitch, neck_yaw=neck_yaw, head_pitch=head_pitch)
