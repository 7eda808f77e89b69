"""RGB-D alignment with the real calibration: a known 3D point lands on the right RGB pixel."""

from __future__ import annotations

import numpy as np
import pytest

from slamlab.datasets.calibration import load_kinect_calibration
from slamlab.texture.align import ir_to_rgb, project, sample_colors, unmirror_calibration


@pytest.fixture(scope="module")
def calib(shared_data):
    return load_kinect_calibration(shared_data / "thor" / "cameraParam")


def test_point_on_rgb_axis_projects_to_principal_point(calib):
    # P_rgb = (0, 0, 2 m) is on the RGB optical axis: it must land on cc whatever kc is.
    p_rgb = np.array([0.0, 0.0, 2.0])
    p_ir = calib.R.T @ (p_rgb - calib.T_mm / 1000.0)
    u, v, ok = project(ir_to_rgb(p_ir[None], calib), calib.rgb)
    assert ok[0]
    assert u[0] == pytest.approx(956.911, abs=1e-3) and v[0] == pytest.approx(533.452, abs=1e-3)


def test_known_point_to_pixel_by_hand(calib):
    # An IR-frame point, worked through the formulas with plain scalars (not the library).
    X = np.array([0.30, -0.20, 2.00])
    R, T = calib.R, calib.T_mm / 1000.0
    Pr = [sum(R[i, j] * X[j] for j in range(3)) + T[i] for i in range(3)]
    x, y = Pr[0] / Pr[2], Pr[1] / Pr[2]
    k1, k2, p1, p2, k3 = calib.rgb.kc
    r2 = x * x + y * y
    rad = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
    xd = x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    u_exp = calib.rgb.fc[0] * xd + calib.rgb.cc[0]
    v_exp = calib.rgb.fc[1] * yd + calib.rgb.cc[1]
    # ~ (1139.3, 429.8): 0.3 m right, 0.2 m up at 2 m, shifted by the baseline.
    assert 1130 < u_exp < 1150 and 420 < v_exp < 440
    u, v, _ = project(ir_to_rgb(X[None], calib), calib.rgb)
    assert u[0] == pytest.approx(u_exp, abs=1e-6) and v[0] == pytest.approx(v_exp, abs=1e-6)
    # And the colour read is that pixel's.
    rgb = np.zeros((1080, 1920, 3), dtype=np.uint8)
    rgb[int(round(v_exp)), int(round(u_exp))] = (11, 22, 33)
    cols, keep = sample_colors(X[None].astype(np.float32), rgb, calib)
    assert keep.tolist() == [True] and cols.tolist() == [[11, 22, 33]]


def test_behind_and_outside_are_dropped(calib):
    pts = np.array(
        [
            [0.0, 0.0, 2.0],  # in view
            [0.0, 0.0, -1.0],  # behind
            [0.0, 0.0, 0.0],  # at the camera
            [5.0, 0.0, 1.0],  # far right: outside the image
            [0.0, -3.0, 1.0],  # far up: outside
        ],
        dtype=np.float32,
    )
    rgb = np.full((1080, 1920, 3), 7, dtype=np.uint8)
    cols, keep = sample_colors(pts, rgb, calib)
    assert keep.tolist() == [True, False, False, False, False]
    assert cols.shape == (1, 3)


def test_smaller_rgb_image_scales_intrinsics(calib):
    X = np.array([[0.30, -0.20, 2.00]], dtype=np.float32)
    u, v, _ = project(ir_to_rgb(X, calib), calib.rgb)
    rgb = np.zeros((270, 480, 3), dtype=np.uint8)
    us, vs = (u[0] + 0.5) / 4 - 0.5, (v[0] + 0.5) / 4 - 0.5
    rgb[int(np.floor(vs + 0.5)), int(np.floor(us + 0.5))] = (1, 2, 3)
    cols, keep = sample_colors(X, rgb, calib)
    assert keep[0] and cols.tolist() == [[1, 2, 3]]


def test_unmirror_calibration_matches_mirrored_images(calib):
    # Projecting the mirrored point with the mirrored calibration gives the mirrored pixel.
    m = unmirror_calibration(calib)
    X = np.array([[0.4, 0.1, 1.8]])
    Xm = X * np.array([-1.0, 1.0, 1.0])
    u, v, _ = project(ir_to_rgb(X, calib), calib.rgb)
    um, vm, _ = project(ir_to_rgb(Xm, m), m.rgb)
    assert um[0] == pytest.approx(calib.rgb.width - 1 - u[0], abs=1e-6)
    assert vm[0] == pytest.approx(v[0], abs=1e-6)
    twice = unmirror_calibration(m)
    assert np.allclose(twice.R, calib.R) and np.allclose(twice.rgb.cc, calib.rgb.cc)
