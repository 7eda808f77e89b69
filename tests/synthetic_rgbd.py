"""Test support: RGB-D frames of a textured floor and one wall, rendered by the simulator's
Kinect renderer (`slamlab.datasets.sim.kinect`), so tests of the texture stage and the ground
detectors never render their frames with the code under test.

A Kinect at known body poses looks at the floor z = 0 coloured by a `GridImage` texture and,
optionally, a wall at x = wall_x_m. Depth and the floor labels come from the IR camera's
rays, colour from the RGB camera's own rays (the calibration's R, T), so RGB-D alignment is
exercised as on real data. The renderer is an ideal pinhole: a calibration's lens distortion
is not applied to the images.
"""

from __future__ import annotations

import numpy as np

from slamlab.camera import scaled_intrinsics
from slamlab.datasets.sim.kinect import camera_rays, render_depth, render_rgb, rgb_to_ir
from slamlab.frames import CameraIntrinsics, GridImage, GroundTruth, KinectCalibration, RGBDFrame, Sequence
from slamlab.geometry import body_to_world
from slamlab.robot import COM_HEIGHT_M, camera_to_body

WALL_HEIGHT_M = 2.5
WALL_RGB = (200, 30, 200)  # a colour the checker textures below never use (before face shading)
NO_PEOPLE = np.zeros((0, 4))  # the renderer's cylinders [x, y, radius, height]: none here


def checker_texture(size_m: float = 12.0, res_m: float = 0.02, tile_m: float = 0.25, seed: int = 0) -> GridImage:
    """A random-colour checkerboard centred on the origin (row 0 = lowest y), tiles of `tile_m` m."""
    rng = np.random.default_rng(seed)
    n = int(round(size_m / res_m))
    nt = int(np.ceil(size_m / tile_m))
    palette = rng.integers(30, 230, size=(nt, nt, 3)).astype(np.uint8)
    idx = (np.arange(n) * res_m // tile_m).astype(int)
    img = palette[idx[:, None], idx[None, :]]
    return GridImage(np.ascontiguousarray(img), res_m, (-size_m / 2, -size_m / 2))


def scaled_calibration(calib: KinectCalibration, scale: float) -> KinectCalibration:
    """The same Kinect with both images resized by `scale` (fast small frames for tests)."""

    def s(intr: CameraIntrinsics) -> CameraIntrinsics:
        return scaled_intrinsics(intr, max(1, round(intr.width * scale)), max(1, round(intr.height * scale)))

    return KinectCalibration(ir=s(calib.ir), rgb=s(calib.rgb), R=calib.R, T_mm=calib.T_mm)


def _wall(wall_x_m: float | None) -> tuple[np.ndarray, np.ndarray]:
    """The renderer's boxes [x0, y0, x1, y1, height] (m) and their colours: one thin, long wall."""
    if wall_x_m is None:
        return np.zeros((0, 5)), np.zeros((0, 3), dtype=np.uint8)
    boxes = np.array([[wall_x_m, -50.0, wall_x_m + 0.1, 50.0, WALL_HEIGHT_M]])
    return boxes, np.array([WALL_RGB], dtype=np.uint8)


def synthetic_sequence(
    calib: KinectCalibration,
    poses: np.ndarray,
    texture: GridImage | None = None,
    head_pitch_rad: float = 0.6,
    neck_yaw_rad: float = 0.0,
    wall_x_m: float | None = 3.0,
    noise_mm: float = 0.0,
    name: str = "synthetic-floor",
) -> Sequence:
    """A `Sequence` with one RGB-D frame per pose (times 0, 1, 2, ... s), ground labels and the
    true floor texture; `poses` (N, 3) are the true body poses (m, m, rad). Depth is what the
    simulated Kinect reports: mm resolution, 0.4-4.5 m, Gaussian noise of `noise_mm`. Frames
    are rendered up front (use a `scaled_calibration` for speed)."""
    texture = texture if texture is not None else checker_texture()
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    boxes, colours = _wall(wall_x_m)
    ir_rays, rgb_rays, rgb_in_ir = camera_rays(calib.ir), camera_rays(calib.rgb), rgb_to_ir(calib)
    rng = np.random.default_rng(0)
    cam_to_body = camera_to_body(neck_yaw_rad, head_pitch_rad)
    frames: list[RGBDFrame] = []
    labels: dict[int, np.ndarray] = {}
    for i, pose in enumerate(poses):
        x, y, th = (float(v) for v in pose)
        ir_to_world = body_to_world(x, y, th, height_m=COM_HEIGHT_M) @ cam_to_body
        depth_mm, floor = render_depth(ir_to_world, calib.ir, ir_rays, boxes, NO_PEOPLE, rng, noise_mm)
        rgb = render_rgb(ir_to_world @ rgb_in_ir, calib.rgb, rgb_rays, boxes, colours, NO_PEOPLE, texture)
        frames.append(
            RGBDFrame(
                index=i, t=float(i), depth_m=(depth_mm / np.float32(1000.0)).astype(np.float32), rgb=rgb, rgb_t=float(i),
                head_angles=np.array([neck_yaw_rad, head_pitch_rad]), camera_to_body=cam_to_body, odom=pose.copy(),
            )  # fmt: skip
        )
        labels[i] = floor
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
