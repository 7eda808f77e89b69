"""Depth image to 3D points in the Kinect IR (depth) optical frame.

Conventions
- The optical frame is z forward, x right, y down (THOR_FORMAT.md); points are in metres.
- Pixel coordinates follow the Bouguet calibration toolbox that produced the `cameraParam/`
  files: (u, v) = (column, row) and (0, 0) is the CENTRE of the top-left pixel, so pixel
  (row r, col c) has u = c, v = r. Pixel to ray: x = (u - cc_u) z / fc_u, y = (v - cc_v) z / fc_v.
- Mirroring: the Kinect stores its images mirrored left-right. The dataset readers undo this
  (`RGBDFrame.depth_m` and `.rgb` are as a person sees them), so nothing here flips images.
  The calibration is applied to the un-mirrored images as it is; if a calibration was
  estimated on the mirrored images, convert it once with `slamlab.texture.align.unmirror_calibration`
  (texture config `calibration_mirrored: true`).
- Lens distortion (`kc`, Bouguet: k1 k2 p1 p2 k3) is optional. Because every depth pixel's
  ray is fixed, the undistorted ray of each pixel is computed ONCE per camera and stride (an
  iterative inversion of the distortion model) and a frame then costs one multiply per axis:
  undistortion is free per frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slamlab.frames import KINECT_MAX_DEPTH_M, KINECT_MIN_DEPTH_M, CameraIntrinsics


def scaled_intrinsics(intr: CameraIntrinsics, width: int, height: int) -> CameraIntrinsics:
    """The same camera for an image of `width` x `height` px (e.g. a simulator that renders a
    smaller image than the calibrated one): focal lengths and principal point scale with the
    image; distortion (in normalised coordinates) does not change."""
    if width == intr.width and height == intr.height:
        return intr
    sx, sy = width / intr.width, height / intr.height
    # Pixel centres at integer coordinates: a pixel-centre grid scales about -0.5.
    cc = np.array([(intr.cc[0] + 0.5) * sx - 0.5, (intr.cc[1] + 0.5) * sy - 0.5])
    return CameraIntrinsics(
        fc=np.array([intr.fc[0] * sx, intr.fc[1] * sy]),
        cc=cc,
        kc=np.asarray(intr.kc, dtype=np.float64).copy(),
        alpha_c=intr.alpha_c,
        width=int(width),
        height=int(height),
    )


def distort_normalized(x: np.ndarray, y: np.ndarray, kc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Apply the Bouguet distortion model to normalised image coordinates (x = X/Z, y = Y/Z)."""
    k1, k2, p1, p2, k3 = (float(k) for k in np.asarray(kc, dtype=np.float64).reshape(-1)[:5])
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return xd, yd


def undistort_normalized(
    xd: np.ndarray, yd: np.ndarray, kc: np.ndarray, iterations: int = 12
) -> tuple[np.ndarray, np.ndarray]:
    """Invert `distort_normalized` with Newton's method (analytic 2x2 Jacobian).

    Why not the toolbox's fixed-point iteration: with the Kinect IR lens (k2 = -0.25) it
    diverges in the image corners. Worse, there the model has NO inverse: r (1 + k1 r^2 +
    k2 r^4) peaks at r_d ~ 0.85, while the IR image corners reach r_d ~ 0.9 (the polynomial is
    extrapolated beyond the calibration target). Such points, and any that do not converge or
    land on the folded-back branch (Jacobian determinant <= 0), come back as NaN so callers
    drop them rather than place them wrongly. Runs once per camera (see `Backprojector`).
    Converges to ~1e-12 elsewhere."""
    k1, k2, p1, p2, k3 = (float(k) for k in np.asarray(kc, dtype=np.float64).reshape(-1)[:5])
    xd = np.asarray(xd, dtype=np.float64)
    yd = np.asarray(yd, dtype=np.float64)
    x, y = xd.copy(), yd.copy()
    for _ in range(iterations):
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        g = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d radial / d r2
        fx = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) - xd
        fy = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y - yd
        jxx = radial + 2.0 * x * x * g + 2.0 * p1 * y + 6.0 * p2 * x
        jxy = 2.0 * x * y * g + 2.0 * p1 * x + 2.0 * p2 * y
        jyy = radial + 2.0 * y * y * g + 6.0 * p1 * y + 2.0 * p2 * x
        det = jxx * jyy - jxy * jxy  # the Jacobian is symmetric
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            x = x - (jyy * fx - jxy * fy) / det
            y = y - (jxx * fy - jxy * fx) / det
    with np.errstate(invalid="ignore", over="ignore"):
        rx, ry = distort_normalized(x, y, kc)
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        g = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
        jxx = radial + 2.0 * x * x * g + 2.0 * p1 * y + 6.0 * p2 * x
        jxy = 2.0 * x * y * g + 2.0 * p1 * x + 2.0 * p2 * y
        jyy = radial + 2.0 * y * y * g + 6.0 * p1 * y + 2.0 * p2 * x
        ok = (np.abs(rx - xd) < 1e-9) & (np.abs(ry - yd) < 1e-9) & (jxx * jyy - jxy * jxy > 0) & (jxx > 0)
    return np.where(ok, x, np.nan), np.where(ok, y, np.nan)


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
            s = self.stride
            v, u = np.mgrid[0:height:s, 0:width:s]
            xd = (u - intr.cc[0]) / intr.fc[0]
            yd = (v - intr.cc[1]) / intr.fc[1]
            # alpha_c (skew) is 0 for the Kinect files; honour it anyway: x_pix = fc*(x + alpha*y) + cc.
            xd = xd - intr.alpha_c * yd
            if self.undistort and np.any(np.asarray(intr.kc) != 0):
                xd, yd = undistort_normalized(xd, yd, intr.kc)
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
