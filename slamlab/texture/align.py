"""RGB-D alignment: IR-frame points to RGB pixels, and the colour they see.

`P_rgb = R @ P_ir + T_mm / 1000` (metres; `exParams.pkl` stores T in millimetres). A point is
then projected with the RGB intrinsics (Bouguet convention, (0, 0) = centre of the top-left
pixel) and coloured from the nearest pixel. Points behind (or too close to) the RGB camera and
points that project outside the image are dropped.

Why nearest-pixel sampling and no undistortion of the colour image: the RGB image is
1920x1080, undistorting it would cost more than the whole per-frame budget; distorting the
few projected points instead is exact and costs microseconds.
"""

from __future__ import annotations

import numpy as np

from slamlab.camera import distort_normalized, scaled_intrinsics
from slamlab.frames import CameraIntrinsics, KinectCalibration

MIN_Z_M = 0.05  # points closer than this to the RGB image plane cannot be projected reliably


def ir_to_rgb(points_ir: np.ndarray, calib: KinectCalibration) -> np.ndarray:
    """(M, 3) IR-frame points (m) to the RGB camera frame (m), same dtype as the input."""
    p = np.asarray(points_ir)
    R = np.asarray(calib.R, dtype=p.dtype if p.dtype.kind == "f" else np.float64)
    T = (np.asarray(calib.T_mm, dtype=np.float64).reshape(3) / 1000.0).astype(R.dtype)
    # Per axis rather than `p @ R.T`: small-matrix matmuls on (M, 3) are several times slower.
    out = np.empty(p.shape, dtype=R.dtype)
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    for k in range(3):
        out[:, k] = R[k, 0] * x + R[k, 1] * y + R[k, 2] * z + T[k]
    return out


def project(
    points_cam: np.ndarray, intrinsics: CameraIntrinsics, distort: bool = True
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Project camera-frame points (m) to pixels: returns (u, v, in_front) with u, v float64
    pixel coordinates (NaN where not in front) and `in_front` = z > MIN_Z_M."""
    p = np.asarray(points_cam, dtype=np.float64)
    z = p[:, 2]
    in_front = z > MIN_Z_M
    with np.errstate(divide="ignore", invalid="ignore"):
        x = np.where(in_front, p[:, 0] / z, np.nan)
        y = np.where(in_front, p[:, 1] / z, np.nan)
    if distort and np.any(np.asarray(intrinsics.kc) != 0):
        x, y = distort_normalized(x, y, intrinsics.kc)
    u = intrinsics.fc[0] * (x + intrinsics.alpha_c * y) + intrinsics.cc[0]
    v = intrinsics.fc[1] * y + intrinsics.cc[1]
    return u, v, in_front


def sample_colors(
    points_ir: np.ndarray, rgb: np.ndarray, calib: KinectCalibration, distort: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """Colour of each IR-frame point from the (un-mirrored) RGB image.

    Returns (colors (K, 3) uint8, keep (M,) bool) where `colors` are for the kept points only:
    in front of the RGB camera and projecting inside the image. If the image size differs from
    the calibrated 1920x1080 (e.g. a smaller simulated image) the intrinsics are scaled."""
    h, w = rgb.shape[:2]
    intr = scaled_intrinsics(calib.rgb, w, h)
    u, v, in_front = project(ir_to_rgb(points_ir, calib), intr, distort=distort)
    # Round to the nearest pixel centre; NaN (behind the camera) fails every comparison.
    with np.errstate(invalid="ignore"):
        ui = np.floor(u + 0.5)
        vi = np.floor(v + 0.5)
        keep = in_front & (ui >= 0) & (ui <= w - 1) & (vi >= 0) & (vi <= h - 1)
    colors = rgb[vi[keep].astype(np.intp), ui[keep].astype(np.intp)]
    return colors, keep


def unmirror_calibration(calib: KinectCalibration) -> KinectCalibration:
    """Convert a calibration estimated on left-right MIRRORED images into one for the
    un-mirrored images the readers deliver.

    Mirroring maps pixel u to (W - 1 - u) and the camera-frame x to -x. Hence cc_u ->
    W - 1 - cc_u, the tangential coefficient p2 changes sign (it multiplies odd powers of x),
    and the extrinsics become M R M, M T with M = diag(-1, 1, 1)."""

    def flip(intr: CameraIntrinsics) -> CameraIntrinsics:
        kc = np.asarray(intr.kc, dtype=np.float64).copy()
        kc[3] = -kc[3]
        return CameraIntrinsics(
            fc=np.asarray(intr.fc, dtype=np.float64).copy(),
            cc=np.array([intr.width - 1 - intr.cc[0], intr.cc[1]]),
            kc=kc,
            alpha_c=-intr.alpha_c,
            width=intr.width,
            height=intr.height,
        )

    M = np.diag([-1.0, 1.0, 1.0])
    return KinectCalibration(
        ir=flip(calib.ir),
        rgb=flip(calib.rgb),
        R=M @ np.asarray(calib.R, dtype=np.float64) @ M,
        T_mm=M @ np.asarray(calib.T_mm, dtype=np.float64).reshape(3),
    )
