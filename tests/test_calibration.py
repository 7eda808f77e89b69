"""The Kinect v2 calibration of the THOR head (cameraParam/ pickles)."""

from __future__ import annotations

import pickle
import shutil
from pathlib import Path

import numpy as np
import pytest

from slamlab.datasets.calibration import load_kinect_calibration
from slamlab.errors import DataError


@pytest.mark.data
def test_real_calibration_values(shared_data: Path) -> None:
    cal = load_kinect_calibration(shared_data / "thor" / "cameraParam")
    # The values listed in data/thor/MANIFEST.md.
    np.testing.assert_allclose(cal.ir.fc, [364.457, 364.543], atol=1e-3)
    np.testing.assert_allclose(cal.ir.cc, [258.422, 202.487], atol=1e-3)
    assert (cal.ir.width, cal.ir.height) == (512, 424)
    np.testing.assert_allclose(cal.rgb.fc, [1049.332, 1051.318], atol=1e-3)
    np.testing.assert_allclose(cal.rgb.cc, [956.911, 533.452], atol=1e-3)
    assert (cal.rgb.width, cal.rgb.height) == (1920, 1080)
    assert cal.ir.kc.shape == (5,) and cal.ir.alpha_c == 0.0
    np.testing.assert_allclose(cal.R @ cal.R.T, np.eye(3), atol=1e-4)
    assert np.linalg.det(cal.R) > 0.999
    # T in millimetres: the RGB camera sits about 52 mm from the IR camera.
    np.testing.assert_allclose(cal.T_mm, [52.2682, 1.5192, -0.6059], atol=1e-4)


@pytest.fixture
def cal_copy(tmp_path: Path, shared_data: Path) -> Path:
    dst = tmp_path / "cameraParam"
    shutil.copytree(shared_data / "thor" / "cameraParam", dst)
    return dst


def _rewrite(path: Path, **changes: object) -> None:
    with path.open("rb") as f:
        d = pickle.load(f, encoding="latin1")
    for k, v in changes.items():
        if v is None:
            d.pop(k)
        else:
            d[k] = v
    with path.open("wb") as f:
        pickle.dump(d, f)


@pytest.mark.data
def test_bad_calibration_files(cal_copy: Path) -> None:
    with pytest.raises(DataError, match="calibration folder not found"):
        load_kinect_calibration(cal_copy / "nope")
    ir = cal_copy / "IRcam_Calib_result.pkl"
    _rewrite(ir, fc=None)
    with pytest.raises(DataError, match=r"IRcam_Calib_result.pkl, field 'fc': missing"):
        load_kinect_calibration(cal_copy)
    _rewrite(ir, fc=[364.0, -1.0])
    with pytest.raises(DataError, match=r"field 'fc'.*positive"):
        load_kinect_calibration(cal_copy)
    _rewrite(ir, fc=[364.0, 364.0], im_size=[512])
    with pytest.raises(DataError, match=r"field 'im_size'"):
        load_kinect_calibration(cal_copy)
    ir.write_bytes(b"\x80\x02truncated")
    with pytest.raises(DataError, match=r"IRcam_Calib_result.pkl: cannot read calibration pickle"):
        load_kinect_calibration(cal_copy)
    ex = cal_copy / "exParams.pkl"
    _rewrite(ex, R=np.ones((3, 3)))
    with pytest.raises(DataError, match=r"exParams.pkl, field 'R': is not a rotation"):
        load_kinect_calibration(cal_copy)
    ex.unlink()
    with pytest.raises(DataError, match=r"exParams.pkl: calibration file is missing"):
        load_kinect_calibration(cal_copy)
