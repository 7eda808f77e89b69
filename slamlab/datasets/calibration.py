"""The Kinect v2 calibration of the THOR head camera (`cameraParam/` folder, pickles)."""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np

from slamlab.errors import DataError
from slamlab.frames import CameraIntrinsics, KinectCalibration

IR_FILE = "IRcam_Calib_result.pkl"
RGB_FILE = "RGBcamera_Calib_result.pkl"
EXTRINSICS_FILE = "exParams.pkl"


# What a calibration pickle may build: numpy arrays, dtypes and scalars (as numpy 1 and 2
# name them) and the bytes codec Python 3 uses for protocol-2 byte strings. Anything else
# (os.system, builtins.eval, ...) would run code from the file: refused.
_ALLOWED_GLOBALS = frozenset({
    ("numpy", "ndarray"), ("numpy", "dtype"),
    ("numpy.core.multiarray", "_reconstruct"), ("numpy._core.multiarray", "_reconstruct"),
    ("numpy.core.multiarray", "scalar"), ("numpy._core.multiarray", "scalar"),
    ("numpy.core.numeric", "_frombuffer"), ("numpy._core.numeric", "_frombuffer"),
    ("_codecs", "encode"),
})


class _CalibrationUnpickler(pickle.Unpickler):
    """Unpickles numbers, strings, lists, tuples, dicts and numpy arrays, nothing else."""

    def find_class(self, module: str, name: str) -> object:
        if (module, name) not in _ALLOWED_GLOBALS:
            raise _ForbiddenObject(f"{module}.{name}")
        return super().find_class(module, name)


class _ForbiddenObject(pickle.UnpicklingError):
    """A pickle names a class or function outside the allowed set."""


def _plain_data(obj: object) -> bool:
    """Only numbers, strings, arrays of numbers, and dicts / lists / tuples of those."""
    if isinstance(obj, dict):
        return all(isinstance(k, str) and _plain_data(v) for k, v in obj.items())
    if isinstance(obj, (list, tuple)):
        return all(_plain_data(v) for v in obj)
    if isinstance(obj, np.ndarray):
        return obj.dtype.kind in "biufc"
    return obj is None or isinstance(obj, (bool, int, float, complex, str, bytes, np.number, np.bool_))


def _load_pickle(path: Path) -> dict:
    """A calibration pickle, read with an unpickler that cannot run code from the file."""
    if not path.is_file():
        raise DataError(path, "calibration file is missing")
    try:
        with path.open("rb") as f:
            # exParams.pkl is a Python 2 pickle of numpy arrays: latin1 reads it.
            obj = _CalibrationUnpickler(f, encoding="latin1").load()
    except _ForbiddenObject as exc:
        raise DataError(path, f"holds a Python object '{exc}', not only numbers, arrays, dicts and lists; "
                        "not loaded (a pickle can run code when loaded)") from None  # fmt: skip
    except Exception as exc:  # truncated or not a pickle
        raise DataError(path, f"cannot read calibration pickle ({exc.__class__.__name__}: {exc})") from None
    if not isinstance(obj, dict):
        raise DataError(path, f"expected a dict, got {type(obj).__name__}")
    if not _plain_data(obj):
        raise DataError(path, "holds values other than numbers, arrays, dicts and lists; not loaded")
    return obj


def _field(d: dict, path: Path, name: str, size: int) -> np.ndarray:
    if name not in d:
        raise DataError(path, "missing", field=name)
    arr = np.asarray(d[name], dtype=np.float64).reshape(-1)
    if arr.size != size or not np.all(np.isfinite(arr)):
        raise DataError(path, f"expected {size} finite numbers, got {arr.size}", field=name)
    return arr


def _intrinsics(path: Path) -> CameraIntrinsics:
    """One camera (Bouguet toolbox result): fc, cc px; kc (5,); alpha_c; im_size [W, H] px."""
    d = _load_pickle(path)
    kc = _field(d, path, "kc", 5)
    size = _field(d, path, "im_size", 2)
    if np.any(size < 1) or np.any(size != np.round(size)):
        raise DataError(path, f"expected a positive [width, height] in pixels, got {size}", field="im_size")
    fc = _field(d, path, "fc", 2)
    if np.any(fc <= 0):
        raise DataError(path, f"focal lengths must be positive, got {fc}", field="fc")
    alpha_c = _field(d, path, "alpha_c", 1)[0] if "alpha_c" in d else 0.0  # skew; 0 for the Kinect
    return CameraIntrinsics(
        fc=fc,
        cc=_field(d, path, "cc", 2),
        kc=kc,
        alpha_c=float(alpha_c),
        width=int(size[0]),
        height=int(size[1]),
    )


def load_kinect_calibration(folder: str | Path) -> KinectCalibration:
    """Read `IRcam_Calib_result.pkl`, `RGBcamera_Calib_result.pkl` and `exParams.pkl` from
    `folder` (the course's `cameraParam/`). Extrinsics: `P_rgb = R @ P_ir + T`, T in mm.
    Raises DataError naming the file and field for a missing/corrupt pickle or bad values."""
    folder = Path(folder)
    if not folder.is_dir():
        raise DataError(folder, "calibration folder not found")
    ext_path = folder / EXTRINSICS_FILE
    ext = _load_pickle(ext_path)
    R = _field(ext, ext_path, "R", 9).reshape(3, 3)
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-3):
        raise DataError(ext_path, "is not a rotation matrix", field="R")
    return KinectCalibration(
        ir=_intrinsics(folder / IR_FILE),
        rgb=_intrinsics(folder / RGB_FILE),
        R=R,
        T_mm=_field(ext, ext_path, "T", 3),
    )

