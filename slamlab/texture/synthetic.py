"""Analytic RGB-D frames of a textured floor (and optionally a wall), for tests and benchmarks.

A pinhole Kinect (no lens distortion unless the intrinsics carry it) at a known world pose
looks at the plane z = 0 coloured by a `GridImage` texture, optionally with a vertical wall
x = wall_x_m. Depth is the exact ray/plane intersection; colour is rendered by casting the
RGB camera's own rays, so RGB-D alignment is exercised exactly as on real data.
"""

from __future__ import annotations

import numpy as np

from slamlab.frames import KINECT_MAX_DEPTH_M, CameraIntrinsics, GridImage, KinectCalibration
from slamlab.texture.backproject import undistort_normalized

WALL_RGB = (200, 30, 200)  # a colour the floor textures below never use


def checker_texture(size_m: float = 12.0, res_m: float = 0.02, tile_m: float = 0.25, seed: int = 0) -> GridImage:
    """A random-colour checkerboard centred on the origin (row 0 = lowest y)."""
    rng = np.random.default_rng(seed)
    n = int(round(size_m / res_m))
    nt = int(np.ceil(size_m / tile_m))
    palette = rng.integers(30, 230, size=(nt, nt, 3)).astype(np.uint8)
    idx = (np.arange(n) * res_m // tile_m).astype(int)
    img = palette[idx[:, None], idx[None, :]]
    return GridImage(np.ascontiguousarray(img), res_m, (-size_m / 2, -size_m / 2))


def _camera_rays(intr: CameraIntrinsics) -> np.ndarray:
    """(H, W, 3) normalised rays (x/z, y/z, 1) of every pixel centre."""
    v, u = np.mgrid[0 : intr.height, 0 : intr.width].astype(np.float64)
    yd = (v - intr.cc[1]) / intr.fc[1]
    xd = (u - intr.cc[0]) / intr.fc[0] - intr.alpha_c * yd
    if np.any(np.asarray(intr.kc) != 0):
        xd, yd = undistort_normalized(xd, yd, intr.kc)
    return np.stack([xd, yd, np.ones_like(xd)], axis=-1)


def _hit(T_world_cam: np.ndarray, rays: np.ndarray, wall_x_m: float | None) -> tuple[np.ndarray, np.ndarray]:
    """Camera-z of the first hit along each ray (inf if none) and whether it is the floor."""
    R, c = T_world_cam[:3, :3], T_world_cam[:3, 3]
    d = rays @ R.T  # world direction per unit camera-z
    with np.errstate(divide="ignore", invalid="ignore"):
        lam_floor = np.where(d[..., 2] < -1e-9, -c[2] / d[..., 2], np.inf)
        if wall_x_m is not None:
            lam_wall = (wall_x_m - c[0]) / d[..., 0]
            lam_wall = np.where(np.isfinite(lam_wall) & (lam_wall > 0), lam_wall, np.inf)
        else:
            lam_wall = np.full_like(lam_floor, np.inf)
    floor = lam_floor <= lam_wall
    return np.minimum(lam_floor, lam_wall), floor & np.isfinite(lam_floor)


def render_frame(
    calib: KinectCalibration,
    T_world_ir: np.ndarray,
    texture: GridImage,
    wall_x_m: float | None = None,
    max_depth_m: float = KINECT_MAX_DEPTH_M,
    noise_m: float = 0.0,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Render (depth_m (H, W) float32, rgb (h, w, 3) uint8, floor_label (H, W) bool).

    `T_world_ir` places the IR optical frame in the world (z = 0 is the floor). Depth beyond
    `max_depth_m` is 0 (invalid), like the Kinect. `noise_m` adds Gaussian depth noise."""
    T = np.asarray(T_world_ir, dtype=np.float64)
    lam, floor = _hit(T, _camera_rays(calib.ir), wall_x_m)
    depth = np.where(lam <= max_depth_m, lam, 0.0)
    if noise_m > 0:
        rng = np.random.default_rng(seed)
        depth = np.where(depth > 0, depth + rng.normal(0.0, noise_m, depth.shape), 0.0)
    label = floor & (depth > 0)

    # RGB camera in the world: P_rgb = R P_ir + T  =>  T_world_rgb = T_world_ir inv([R | T]).
    T_rgb_ir = np.eye(4)
    T_rgb_ir[:3, :3] = calib.R
    T_rgb_ir[:3, 3] = np.asarray(calib.T_mm, dtype=np.float64).reshape(3) / 1000.0
    T_world_rgb = T @ np.linalg.inv(T_rgb_ir)
    rays = _camera_rays(calib.rgb)
    lam_c, floor_c = _hit(T_world_rgb, rays, wall_x_m)
    pts = rays * np.where(np.isfinite(lam_c), lam_c, 0.0)[..., None]
    world = pts @ T_world_rgb[:3, :3].T + T_world_rgb[:3, 3]
    th, tw = texture.data.shape[:2]
    col = np.floor((world[..., 0] - texture.origin_xy[0]) / texture.resolution_m).astype(np.int64)
    row = np.floor((world[..., 1] - texture.origin_xy[1]) / texture.resolution_m).astype(np.int64)
    inside = floor_c & (col >= 0) & (col < tw) & (row >= 0) & (row < th)
    rgb = np.zeros(rays.shape[:2] + (3,), dtype=np.uint8)
    rgb[inside] = texture.data[row[inside], col[inside], :3]
    rgb[~floor_c & np.isfinite(lam_c)] = WALL_RGB
    return depth.astype(np.float32), rgb, label


def scaled_calibration(calib: KinectCalibration, scale: float) -> KinectCalibration:
    """The same Kinect with both images resized by `scale` (fast small frames for tests)."""
    from slamlab.texture.backproject import scaled_intrinsics

    def s(intr: CameraIntrinsics) -> CameraIntrinsics:
        return scaled_intrinsics(intr, max(1, round(intr.width * scale)), max(1, round(intr.height * scale)))

    return KinectCalibration(ir=s(calib.ir), rgb=s(calib.rgb), R=calib.R, T_mm=calib.T_mm)


def synthetic_sequence(
    calib: KinectCalibration,
    poses: np.ndarray,
    texture: GridImage | None = None,
    head_pitch_rad: float = 0.6,
    neck_yaw_rad: float = 0.0,
    wall_x_m: float | None = 3.0,
    noise_m: float = 0.0,
    name: str = "synthetic-floor",
):
    """A `Sequence` with one RGB-D frame per pose (times 0, 1, 2, ... s), ground labels and the
    true floor texture; `poses` (N, 3) are the true body poses. Frames are rendered up front
    (use a `scaled_calibration` for speed)."""
    from slamlab.frames import GroundTruth, RGBDFrame, Sequence
    from slamlab.robot import COM_HEIGHT_M, camera_to_body
    from slamlab.texture.pipeline import body_to_world

    texture = texture if texture is not None else checker_texture()
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    frames: list[RGBDFrame] = []
    labels: dict[int, np.ndarray] = {}
    cam_to_body = camera_to_body(neck_yaw_rad, head_pitch_rad)
    for i, pose in enumerate(poses):
        T = body_to_world(pose, COM_HEIGHT_M) @ cam_to_body
        depth, rgb, label = render_frame(calib, T, texture, wall_x_m=wall_x_m, noise_m=noise_m, seed=i)
        frames.append(
            RGBDFrame(
                index=i, t=float(i), depth_m=depth, rgb=rgb, rgb_t=float(i),
                head_angles=np.array([neck_yaw_rad, head_pitch_rad]), camera_to_body=cam_to_body, odom=pose.copy(),
            )  # fmt: skip
        )
        labels[i] = label
    return Sequence(
        name=name,
        scans=[],
        body_height_m=COM_HEIGHT_M,
        sources=[],
        rgbd=lambda: iter(frames),
        rgbd_count=len(frames),
        calibration=calib,
        ground_truth=GroundTruth(poses=poses, floor_texture=texture, ground_labels=labels),
    )
