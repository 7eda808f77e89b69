"""Scan to points: lidar polar readings to 2D points in the body-yaw frame.

For one scan the chain `Tz(body_height) Ry(pitch) Rx(roll) lidar_to_body` is the same for
every particle (particles differ only in x, y, yaw), so it is applied once here; a particle
then only rotates the 2D points by its yaw and translates them (`points_to_world`).
The body-yaw frame has its origin below/at the body origin, axes x forward, y left of the
robot's heading, z up from the floor.

Dropped: invalid beams (`ScanFrame.valid`), beams shorter than `min_range_m` or longer than
`max_range_m` (m), and, when the sequence knows the body height, points whose height above
the floor is below `ground_threshold_m` (they hit the ground, not a wall).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import TYPE_CHECKING

import numpy as np

from slamlab.frames import ScanFrame, Sequence
from slamlab.geometry import FloatArray, body_to_world

if TYPE_CHECKING:
    from slamlab.slam.grid import MapSettings


@dataclass(frozen=True, slots=True)
class ScanPoints:
    """`xy` (M, 2) points (m) in the body-yaw frame; `origin` (2,) the lidar centre there."""

    xy: FloatArray
    origin: FloatArray


def scan_to_points(
    frame: ScanFrame,
    body_height_m: float | None,
    min_range_m: float,
    max_range_m: float,
    ground_threshold_m: float,
) -> ScanPoints:
    """Project one scan into the body-yaw frame, dropping unusable and ground points.

    `body_height_m` None means a planar robot (CARMEN): no ground filtering, heights ignored.
    """
    r = frame.ranges.astype(np.float64)
    a = frame.angles.astype(np.float64)
    keep = frame.valid & np.isfinite(r) & (r >= min_range_m) & (r <= max_range_m)
    r, a = r[keep], a[keep]
    height = 0.0 if body_height_m is None else float(body_height_m)
    T = _lidar_in_body_yaw(float(frame.roll), float(frame.pitch), height, np.asarray(frame.lidar_to_body, dtype=np.float64).tobytes())
    p = np.stack([r * np.cos(a), r * np.sin(a)], axis=1)
    # transform of (x, y, 0): only the first two columns of the rotation matter
    pts = p @ T[:3, :2].T + T[:3, 3]
    if body_height_m is not None:
        pts = pts[pts[:, 2] > ground_threshold_m]
    return ScanPoints(xy=np.ascontiguousarray(pts[:, :2]), origin=T[:2, 3].copy())


@lru_cache(maxsize=16)
def _lidar_in_body_yaw(roll: float, pitch: float, height_m: float, lidar_to_body: bytes) -> FloatArray:
    """4x4 pose of the lidar in the body-yaw frame (the body at the origin with zero yaw:
    particles add x, y, theta later, in 2D). Cached: a planar log's scans all share one (the
    engine projects every scan, ~10,000 on Intel), a THOR walk's change with the IMU."""
    T = body_to_world(0.0, 0.0, 0.0, roll, pitch, height_m) @ np.frombuffer(lidar_to_body, dtype=np.float64).reshape(4, 4)
    T.flags.writeable = False  # shared between calls
    return T


def range_limits(settings: MapSettings, sequence: Sequence) -> tuple[float, float]:
    """(min, max) beam range (m) a run uses: the map settings' own limits where set
    (`map.min_range_m` / `map.max_range_m`), else the sequence's sensor limits."""
    lo = settings.min_range_m if settings.min_range_m is not None else sequence.min_range_m
    hi = settings.max_range_m if settings.max_range_m is not None else sequence.max_range_m
    return float(lo), float(hi)


def points_to_world(points_xy: FloatArray, pose: FloatArray) -> FloatArray:
    """Rotate (M, 2) body-yaw points by pose[2] (rad) and translate by pose[:2] (m)."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    x = pose[0] + c * points_xy[:, 0] - s * points_xy[:, 1]
    y = pose[1] + s * points_xy[:, 0] + c * points_xy[:, 1]
    return np.stack([x, y], axis=1)
