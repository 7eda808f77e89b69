"""Kinect v2 rendering: depth in the IR camera and colour in the RGB camera, ray cast from
the same world the lidar sees (floor with its texture, boxes with one plain colour each).

Images are produced UN-mirrored (as a person sees them); the THOR writer mirrors them the
way the real files are stored. Depth is the z-coordinate in the IR optical frame (what the
Kinect reports), in millimetres, 0 where invalid (nothing hit, or outside 0.4..4.5 m).
"""

from __future__ import annotations

import numpy as np

from slamlab.camera import pixel_rays
from slamlab.frames import KINECT_MAX_DEPTH_M, KINECT_MIN_DEPTH_M, CameraIntrinsics, GridImage, KinectCalibration
from slamlab.geometry import FloatArray
from slamlab.datasets.sim.raycast import HIT_FLOOR, HIT_NONE, cast_camera, colour_hits

DEPTH_MIN_M = KINECT_MIN_DEPTH_M
DEPTH_MAX_M = KINECT_MAX_DEPTH_M
PERSON_RGB = (190, 70, 60)
CEILING_RGB = (225, 225, 215)  # rays that leave over the 2.5 m walls: an unmodelled ceiling


def camera_rays(cam: CameraIntrinsics) -> FloatArray:
    """(H*W, 3) optical-frame rays (x, y, 1) through each pixel centre, row-major, so that a
    ray parameter equals the z-depth: `slamlab.camera.pixel_rays` of an ideal pinhole."""
    _, _, x, y = pixel_rays(cam)
    rays = np.stack([x, y, np.ones_like(x)], axis=-1)
    return np.ascontiguousarray(rays.reshape(-1, 3))


def rgb_to_ir(calib: KinectCalibration) -> FloatArray:
    """4x4 pose of the RGB optical frame in the IR optical frame (metres), from
    P_rgb = R P_ir + T_mm / 1000."""
    R = np.asarray(calib.R, dtype=np.float64)
    T = np.asarray(calib.T_mm, dtype=np.float64).reshape(3) / 1000.0
    m = np.eye(4)
    m[:3, :3] = R.T
    m[:3, 3] = -R.T @ T
    return m


def visible_boxes(cam_to_world: FloatArray, cam: CameraIntrinsics, boxes: np.ndarray, far_m: float) -> np.ndarray:
    """Indices of the boxes that may appear in the image: a box is dropped only if all 8 of
    its corners lie outside the same plane of the view frustum (conservative, so no box that
    is visible is ever dropped). Ray casting then tests ~3x fewer boxes per pixel."""
    if boxes.shape[0] == 0:
        return np.zeros(0, dtype=np.int64)
    xs = boxes[:, [0, 2]]
    ys = boxes[:, [1, 3]]
    zs = np.stack([np.zeros(len(boxes)), boxes[:, 4]], axis=1)
    corners = np.stack(
        [np.stack([xs[:, i], ys[:, j], zs[:, k]], axis=1) for i in (0, 1) for j in (0, 1) for k in (0, 1)], axis=1
    )  # (K, 8, 3) world
    R, t = cam_to_world[:3, :3], cam_to_world[:3, 3]
    pc = (corners - t) @ R  # world -> camera: R^T (p - t)
    x, y, z = pc[..., 0], pc[..., 1], pc[..., 2]
    # image edges as slopes x/z, y/z (half a pixel beyond the outer pixel centres)
    x_lo, x_hi = (-0.5 - cam.cc[0]) / cam.fc[0], (cam.width - 0.5 - cam.cc[0]) / cam.fc[0]
    y_lo, y_hi = (-0.5 - cam.cc[1]) / cam.fc[1], (cam.height - 0.5 - cam.cc[1]) / cam.fc[1]
    out = (
        np.all(z <= 0.0, axis=1)
        | np.all(z > far_m, axis=1)
        | np.all(x > x_hi * z, axis=1)
        | np.all(x < x_lo * z, axis=1)
        | np.all(y > y_hi * z, axis=1)
        | np.all(y < y_lo * z, axis=1)
    )
    return np.flatnonzero(~out)


def render_depth(ir_to_world: FloatArray, cam: CameraIntrinsics, rays: FloatArray, boxes: np.ndarray,
                 cylinders: np.ndarray, rng: np.random.Generator, noise_mm: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """One depth image (H, W) uint16 mm (0 = invalid) and its floor mask (H, W) bool (True
    where the pixel's first hit is the floor and the depth is valid), both un-mirrored."""
    keep = visible_boxes(ir_to_world, cam, boxes, DEPTH_MAX_M * 2.0)
    z, ids, _ = cast_camera(np.ascontiguousarray(ir_to_world), rays, np.ascontiguousarray(boxes[keep]), cylinders, DEPTH_MAX_M * 2.0)
    z = z + rng.normal(0.0, noise_mm / 1000.0, z.shape)
    valid = (ids != HIT_NONE) & (z >= DEPTH_MIN_M) & (z <= DEPTH_MAX_M)
    depth_mm = np.where(valid, np.round(z * 1000.0), 0.0).astype(np.uint16)
    floor = valid & (ids == HIT_FLOOR)
    return depth_mm.reshape(cam.height, cam.width), floor.reshape(cam.height, cam.width)


def render_rgb(rgb_to_world: FloatArray, cam: CameraIntrinsics, rays: FloatArray, boxes: np.ndarray,
               colors: np.ndarray, cylinders: np.ndarray, floor: GridImage) -> np.ndarray:
    """One colour image (H, W, 3) uint8, un-mirrored. Floor pixels take the floor texture at
    the hit point (nearest texel); box faces their box colour, shaded by face orientation so
    corners stay visible; people a fixed colour; nothing hit (up, over the walls) ceiling grey."""
    keep = visible_boxes(rgb_to_world, cam, boxes, 60.0)
    boxes, colors = np.ascontiguousarray(boxes[keep]), np.ascontiguousarray(colors[keep])
    _, ids, pts = cast_camera(np.ascontiguousarray(rgb_to_world), rays, boxes, cylinders, 60.0)
    out = colour_hits(ids, pts, boxes, colors, floor.data, float(floor.origin_xy[0]), float(floor.origin_xy[1]),
                      float(floor.resolution_m), np.array(PERSON_RGB, dtype=np.uint8), np.array(CEILING_RGB, dtype=np.uint8))
    return out.reshape(cam.height, cam.width, 3)
