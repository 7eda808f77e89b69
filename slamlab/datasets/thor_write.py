"""Write THOR-OP logs in the exact MATLAB layout of the course files (see THOR_FORMAT.md).

The simulator writes its sequences with these functions and the tests use them to build
small logs; what they write must read back identically through a user's own course-style
loader, i.e. plain `scipy.io.loadmat` indexing:

- lidar  `loadmat(f)['lidar'][0][i][0][0]` is record i, a 1x1 struct read BY POSITION:
  `t` (1x1 double, Unix s), [optional extra field], `pose` (1x3 [x m, y m, theta rad]),
  `res` (1x1 rad), `rpy` (1x3 rad), `scan` (1x1081 single, m).
  UCSD variant: `t`, `scan`, `delta_pose` (1x3, odometry change since the previous record).
- joint  top-level `ts` 1xM, `head_angles` 2xM, `rpy`/`acc`/`gyro` 3xM, `pos` 35xM,
  `ft_l`/`ft_r` 6xM: time along axis 1.
- Kinect `loadmat(f)['DEPTH'][0][k][0][0]` / `['RGB'][0][k][0][0]` is frame k, a 1x1 struct
  with the 16 fields `t, width, imu_rpy, id, odom, head_angles, c, sz, vel, rsz,
  body_height, tr, bpp, name, height` then `depth` (HxW uint16 mm) / `image` (HxWx3 uint8),
  images stored mirrored left-right as the real Kinect files are.

Files are written to a temporary name and renamed into place, so a crash never leaves a
half-written .mat behind. Arrays are validated for shape; values are NOT validated (tests
write deliberately bad logs: non-monotonic time, NaN ranges, ...).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.io

from slamlab.io.atomic import atomic_path

__all__ = [
    "DepthRecord",
    "RGBRecord",
    "KINECT_FIELDS",
    "write_lidar_mat",
    "write_joint_mat",
    "write_depth_mat",
    "write_rgb_mats",
    "write_struct_cell",
]

# The 15 metadata fields of a Kinect record, in file order; the 16th is `depth` or `image`.
KINECT_FIELDS = (
    "t", "width", "imu_rpy", "id", "odom", "head_angles", "c", "sz", "vel", "rsz",
    "body_height", "tr", "bpp", "name", "height",
)  # fmt: skip

DEFAULT_RES_RAD = 0.0044  # what the THOR files store (0.25 deg rounded to 4 decimals)
JOINT_POS_ROWS = 35
_HEADER_TEXT = b"MATLAB 5.0 MAT-file, Platform: posix, Created by: slamlab.datasets.thor_write"
FT_ROWS = 6


@dataclass
class DepthRecord:
    """One Kinect depth frame to write.

    `t` Unix time (s); `depth_mm` (H, W) uint16 millimetres, UN-mirrored (as a person sees
    it; the writer mirrors it); `imu_rpy` (3,) rad; `odom` (3,) (x m, y m, theta rad);
    `head_angles` (2,) (neck yaw, head pitch) rad; `body_height` (m).
    """

    t: float
    depth_mm: np.ndarray
    imu_rpy: np.ndarray
    odom: np.ndarray
    head_angles: np.ndarray
    body_height: float = 0.93


@dataclass
class RGBRecord:
    """One Kinect colour frame to write: like DepthRecord, with `image` (H, W, 3) uint8
    UN-mirrored (the writer mirrors it)."""

    t: float
    image: np.ndarray
    imu_rpy: np.ndarray
    odom: np.ndarray
    head_angles: np.ndarray
    body_height: float = 0.93


def _row(x: object, n: int, name: str, dtype: type = np.float64) -> np.ndarray:
    """A 1xn MATLAB row vector (what loadmat returns for a MATLAB row)."""
    a = np.asarray(x, dtype=dtype).reshape(-1)
    if a.size != n:
        raise ValueError(f"{name}: expected {n} values, got {a.size}")
    return a.reshape(1, n)


def _scalar(x: float, dtype: type = np.float64) -> np.ndarray:
    return np.array([[x]], dtype=dtype)


def _atomic_savemat(path: str | Path, variables: Mapping[str, object]) -> Path:
    """savemat to `path` via a temporary file + rename (no half-written file on failure)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp, tmp.open("w+b") as f:  # a file object: savemat must not append '.mat'
        scipy.io.savemat(f, dict(variables), format="5", oned_as="row")
        # scipy stamps the wall-clock time into the header text: a fixed text makes the
        # same arrays give byte-identical files (reproducible data fingerprints).
        f.seek(0)
        f.write(_HEADER_TEXT.ljust(116, b" ")[:116])
    return path


def write_struct_cell(path: str | Path, varname: str, records: Sequence[Mapping[str, np.ndarray]]) -> Path:
    """Write `records` as a 1xN MATLAB cell of 1x1 structs named `varname`.

    Each record is an ordered mapping field name -> value (field order = file order). All
    records must have the same field names. This is the building block of the lidar and
    Kinect writers; tests use it directly to write malformed logs (4 or 7 fields, ...).
    """
    cell = np.empty((1, len(records)), dtype=object)
    for i, rec in enumerate(records):
        names = list(rec.keys())
        struct = np.empty((1, 1), dtype=[(n, object) for n in names])
        struct[0, 0] = tuple(rec[n] for n in names)
        cell[0, i] = struct
    return _atomic_savemat(path, {varname: cell})


def write_lidar_mat(
    path: str | Path,
    t: np.ndarray,
    pose: np.ndarray,
    rpy: np.ndarray,
    scans: np.ndarray,
    res: float = DEFAULT_RES_RAD,
    extra_field: bool = False,
    ucsd_delta_pose: bool = False,
) -> None:
    """Write a lidar log `train_lidarK.mat` (variable `lidar`).

    t: (N,) absolute Unix times (s, float64). pose: (N, 3) global odometry (x m, y m,
    theta rad). rpy: (N, 3) IMU roll, pitch, yaw (rad). scans: (N, B) ranges (m), stored
    as single (B = 1081 for the real Hokuyo: -135..+135 deg). res: angular step (rad).

    extra_field: insert a 6th field `id` (1-based record counter) after `t`, as some years'
    files have (readers must then use the last four fields by position).
    ucsd_delta_pose: write the UCSD variant instead: fields `t`, `scan`, `delta_pose`, where
    delta_pose[i] = pose[i] - pose[i-1] (componentwise, theta wrapped to [-pi, pi)) and
    delta_pose[0] = pose[0], so that a cumulative sum gives the global odometry back.
    """
    t = np.asarray(t, dtype=np.float64).reshape(-1)
    n = t.size
    pose = np.asarray(pose, dtype=np.float64).reshape(n, 3)
    rpy = np.asarray(rpy, dtype=np.float64).reshape(n, 3)
    scans = np.asarray(scans, dtype=np.float32)
    if scans.ndim != 2 or scans.shape[0] != n:
        raise ValueError(f"scans: expected shape ({n}, B), got {scans.shape}")
    records: list[dict[str, np.ndarray]] = []
    if ucsd_delta_pose:
        delta = np.diff(pose, axis=0, prepend=np.zeros((1, 3)))
        delta[:, 2] = (delta[:, 2] + np.pi) % (2 * np.pi) - np.pi
        for i in range(n):
            records.append({"t": _scalar(t[i]), "scan": scans[i : i + 1], "delta_pose": delta[i : i + 1]})
    else:
        for i in range(n):
            rec = {"t": _scalar(t[i])}
            if extra_field:
                rec["id"] = _scalar(i + 1)
            rec["pose"] = pose[i : i + 1]
            rec["res"] = _scalar(res)
            rec["rpy"] = rpy[i : i + 1]
            rec["scan"] = scans[i : i + 1]
            records.append(rec)
    write_struct_cell(path, "lidar", records)


def write_joint_mat(
    path: str | Path,
    ts: np.ndarray,
    head_angles: np.ndarray,
    rpy: np.ndarray,
    acc: np.ndarray | None = None,
    gyro: np.ndarray | None = None,
    pos: np.ndarray | None = None,
    ft_l: np.ndarray | None = None,
    ft_r: np.ndarray | None = None,
) -> None:
    """Write a joint log `train_jointK.mat`: top-level variables, time along axis 1.

    ts: (M,) absolute Unix times (s). head_angles: (2, M) row 0 neck yaw, row 1 head pitch
    (rad). rpy: (3, M) IMU roll, pitch, yaw (rad). acc (3, M), gyro (3, M), pos (35, M)
    joint positions, ft_l / ft_r (6, M) force/torque: zeros of that shape when None.
    """
    ts = np.asarray(ts, dtype=np.float64).reshape(1, -1)
    m = ts.shape[1]

    def block(x: np.ndarray | None, rows: int, name: str) -> np.ndarray:
        if x is None:
            return np.zeros((rows, m))
        a = np.asarray(x, dtype=np.float64)
        if a.shape != (rows, m):
            raise ValueError(f"{name}: expected shape ({rows}, {m}), got {a.shape}")
        return a

    pos_rows = JOINT_POS_ROWS if pos is None else np.asarray(pos).shape[0]  # 35 or 37
    _atomic_savemat(
        path,
        {
            "ts": ts,
            "head_angles": block(head_angles, 2, "head_angles"),
            "rpy": block(rpy, 3, "rpy"),
            "acc": block(acc, 3, "acc"),
            "gyro": block(gyro, 3, "gyro"),
            "pos": block(pos, pos_rows, "pos"),
            "ft_l": block(ft_l, FT_ROWS, "ft_l"),
            "ft_r": block(ft_r, FT_ROWS, "ft_r"),
        },
    )


def _kinect_record(rec: DepthRecord | RGBRecord, frame_id: int) -> dict[str, np.ndarray]:
    """The 16 fields of one Kinect struct, image mirrored left-right as the real files."""
    if isinstance(rec, DepthRecord):
        img = np.asarray(rec.depth_mm)
        if img.ndim != 2:
            raise ValueError(f"depth_mm: expected (H, W), got {img.shape}")
        img = np.ascontiguousarray(np.flip(img.astype(np.uint16, copy=False), 1))
        data_name, bpp, name = "depth", 2, "depth"
    else:
        img = np.asarray(rec.image)
        if img.ndim != 3 or img.shape[2] != 3:
            raise ValueError(f"image: expected (H, W, 3), got {img.shape}")
        img = np.ascontiguousarray(np.flip(img.astype(np.uint8, copy=False), 1))
        data_name, bpp, name = "image", 3, "rgb"
    h, w = img.shape[:2]
    nbytes = float(img.nbytes)
    fields = {
        "t": _scalar(rec.t),
        "width": _scalar(w),
        "imu_rpy": _row(rec.imu_rpy, 3, "imu_rpy"),
        "id": _scalar(frame_id),
        "odom": _row(rec.odom, 3, "odom"),
        "head_angles": _row(rec.head_angles, 2, "head_angles"),
        "c": np.array(["raw"]),  # compression tag: frames are stored uncompressed
        "sz": _scalar(nbytes),
        "vel": np.zeros((1, 3)),
        "rsz": _scalar(nbytes),
        "body_height": _scalar(rec.body_height),
        "tr": np.zeros((1, 3)),
        "bpp": _scalar(bpp),
        "name": np.array([name]),
        "height": _scalar(h),
        data_name: img,
    }
    return fields


def write_depth_mat(path: str | Path, frames: Iterable[DepthRecord]) -> None:
    """Write `DEPTH_K.mat` (variable `DEPTH`): all depth frames in one file, in the given
    order (the real files are time-ordered). Holds all frames in memory while writing."""
    records = [_kinect_record(r, k + 1) for k, r in enumerate(frames)]
    write_struct_cell(path, "DEPTH", records)


def write_rgb_mats(folder: str | Path, seq: int, frames: Iterable[RGBRecord], frames_per_file: int = 300) -> list[Path]:
    """Write colour frames as `RGB_{seq}_{j}.mat` (variable `RGB`), j = 1, 2, ..., each
    holding `frames_per_file` consecutive frames (the last one the remainder).

    `frames` is consumed lazily: at most one file's worth of frames is held in memory.
    Returns the paths written, in j order.
    """
    if frames_per_file < 1:
        raise ValueError("frames_per_file must be >= 1")
    folder = Path(folder)
    paths: list[Path] = []
    batch: list[dict[str, np.ndarray]] = []
    frame_id = 0
    for rec in frames:
        frame_id += 1
        batch.append(_kinect_record(rec, frame_id))
        if len(batch) == frames_per_file:
            paths.append(write_struct_cell(folder / f"RGB_{seq}_{len(paths) + 1}.mat", "RGB", batch))
            batch = []
    if batch:
        paths.append(write_struct_cell(folder / f"RGB_{seq}_{len(paths) + 1}.mat", "RGB", batch))
    return paths
