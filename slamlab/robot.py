"""THOR-OP geometry (see THOR_FORMAT.md): heights in metres, the head kinematic chain.

Body frame: origin at the centre of mass, x forward, y left, z up. The world pose of the
body is Txyz(x, y, COM_HEIGHT_M) Rz(theta) Ry(pitch) Rx(roll).
"""

from __future__ import annotations

import numpy as np

from slamlab.geometry import FloatArray, rot_y, rot_z, trans

COM_HEIGHT_M = 0.93  # centre of mass (body origin) above the ground
HEAD_ABOVE_COM_M = 0.33  # neck/head joint above the centre of mass
LIDAR_ABOVE_HEAD_M = 0.15  # lidar above the head joint, not rotated
KINECT_ABOVE_HEAD_M = 0.07  # Kinect above the head joint, not rotated
IMU_BELOW_COM_M = 0.16

# Camera optical axes (z forward, x right, y down) expressed in head axes (x fwd, y left, z up).
HEAD_R_CAMERA = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def head_to_body(neck_yaw: float, head_pitch: float) -> FloatArray:
    """4x4 transform of the head joint frame into the body frame (rad)."""
    return trans(z=HEAD_ABOVE_COM_M) @ rot_z(neck_yaw) @ rot_y(head_pitch)


def lidar_to_body(neck_yaw: float, head_pitch: float) -> FloatArray:
    """4x4 transform of the lidar frame into the body frame."""
    return head_to_body(neck_yaw, head_pitch) @ trans(z=LIDAR_ABOVE_HEAD_M)


def camera_to_body(neck_yaw: float, head_pitch: float) -> FloatArray:
    """4x4 transform of the Kinect IR (depth) optical frame into the body frame."""
    m = np.eye(4)
    m[:3, :3] = HEAD_R_CAMERA
    return head_to_body(neck_yaw, head_pitch) @ trans(z=KINECT_ABOVE_HEAD_M) @ m
