"""Depth image to 3D points in the Kinect IR (depth) optical frame.

Conventions
- The optical frame is z forward, x right, y down (THOR_FORMAT.md); points are in metres.
- Pixel coordinates follow the Bouguet calibration toolbox that produced the `cameraParam/`
  files: (u, v) = (column, row) and (0, 0) is the CENTRE of the top-left pixel, so pixel
  (row r, col c) has u = c, v = r. Pixel to ray: x = (u - cc_u) z / fc_u, y = (v - cc_v) z / fc_v
  (`slamlab.camera.pixel_rays`, shared with the simulator).
- Mirroring: the Kinect stores its images mirrored left-right. The dataset readers undo this
  (`RGBDFrame.depth_m` and `.rgb` are as a person sees them), so nothing here flips images.
  The calibration is applied to the un-mirrored images as it is; if a calibration was
  estimated on the mirrored images, convert it once with `slamlab.texture.align.unmirror_calibration`
  (texture config `calibration_mirrored: true`).
- Lens distortion (`kc`, Bouguet: k1 k2 p1 p2 k3; `slamlab.camera`) is optional. Because every depth pixel's
  ray is fixed, the undistorted ray of each pixel is computed ONCE per camera and stride (an
  iterative inversion of the distortion model) and a frame then costs one multiply per axis:
  undistortion is free per frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slamlab.camera import pixel_rays, scaled_intrinsics
from slamlab.frames import KINECT_MAX_DEPTH_M, KINECT_MIN_DEPTH_M, CameraIntrinsics


@dataclass(frozen=True, slots=True)
class DepthPoints:
    """The valid depth pixels of one frame as 3D points (what ground detectors see).

    - `cam` (M, 3) float32: points in the IR optical frame (m).
    - `u`, `v` (M,) int32: pixel column / row in the full-resolution (un-mirrored) depth image.
    - `depth_m` (M,) float32: z (m), so inverse depth is 1 / depth_m.
    - `ray_x`, `ray_y` (M,) float32: the normalised (undistorted when enabled) ray, cam = z * (ray_x, ray_y, 1).
    """

    cam: np.ndarray
    u: np.ndarray
    v: np.ndarray
    depth_m: np.ndarray
    ray_x: np.ndarray
    ray_y: np.ndarray

    def __len__(self) -> int:
        return int(self.u.shape[0])


_TABLE_CACHE: dict[tuple, tuple[np.ndarray, ...]] = {}


def _intrinsics_key(intr: CameraIntrinsics, stride: int, undistort: bool, height: int, width: int) -> tuple:
    return (
        tuple(np.asarray(intr.fc, dtype=np.float64).tolist()),
        tuple(np.asarray(intr.cc, dtype=np.float64).tolist()),
        tuple(np.asarray(intr.kc, dtype=np.float64).tolist()),
        float(intr.alpha_c), intr.width, intr.height, stride, undistort, height, width,
    )  # fmt: skip


class Backprojector:
    """Turns depth images of one camera into `DepthPoints`, with the ray table precomputed.

    `stride` keeps every k-th pixel in u and v (1 = all 512x424 pixels). `undistort` applies
    the inverse of `kc` to each pixel's ray. `min_depth_m`/`max_depth_m` bound valid depth
    (the Kinect v2 is usable about 0.4..4.5 m); 0, NaN and inf are always invalid.
    """

    def __init__(
        self,
        intrinsics: CameraIntrinsics,
        stride: int = 1,
        undistort: bool = True,
        min_depth_m: float = KINECT_MIN_DEPTH_M,
        max_depth_m: float = KINECT_MAX_DEPTH_M,
    ):
        if stride < 1:
            raise ValueError(f"stride must be >= 1, got {stride}")
        self.intrinsics = intrinsics
        self.stride = int(stride)
        self.undistort = bool(undistort)
        self.min_depth_m = float(min_depth_m)
        self.max_depth_m = float(max_depth_m)
        self._tables: dict[tuple, tuple[np.ndarray, ...]] = {}

    def _table(self, height: int, width: int) -> tuple[np.ndarray, ...]:
        key = (height, width)
        if key not in self._tables:
            # Shared across instances: the SLAM and the odometry texture runs use the same camera.
            ikey = _intrinsics_key(self.intrinsics, self.stride, self.undistort, height, width)
            if ikey in _TABLE_CACHE:
                self._tables[key] = _TABLE_CACHE[ikey]
                return self._tables[key]
            intr = scaled_intrinsics(self.intrinsics, width, height)
            u, v, xd, yd = pixel_rays(intr, self.stride, self.undistort)
            self._tables[key] = (
                u.astype(np.int32).ravel(),
                v.astype(np.int32).ravel(),
                xd.astype(np.float32).ravel(),
                yd.astype(np.float32).ravel(),
            )
            if len(_TABLE_CACHE) >= 8:  # a handful of cameras per process at most
                _TABLE_CACHE.pop(next(iter(_TABLE_CACHE)))
            _TABLE_CACHE[ikey] = self._tables[key]
        return self._tables[key]

    def _ray_ok(self, height: int, width: int) -> np.ndarray:
        key = ("ok", height, width)
        if key not in self._tables:
            rx = self._table(height, width)[2]
            self._tables[key] = (np.isfinite(rx),)
        return self._tables[key][0]

    def __call__(self, depth_m: np.ndarray) -> DepthPoints:
        """Back-project a (H, W) depth image in metres (0 = invalid) to `DepthPoints`."""
        depth_m = np.asarray(depth_m)
        if depth_m.ndim != 2:
            raise ValueError(f"depth image must be 2-D (H, W), got shape {depth_m.shape}")
        u, v, rx, ry = self._table(*depth_m.shape)
        z = depth_m[:: self.stride, :: self.stride].astype(np.float32, copy=False).ravel()
        # NaN compares False, so NaN/inf/0 all fall out here without a separate isfinite pass.
        # The ray table is NaN where the lens model has no inverse (image corners): NaN * z
        # stays NaN, so those pixels are dropped together with invalid depth.
        keep = np.flatnonzero((z >= self.min_depth_m) & (z <= self.max_depth_m) & self._ray_ok(*depth_m.shape))
        z = z[keep]
        rxk, ryk = rx[keep], ry[keep]
        cam = np.empty((keep.size, 3), dtype=np.float32)
        cam[:, 0] = rxk * z
        cam[:, 1] = ryk * z
        cam[:, 2] = z
        return DepthPoints(cam=cam, u=u[keep], v=v[keep], depth_m=z, ray_x=rxk, ray_y=ryk)


def backproject(
    depth_m: np.ndarray, intrinsics: CameraIntrinsics, stride: int = 1, undistort: bool = False
) -> DepthPoints:
    """One-off convenience: back-project a depth image (m) with `intrinsics` (see `Backprojector`)."""
    return Backprojector(intrinsics, stride=stride, undistort=undistort)(depth_m)
