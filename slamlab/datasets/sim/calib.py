"""Kinect v2 calibration used by the simulator: the real THOR head camera numbers, scaled.

The numbers are copied from the course's `cameraParam/*.pkl` (see data/thor/MANIFEST.md) so
that simulated RGB-D frames have the real geometry (focal lengths, principal points, the
52 mm IR-to-RGB baseline) without the simulator depending on the data files.

The simulator renders an ideal pinhole camera, so the pickles it writes beside a generated
sequence carry zero distortion (`kc`): a texture mapper that undistorts with them is then
exactly consistent with the rendered images.
"""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np

from slamlab.datasets.calibration import EXTRINSICS_FILE, IR_FILE, RGB_FILE, load_kinect_calibration
from slamlab.frames import CameraIntrinsics, KinectCalibration

# Real values (IRcam_Calib_result.pkl, RGBcamera_Calib_result.pkl, exParams.pkl).
IR_FC = (364.4573624856433, 364.5428106269892)
IR_CC = (258.4224875619147, 202.487139940006)
IR_SIZE = (512, 424)  # width, height px
RGB_FC = (1049.3317526048313, 1051.3184762853225)
RGB_CC = (956.9105164280157, 533.4520324414847)
RGB_SIZE = (1920, 1080)
EXT_R = (
    (0.9999685510087598, 0.005899814450951683, 0.005299922913181838),
    (-0.005894063933535813, 0.9999820248613468, -0.0010999838853508743),
    (-0.0053063173471552295, 0.0010687112074741943, 0.9999853503189765),
)
EXT_T_MM = (52.2682, 1.5192, -0.6059)  # P_rgb = R @ P_ir + T (mm)


def _scale(cam: CameraIntrinsics, scale: float) -> CameraIntrinsics:
    """Intrinsics of the same camera with the image resized by `scale`.

    Pixel centres are kept consistent: a pixel u in the full image maps to (u + 0.5) s - 0.5.
    """
    w = max(1, int(round(cam.width * scale)))
    h = max(1, int(round(cam.height * scale)))
    sx, sy = w / cam.width, h / cam.height
    return CameraIntrinsics(
        fc=np.array([cam.fc[0] * sx, cam.fc[1] * sy]),
        cc=np.array([(cam.cc[0] + 0.5) * sx - 0.5, (cam.cc[1] + 0.5) * sy - 0.5]),
        kc=np.zeros(5),  # the renderer is an ideal pinhole
        alpha_c=0.0,
        width=w,
        height=h,
    )


def default_calibration() -> KinectCalibration:
    """The real THOR Kinect v2 calibration at full resolution (distortion as calibrated)."""
    ir = CameraIntrinsics(np.array(IR_FC), np.array(IR_CC), np.zeros(5), 0.0, *IR_SIZE)
    rgb = CameraIntrinsics(np.array(RGB_FC), np.array(RGB_CC), np.zeros(5), 0.0, *RGB_SIZE)
    return KinectCalibration(ir=ir, rgb=rgb, R=np.array(EXT_R, dtype=np.float64), T_mm=np.array(EXT_T_MM))


def sim_calibration(kinect_scale: float, calibration_dir: str | Path | None = None) -> KinectCalibration:
    """The calibration the simulator renders with: real (or `calibration_dir`) numbers, images
    resized by `kinect_scale` (1.0 = 512x424 depth, 1920x1080 RGB), zero distortion."""
    base = load_kinect_calibration(calibration_dir) if calibration_dir is not None else default_calibration()
    return KinectCalibration(
        ir=_scale(base.ir, kinect_scale),
        rgb=_scale(base.rgb, kinect_scale),
        R=np.asarray(base.R, dtype=np.float64),
        T_mm=np.asarray(base.T_mm, dtype=np.float64).reshape(3),
    )


def _intrinsics_dict(cam: CameraIntrinsics) -> dict:
    # Same keys and plain-list values as the real pickles, so course code reads them unchanged.
    return {
        "fc": [float(v) for v in cam.fc],
        "cc": [float(v) for v in cam.cc],
        "kc": [float(v) for v in cam.kc],
        "alpha_c": float(cam.alpha_c),
        "im_size": [int(cam.width), int(cam.height)],
        "fc_err": [0.0, 0.0],
        "cc_err": [0.0, 0.0],
        "kc_err": [0.0] * 5,
        "alpha_c_err": 0.0,
    }


def write_camera_params(folder: str | Path, calib: KinectCalibration) -> Path:
    """Write `cameraParam/`-style pickles (real keys; exParams with R 3x3, T 3x1 mm) into
    `folder` and return it. Protocol 2 keeps them readable by the course's Python 2 code."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    with (folder / IR_FILE).open("wb") as f:
        pickle.dump(_intrinsics_dict(calib.ir), f, protocol=2)
    with (folder / RGB_FILE).open("wb") as f:
        pickle.dump(_intrinsics_dict(calib.rgb), f, protocol=2)
    with (folder / EXTRINSICS_FILE).open("wb") as f:
        pickle.dump({"R": np.asarray(calib.R, dtype=np.float64), "T": np.asarray(calib.T_mm, dtype=np.float64).reshape(3, 1)}, f, protocol=2)
    (folder / "note4exParam.txt").write_text(
        "Simulated THOR Kinect v2 (slamlab.datasets.sim): ideal pinhole, images scaled from the real calibration.\n"
        "P_rgb = R*P_depth+T, T in mm.\n"
    )
    return folder
