"""Depth -> 3D: a synthetic depth image of a known plane back-projects onto that plane."""

from __future__ import annotations

import numpy as np
import pytest

from slamlab.camera import distort_normalized, scaled_intrinsics, undistort_normalized
from slamlab.datasets.calibration import load_kinect_calibration
from slamlab.datasets.sim.calib import default_calibration
from slamlab.frames import CameraIntrinsics
from slamlab.texture.backproject import Backprojector, backproject


def _plane_depth(intr: CameraIntrinsics, n: np.ndarray, c: float, distorted: bool) -> np.ndarray:
    """Depth (m) of the plane n . P = c seen by every pixel, computed independently."""
    v, u = np.mgrid[0 : intr.height, 0 : intr.width].astype(np.float64)
    x = (u - intr.cc[0]) / intr.fc[0]
    y = (v - intr.cc[1]) / intr.fc[1]
    if distorted:
        x, y = undistort_normalized(x, y, intr.kc)
    return c / (n[0] * x + n[1] * y + n[2])


@pytest.fixture(scope="module")
def real_calib(shared_data):
    return load_kinect_calibration(shared_data / "thor" / "cameraParam")


def test_known_plane_back_projects_to_the_plane_pinhole():
    ir = default_calibration().ir  # real focal lengths / principal point, no distortion
    n = np.array([0.1, -0.6, 0.8])
    n /= np.linalg.norm(n)
    depth = _plane_depth(ir, n, 1.5, distorted=False).astype(np.float32)
    depth[depth > 4.5] = 0
    pts = backproject(depth, ir, undistort=False)
    assert len(pts) > 0.5 * depth.size
    assert np.abs(pts.cam.astype(np.float64) @ n - 1.5).max() < 1e-5
    # The pixel formula itself: x = (u - cc_u) z / fc_u.
    i = len(pts) // 2
    assert pts.cam[i, 0] == pytest.approx((pts.u[i] - ir.cc[0]) * pts.depth_m[i] / ir.fc[0], rel=1e-5)
    assert pts.cam[i, 1] == pytest.approx((pts.v[i] - ir.cc[1]) * pts.depth_m[i] / ir.fc[1], rel=1e-5)


def test_known_plane_with_real_lens_distortion(real_calib):
    ir = real_calib.ir
    assert np.any(ir.kc != 0)
    n = np.array([0.0, -0.5, 0.85])
    n /= np.linalg.norm(n)
    depth = _plane_depth(ir, n, 1.2, distorted=True).astype(np.float32)
    good = Backprojector(ir, undistort=True)(depth)
    assert np.abs(good.cam.astype(np.float64) @ n - 1.2).max() < 1e-4
    # Ignoring kc bends the plane: the corners are off by centimetres.
    bad = Backprojector(ir, undistort=False)(depth)
    assert np.abs(bad.cam.astype(np.float64) @ n - 1.2).max() > 0.01


def test_undistort_inverts_distort(real_calib):
    rng = np.random.default_rng(0)
    x, y = rng.uniform(-0.6, 0.6, 1000), rng.uniform(-0.5, 0.5, 1000)
    xd, yd = distort_normalized(x, y, real_calib.ir.kc)
    xu, yu = undistort_normalized(xd, yd, real_calib.ir.kc)
    assert np.abs(xu - x).max() < 1e-9 and np.abs(yu - y).max() < 1e-9


def test_undistort_marks_corners_without_inverse(real_calib):
    # The IR model r(1 + k1 r^2 + k2 r^4) peaks at r_d ~ 0.85: the extreme corners (r_d ~ 0.9)
    # have no undistorted ray. They must come back NaN (dropped), not as garbage.
    ir = real_calib.ir
    v, u = np.mgrid[0 : ir.height, 0 : ir.width].astype(np.float64)
    xd, yd = (u - ir.cc[0]) / ir.fc[0], (v - ir.cc[1]) / ir.fc[1]
    xu, yu = undistort_normalized(xd, yd, ir.kc)
    ok = np.isfinite(xu)
    assert 0.97 < ok.mean() < 1.0
    assert ok[ir.height // 2, :].all() and ok[:, ir.width // 2].all()  # centre lines all fine
    assert not ok[0, 0] and not ok[-1, -1]
    rx, ry = distort_normalized(xu[ok], yu[ok], ir.kc)
    assert np.abs(rx - xd[ok]).max() < 1e-9 and np.abs(ry - yd[ok]).max() < 1e-9
    pts = Backprojector(ir, undistort=True)(np.full((ir.height, ir.width), 2.0, np.float32))
    assert len(pts) == ok.sum() and np.isfinite(pts.cam).all()


def test_invalid_depth_dropped_and_stride():
    ir = default_calibration().ir
    depth = np.full((ir.height, ir.width), 2.0, dtype=np.float32)
    depth[0, :] = 0.0
    depth[1, :] = np.nan
    depth[2, :] = np.inf
    depth[3, :] = 0.2  # closer than the Kinect can see
    depth[4, :] = 9.0  # beyond max
    pts = Backprojector(ir, stride=1)(depth)
    assert len(pts) == (ir.height - 5) * ir.width
    assert pts.v.min() == 5
    s2 = Backprojector(ir, stride=2)(depth)
    assert set(np.unique(s2.u) % 2) == {0} and set(np.unique(s2.v) % 2) == {0}
    assert len(s2) == len(range(6, ir.height, 2)) * len(range(0, ir.width, 2))
    assert len(Backprojector(ir)(np.zeros_like(depth))) == 0
    with pytest.raises(ValueError):
        Backprojector(ir)(np.zeros(10))


def test_scaled_intrinsics_keep_geometry():
    ir = default_calibration().ir
    small = scaled_intrinsics(ir, ir.width // 4, ir.height // 4)
    assert small.fc[0] == pytest.approx(ir.fc[0] / 4)
    # The same ray: full-res pixel u maps to (u + 0.5)/4 - 0.5.
    u = 300.0
    x_full = (u - ir.cc[0]) / ir.fc[0]
    x_small = ((u + 0.5) / 4 - 0.5 - small.cc[0]) / small.fc[0]
    assert x_small == pytest.approx(x_full)
    # A depth image of another size is back-projected with scaled intrinsics automatically.
    depth = np.full((small.height, small.width), 2.0, dtype=np.float32)
    pts = Backprojector(ir, undistort=False)(depth)
    assert len(pts) == depth.size
    i = 5
    assert pts.cam[i, 0] == pytest.approx((pts.u[i] - small.cc[0]) * 2.0 / small.fc[0], rel=1e-5)
