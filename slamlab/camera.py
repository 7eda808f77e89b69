"""The pinhole camera with Bouguet lens distortion: pixels to rays, in one place.

Conventions (the calibration toolbox that produced the `cameraParam/` files): the optical
frame is z forward, x right, y down; (u, v) = (column, row) and (0, 0) is the CENTRE of the
top-left pixel. A pixel's normalised ray is (x, y) = (X/Z, Y/Z) with
y = (v - cc_v) / fc_v and x = (u - cc_u) / fc_u - alpha_c y, then the inverse of the lens
distortion `kc` (k1 k2 p1 p2 k3) when it is undistorted. The simulator's renderer (which also
renders the tests' frames) and the texture stage's back-projection take their rays from `pixel_rays`.
"""

from __future__ import annotations

import numpy as np

from slamlab.frames import CameraIntrinsics


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


def pixel_rays(
    intr: CameraIntrinsics, stride: int = 1, undistort: bool = False
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The normalised ray through every `stride`-th pixel centre of `intr`'s image.

    Returns (u, v, x, y), each (ceil(height / stride), ceil(width / stride)): the pixel's
    column and row (int) and its ray x = X/Z, y = Y/Z (float64), so a point at z-depth d is
    d * (x, y, 1). With `undistort` the lens distortion is inverted (`undistort_normalized`:
    NaN where the model has no inverse); without, the camera is an ideal pinhole."""
    v, u = np.mgrid[0 : intr.height : stride, 0 : intr.width : stride]
    y = (v - intr.cc[1]) / intr.fc[1]
    x = (u - intr.cc[0]) / intr.fc[0]
    # alpha_c (skew) is 0 for the Kinect files; honour it anyway: x_pix = fc*(x + alpha*y) + cc.
    x = x - intr.alpha_c * y
    if undistort and np.any(np.asarray(intr.kc) != 0):
        x, y = undistort_normalized(x, y, intr.kc)
    return u, v, x, y
