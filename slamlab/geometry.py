"""Rigid-body algebra: SE(2) poses as (x m, y m, theta rad) arrays, SE(3) as 4x4 matrices.

All SE(2) functions accept a single pose of shape (3,) or a stack of shape (N, 3) and
broadcast, so particle sets are handled without Python loops.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


def wrap_angle(theta: ArrayLike) -> FloatArray:
    """Wrap angles (rad) to [-pi, pi)."""
    t = np.asarray(theta, dtype=np.float64)
    return (t + np.pi) % (2.0 * np.pi) - np.pi


def se2_compose(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """a (+) b: pose b expressed in frame a, returned in a's parent frame."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = a[..., 0] + c * b[..., 0] - s * b[..., 1]
    y = a[..., 1] + s * b[..., 0] + c * b[..., 1]
    th = wrap_angle(a[..., 2] + b[..., 2])
    return np.stack([x, y, th], axis=-1)


def se2_inverse(a: ArrayLike) -> FloatArray:
    """The inverse pose: se2_compose(a, se2_inverse(a)) == 0."""
    a = np.asarray(a, dtype=np.float64)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = -c * a[..., 0] - s * a[..., 1]
    y = s * a[..., 0] - c * a[..., 1]
    return np.stack([x, y, wrap_angle(-a[..., 2])], axis=-1)


def se2_between(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """a (-) b in the course's notation reversed: the pose of b seen from a, inv(a) (+) b."""
    return se2_compose(se2_inverse(a), b)


def se2_fit(src_xy: ArrayLike, dst_xy: ArrayLike) -> FloatArray:
    """The pose T (x m, y m, theta rad) that best carries points `src_xy` onto `dst_xy` (both
    (N, 2), pairwise): se2_compose(T, (p, 0)) ~ q in the least-squares sense, rotation and
    translation only (Kabsch in 2-D). One point gives the pure translation."""
    a = np.asarray(src_xy, dtype=np.float64).reshape(-1, 2)
    b = np.asarray(dst_xy, dtype=np.float64).reshape(-1, 2)
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    u, v = a - ca, b - cb
    theta = float(np.arctan2(np.sum(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]), np.sum(u[:, 0] * v[:, 0] + u[:, 1] * v[:, 1])))
    c, s = np.cos(theta), np.sin(theta)
    return np.array([cb[0] - (c * ca[0] - s * ca[1]), cb[1] - (s * ca[0] + c * ca[1]), theta])


def weighted_mean_pose(poses: ArrayLike, weights: ArrayLike) -> FloatArray:
    """The weighted mean of SE(2) poses (N, 3) (x m, y m, theta rad): x and y averaged, theta
    the circular mean (the angle of the weighted sum of unit vectors). `weights` (N,) need
    not be normalised."""
    p = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    w = np.asarray(weights, dtype=np.float64).reshape(-1)
    w = w / w.sum()
    theta = np.arctan2(w @ np.sin(p[:, 2]), w @ np.cos(p[:, 2]))
    return np.array([w @ p[:, 0], w @ p[:, 1], theta])


def se2_to_matrix(a: ArrayLike) -> FloatArray:
    """(3,) pose to a 3x3 homogeneous matrix."""
    x, y, th = np.asarray(a, dtype=np.float64)
    c, s = np.cos(th), np.sin(th)
    return np.array([[c, -s, x], [s, c, y], [0.0, 0.0, 1.0]])


def rot_x(angle: float) -> FloatArray:
    """4x4 rotation about +x by angle (rad)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1]], dtype=np.float64)


def rot_y(angle: float) -> FloatArray:
    """4x4 rotation about +y by angle (rad)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0, s, 0], [0, 1, 0, 0], [-s, 0, c, 0], [0, 0, 0, 1]], dtype=np.float64)


def rot_z(angle: float) -> FloatArray:
    """4x4 rotation about +z by angle (rad)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=np.float64)


def trans(x: float = 0.0, y: float = 0.0, z: float = 0.0) -> FloatArray:
    """4x4 translation (m)."""
    m = np.eye(4)
    m[:3, 3] = (x, y, z)
    return m


def transform_points(T: ArrayLike, points: ArrayLike) -> FloatArray:
    """Apply a 4x4 transform to (N, 3) points."""
    T = np.asarray(T, dtype=np.float64)
    p = np.asarray(points, dtype=np.float64)
    return p @ T[:3, :3].T + T[:3, 3]


def yaw_to_quaternion(theta: ArrayLike) -> FloatArray:
    """Planar yaw (rad) to unit quaternions (qx, qy, qz, qw), shape (..., 4)."""
    th = np.asarray(theta, dtype=np.float64)
    z = np.zeros_like(th)
    return np.stack([z, z, np.sin(th / 2.0), np.cos(th / 2.0)], axis=-1)


def body_to_world(x: float, y: float, theta: float, roll: float = 0.0, pitch: float = 0.0, height_m: float = 0.0) -> FloatArray:
    """4x4 world pose of the body frame, as slamlab.frames defines it:
    Txyz(x, y, height_m) Rz(theta) Ry(pitch) Rx(roll) (m, rad)."""
    return trans(x, y, height_m) @ rot_z(theta) @ rot_y(pitch) @ rot_x(roll)
