"""Read a THOR-OP log (lidar + joint files, optional Kinect RGB-D) into a `Sequence`.

The files are the UPenn ESE 650 course's MATLAB files, read exactly as THOR_FORMAT.md says:

- `train_lidarK.mat`: `loadmat(f)['lidar'][0][i][0][0]` is record i, a struct read BY
  POSITION because field names vary between years: 5 or 6 fields, the first is `t` and the
  last four are `pose, res, rpy, scan`. The UCSD variant has 3 fields `t, scan, delta_pose`;
  its odometry is the running sum of `delta_pose`.
- `train_jointK.mat`: top-level `ts` (1xM) and `head_angles` (2xM), time along axis 1; each
  scan takes the joint sample nearest in time.

Choices (why):
- Body roll/pitch come from the lidar record's own `rpy` (the IMU sampled with the scan, as
  the course code uses it); only the UCSD variant, which has no `rpy`, falls back to the
  joint file's `rpy` at the nearest joint time (0 if the joint file has none either).
- Beam angles are centred on 0 with `res` steps. The files store `res` rounded to 0.0044 rad,
  which over 1080 steps would span 272.2 deg instead of 270 deg (a 1.1 deg error at the
  edges); when `res` is the rounded 0.25 deg, the exact 270 deg / 1080 step is used.
- Ranges are kept as the float32 the file holds; NaN/inf are replaced by 0 and marked
  invalid (one warning with the count), so downstream arithmetic never meets NaN.
- Times must not decrease: THOR clocks are monotonic, so a step back means a corrupt or
  concatenated file, and the record index is reported.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import scipy.io

from slamlab import robot
from slamlab.datasets.calibration import load_kinect_calibration
from slamlab.datasets.stamps import nearest_index
from slamlab.errors import DataError
from slamlab.frames import KinectCalibration, LazyScans, ScanFrame, Sequence
from slamlab.heap import release_freed_memory
from slamlab.geometry import wrap_angle
from slamlab.config.datasets import ThorDatasetConfig

__all__ = ["load_thor", "read_lidar_mat", "read_joint_mat", "beam_angles", "LidarLog", "JointLog"]

N_BEAMS = 1081  # Hokuyo UTM-30LX: -135..+135 deg in 0.25 deg steps
FOV_RAD = np.deg2rad(270.0)
MIN_RANGE_M = 0.1
MAX_RANGE_M = 30.0
MAX_JOINT_GAP_S = 0.5  # a scan whose nearest joint sample is further away is suspicious
CALIBRATION_SUBDIR = "cameraParam"


# --------------------------------------------------------------------------- .mat access


def loadmat_checked(path: Path, cell_var: str | None = None, variable_names: list[str] | None = None) -> dict:
    """`scipy.io.loadmat` with user-facing errors for missing, truncated or v7.3 files;
    for a damaged file holding cell variable `cell_var`, the error names the first bad record.
    `variable_names`: read only these (a variable the file lacks is then not in the dict)."""
    if not path.is_file():
        raise DataError(path, "file not found")
    try:
        return scipy.io.loadmat(path, variable_names=variable_names)
    except NotImplementedError:  # scipy's message for HDF5-based MAT v7.3 files
        raise DataError(path, "MATLAB v7.3 (HDF5) files are not supported: re-save with save(..., '-v7')") from None
    except Exception as exc:  # noqa: BLE001 - scipy raises many types for corrupt files
        record = _locate_damage(path, cell_var) if cell_var else None
        raise DataError(path, f"cannot read .mat file, truncated or corrupt ({exc.__class__.__name__}: {exc})", record=record) from None


def _locate_damage(path: Path, varname: str) -> str | None:
    """The first unreadable record of a damaged cell variable, found by streaming it."""
    from slamlab.datasets.thor_rgbd import iter_struct_cell

    try:
        for _ in iter_struct_cell(path, varname):
            pass
    except DataError as err:
        return None if err.record is None else str(err.record).replace("frame", "record")
    return None


def _numbers(value: object, path: Path, record: str, field: str, size: int | None = None) -> np.ndarray:
    """A struct field as a flat float64 array, with its size checked."""
    try:
        arr = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise DataError(path, f"expected numbers, got {type(value).__name__}", record=record, field=field) from None
    if size is not None and arr.size != size:
        raise DataError(path, f"expected {size} values, got {arr.size} (shape {np.shape(value)})", record=record, field=field)
    return arr


def _check_times(t: np.ndarray, path: Path, what: str, field: str) -> None:
    """Times must be finite and never step back (THOR clocks are monotonic)."""
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise DataError(path, f"time is {t[bad[0]]}", record=f"{what} {bad[0]}", field=field)
    back = np.flatnonzero(np.diff(t) < 0)
    if back.size:
        i = int(back[0]) + 1
        raise DataError(
            path,
            f"time steps back from {t[i - 1]:.6f} to {t[i]:.6f} s (THOR clocks are monotonic)",
            record=f"{what} {i}",
            field=field,
        )


# --------------------------------------------------------------------------- lidar


class LidarLog:
    """The lidar file as arrays. t (N,) Unix s; odom (N, 3) (x m, y m, theta rad);
    res (N,) rad; rpy (N, 3) rad or None (UCSD variant); scans (N, 1081) float32 m."""

    def __init__(self, t: np.ndarray, odom: np.ndarray, res: np.ndarray, rpy: np.ndarray | None, scans: np.ndarray):
        self.t, self.odom, self.res, self.rpy, self.scans = t, odom, res, rpy, scans

    def __len__(self) -> int:
        return int(self.t.size)


def _record_struct(cell_item: object, path: Path, record: str) -> np.void:
    """`lidar[0][i][0][0]`: the 1x1 struct of one record."""
    try:
        rec = cell_item[0][0]  # type: ignore[index]
    except (IndexError, TypeError):
        raise DataError(path, "is not a 1x1 struct", record=record) from None
    if not isinstance(rec, np.void) or rec.dtype.names is None:
        raise DataError(path, f"is not a struct (got {type(rec).__name__})", record=record)
    return rec


def read_lidar_mat(path: str | Path) -> LidarLog:
    """Read `train_lidarK.mat` (5/6-field records, or the 3-field UCSD variant).

    Raises DataError naming the file, the record ("record 17") and the field on a missing
    `lidar` variable, wrong field counts (only 3, 5 or 6 are THOR layouts), scans that are
    not 1081 ranges, bad `res`, empty logs and times that step back.
    """
    path = Path(path)
    mat = loadmat_checked(path, cell_var="lidar")
    if "lidar" not in mat:
        found = sorted(k for k in mat if not k.startswith("__"))
        raise DataError(path, f"variable missing (found: {found})", field="lidar")
    cell = mat["lidar"]
    if not isinstance(cell, np.ndarray) or cell.dtype != object:
        raise DataError(path, f"expected a 1xN cell array, got {getattr(cell, 'dtype', type(cell))}", field="lidar")
    # each record is let go of once read (below): the file's records (~190 MB of arrays and
    # objects for the hard simulated world's 27,560 scans) and the scans copied out of them
    # are then not both held at once
    items = list(cell.reshape(-1))
    del mat, cell
    n = len(items)
    if n == 0:
        raise DataError(path, "log is empty (0 records)", field="lidar")

    t = np.empty(n)
    odom = np.empty((n, 3))
    res = np.empty(n)
    rpy = np.empty((n, 3))
    scans = np.empty((n, N_BEAMS), dtype=np.float32)
    ucsd: bool | None = None
    for i in range(n):
        rid = f"record {i}"
        rec = _record_struct(items[i], path, rid)
        items[i] = None
        names = rec.dtype.names
        nf = len(names)
        if nf in (5, 6):
            is_ucsd = False
            pos = {"t": 0, "pose": nf - 4, "res": nf - 3, "rpy": nf - 2, "scan": nf - 1}
        elif nf == 3:
            is_ucsd = True
            # UCSD: t, scan, delta_pose; trust the names if they are there, else the order.
            pos = {k: names.index(k) for k in ("t", "scan", "delta_pose")} if set(names) >= {"t", "scan", "delta_pose"} else {"t": 0, "scan": 1, "delta_pose": 2}
        else:
            raise DataError(
                path,
                f"has {nf} fields {list(names)}; expected 5 or 6 (t, [extra], pose, res, rpy, scan) or 3 (t, scan, delta_pose)",
                record=rid,
            )
        if ucsd is None:
            ucsd = is_ucsd
        elif ucsd != is_ucsd:
            raise DataError(path, f"has {nf} fields but record 0 has a different layout", record=rid)

        def get(key: str, size: int) -> np.ndarray:
            p = pos[key]  # errors name the field as the file spells it
            return _numbers(rec[p], path, rid, names[p], size)

        t[i] = get("t", 1)[0]
        scan = rec[pos["scan"]]
        if np.size(scan) != N_BEAMS:
            raise DataError(path, f"expected {N_BEAMS} ranges, got shape {np.shape(scan)}", record=rid, field=names[pos["scan"]])
        scans[i] = np.asarray(scan).reshape(-1)  # float32 'single' kept exactly
        if is_ucsd:
            odom[i] = get("delta_pose", 3)
        else:
            odom[i] = get("pose", 3)
            res[i] = get("res", 1)[0]
            rpy[i] = get("rpy", 3)
    _check_times(t, path, "record", "t")
    # checked before the UCSD running sum, where one NaN would spoil every later pose
    pose_field = "delta_pose" if ucsd else "pose"
    bad_odom = np.flatnonzero(~np.all(np.isfinite(odom), axis=1))
    if bad_odom.size:
        raise DataError(path, f"{pose_field} is {odom[bad_odom[0]]}", record=f"record {bad_odom[0]}", field=pose_field)
    if ucsd:
        # Global odometry = running sum of the per-record changes (the writer stores
        # delta_pose[0] = first pose), theta wrapped to [-pi, pi).
        odom = np.cumsum(odom, axis=0)
        odom[:, 2] = wrap_angle(odom[:, 2])
        res[:] = FOV_RAD / (N_BEAMS - 1)
        return LidarLog(t, odom, res, None, scans)
    bad_res = np.flatnonzero(~(np.isfinite(res) & (res > 0) & (res * (N_BEAMS - 1) <= 2 * np.pi)))
    if bad_res.size:
        raise DataError(path, f"angular resolution {res[bad_res[0]]} rad is impossible", record=f"record {bad_res[0]}", field="res")
    return LidarLog(t, odom, res, rpy, scans)


def beam_angles(res_rad: float, n: int = N_BEAMS) -> np.ndarray:
    """(n,) float32 beam angles (rad), centred on 0, CCW from the lidar's +x.

    If `res_rad` is the 4-decimal rounding of an exact 270 deg / (n - 1) step (THOR stores
    0.0044 for 0.25 deg), the exact step is used: rounding would skew the edge beams by 1 deg.
    """
    exact = FOV_RAD / (n - 1)
    step = exact if abs(res_rad - exact) <= 5e-5 else float(res_rad)
    angles = ((np.arange(n) - (n - 1) / 2.0) * step).astype(np.float32)
    angles.flags.writeable = False  # shared by every frame of the log
    return angles


# --------------------------------------------------------------------------- joint


class JointLog:
    """The joint file as arrays: ts (M,) Unix s; head_angles (2, M) rad (neck yaw, head
    pitch); rpy (3, M) rad or None when the file has none."""

    def __init__(self, ts: np.ndarray, head_angles: np.ndarray, rpy: np.ndarray | None):
        self.ts, self.head_angles, self.rpy = ts, head_angles, rpy

    def nearest(self, t: np.ndarray) -> np.ndarray:
        """Index of the joint sample nearest in time to each t (vectorised)."""
        return nearest_index(self.ts, t)


def read_joint_mat(path: str | Path) -> JointLog:
    """Read `train_jointK.mat`: `ts` 1xM, `head_angles` 2xM (required), `rpy` 3xM (optional)."""
    path = Path(path)
    # only what is used: a THOR joint file also holds every joint's position, the IMU's rates
    # and the feet's forces (32 MB for the hard simulated world, 3 MB of them read)
    mat = loadmat_checked(path, variable_names=["ts", "head_angles", "rpy"])
    for key in ("ts", "head_angles"):
        if key not in mat:
            found = sorted(name for name, _, _ in scipy.io.whosmat(path))
            raise DataError(path, f"variable missing (found: {found})", field=key)
    ts = np.asarray(mat["ts"], dtype=np.float64)
    if ts.ndim != 2 or ts.shape[0] != 1:
        raise DataError(path, f"expected 1xM times, got shape {ts.shape}", field="ts")
    ts = ts.reshape(-1)
    m = ts.size
    if m == 0:
        raise DataError(path, "log is empty (0 samples)", field="ts")
    head = np.asarray(mat["head_angles"], dtype=np.float64)
    if head.shape != (2, m):
        raise DataError(path, f"expected 2x{m} (neck yaw, head pitch) x time, got shape {head.shape}", field="head_angles")
    _check_times(ts, path, "sample", "ts")
    bad = np.flatnonzero(~np.all(np.isfinite(head), axis=0))
    if bad.size:
        raise DataError(path, f"angles are {head[:, bad[0]]}", record=f"sample {bad[0]}", field="head_angles")
    rpy = None
    if "rpy" in mat:
        rpy = np.asarray(mat["rpy"], dtype=np.float64)
        if rpy.shape != (3, m):
            raise DataError(path, f"expected 3x{m}, got shape {rpy.shape}", field="rpy")
    return JointLog(ts, head, rpy)


# --------------------------------------------------------------------------- sequence


def _resolve(root: Path, name: str | None, default: str) -> Path:
    if name is None:
        return root / default
    p = Path(name).expanduser()
    return p if p.is_absolute() else root / p


def load_thor(
    root: str | Path,
    sequence: int = ThorDatasetConfig.sequence,
    calibration_dir: str | Path | None = None,
    lidar_file: str | None = None,
    joint_file: str | None = None,
    name: str | None = None,
) -> Sequence:
    """Load THOR sequence `sequence` from folder `root` as a slamlab `Sequence`.

    Reads `root/train_lidar{sequence}.mat` and `root/train_joint{sequence}.mat`; pass
    `lidar_file="test_lidar.mat", joint_file="test_joint.mat"` (names relative to `root`, or
    absolute paths) for the test log. Each scan gets the joint sample nearest in time:
    `lidar_to_body = robot.lidar_to_body(neck_yaw, head_pitch)`. Times are absolute Unix
    seconds (float64), odometry (x m, y m, theta rad), ranges float32 m, valid =
    finite & 0.1 m <= r < 30 m, body height `robot.COM_HEIGHT_M`.

    RGB-D: if `root/DEPTH_{sequence}.mat` exists, `Sequence.rgbd` streams RGBDFrames (see
    `slamlab.datasets.thor_rgbd`). Calibration: `calibration_dir`, else `root/cameraParam`
    if present, else None.
    """
    root = Path(root).expanduser()
    if not root.is_dir():
        raise DataError(root, "dataset folder not found (set dataset.root)")
    lidar_path = _resolve(root, lidar_file, f"train_lidar{sequence}.mat")
    joint_path = _resolve(root, joint_file, f"train_joint{sequence}.mat")
    for p, alt in ((lidar_path, "lidar_file=test_lidar.mat"), (joint_path, "joint_file=test_joint.mat")):
        if not p.is_file():
            have = sorted(x.name for x in root.glob("*.mat"))[:12]
            raise DataError(p, f"file not found (folder has: {have}; for the test log pass {alt})")

    lidar = read_lidar_mat(lidar_path)
    release_freed_memory()  # loadmat's records, freed in small blocks (~130 MB for 27,560 scans)
    joint = read_joint_mat(joint_path)

    j = joint.nearest(lidar.t)
    gap = np.abs(joint.ts[j] - lidar.t)
    far = int(np.count_nonzero(gap > MAX_JOINT_GAP_S))
    if far == len(lidar):
        raise DataError(
            joint_path,
            f"no joint sample within {MAX_JOINT_GAP_S} s of any scan (lidar t {lidar.t[0]:.3f}..{lidar.t[-1]:.3f}, "
            f"joint ts {joint.ts[0]:.3f}..{joint.ts[-1]:.3f}): the files are not from the same run",
            field="ts",
        )
    if far:
        warnings.warn(f"{joint_path}: {far} of {len(lidar)} scans have no joint sample within {MAX_JOINT_GAP_S} s; using the nearest", stacklevel=2)

    # Ranges: negative, NaN or inf -> 0 and invalid, one warning for the whole file.
    scans = lidar.scans
    with np.errstate(invalid="ignore"):
        possible = np.isfinite(scans) & (scans >= 0)
    n_bad = int(possible.size - np.count_nonzero(possible))
    if n_bad:
        warnings.warn(f"{lidar_path}: {n_bad} negative, NaN or inf ranges in "
                      f"{int(np.count_nonzero(~possible.all(axis=1)))} scans dropped as invalid beams", stacklevel=2)
        scans = np.where(possible, scans, np.float32(0.0))
    del possible  # a frame's valid beams: MIN_RANGE_M <= r < MAX_RANGE_M, computed with the frame (`_LidarFrames`)

    if lidar.rpy is not None:
        roll, pitch = lidar.rpy[:, 0], lidar.rpy[:, 1]
    elif joint.rpy is not None:  # UCSD variant: the IMU from the joint file
        roll, pitch = joint.rpy[0, j], joint.rpy[1, j]
    else:
        roll = pitch = np.zeros(len(lidar))

    angle_cache: dict[float, int] = {}
    angle_sets: list[np.ndarray] = []
    angle_of = np.empty(len(lidar), dtype=np.int64)
    mounts = np.empty((len(lidar), 4, 4))
    head = joint.head_angles
    for i in range(len(lidar)):
        res = float(lidar.res[i])
        if res not in angle_cache:
            angle_cache[res] = len(angle_sets)
            angle_sets.append(beam_angles(res))
        angle_of[i] = angle_cache[res]
        k = j[i]
        mounts[i] = robot.lidar_to_body(float(head[0, k]), float(head[1, k]))
    times = np.array(lidar.t, dtype=np.float64)
    frames = _LidarFrames(scans, lidar.odom, times, angle_sets, angle_of, mounts,
                          np.asarray(roll, dtype=np.float64), np.asarray(pitch, dtype=np.float64))
    times.flags.writeable = False

    calibration = _find_calibration(root, calibration_dir)
    seq = Sequence(
        name=name or f"thor-{lidar_path.stem}",
        scans=LazyScans(frames, np.arange(len(lidar)), times, lidar.odom),
        body_height_m=robot.COM_HEIGHT_M,
        sources=[str(lidar_path.resolve()), str(joint_path.resolve())],
        calibration=calibration,
        max_range_m=MAX_RANGE_M,
        min_range_m=MIN_RANGE_M,
    )
    from slamlab.datasets import thor_rgbd  # local: RGB-D support is optional

    stream = thor_rgbd.open_rgbd(root, sequence)
    if stream is not None:
        seq.rgbd = stream
        seq.rgbd_count = stream.count
        seq.sources.extend(str(p.resolve()) for p in stream.files)
    return seq


class _LidarFrames:
    """Scan i of a THOR log as a `ScanFrame` made when asked for (`LazyScans`): views into the
    log's arrays, its valid beams computed then. Why: a frame object, its valid mask and its
    mount matrix per scan held ~50 MB for the 27,560 scans of the hard simulated world
    (`+experiment=sim_loops`), for values the arrays hold anyway.

    `ranges` (N, 1081) float32 m with NaN, inf and negative readings already 0, so a beam is
    valid exactly when MIN_RANGE_M <= r < MAX_RANGE_M (what `load_thor` computed for all
    scans at once before); `mounts` (N, 4, 4) each scan's `robot.lidar_to_body`."""

    def __init__(self, ranges: np.ndarray, odom: np.ndarray, times: np.ndarray, angle_sets: list[np.ndarray],
                 angle_of: np.ndarray, mounts: np.ndarray, roll: np.ndarray, pitch: np.ndarray) -> None:
        self.ranges, self.odom, self.times = ranges, odom, times
        self.angle_sets, self.angle_of, self.mounts = angle_sets, angle_of, mounts
        self.roll, self.pitch = roll, pitch

    def __call__(self, i: int) -> ScanFrame:
        r = self.ranges[i]
        return ScanFrame(
            index=i,
            t=float(self.times[i]),
            odom=self.odom[i],
            ranges=r,
            angles=self.angle_sets[self.angle_of[i]],
            valid=(r >= MIN_RANGE_M) & (r < MAX_RANGE_M),
            lidar_to_body=self.mounts[i],
            roll=float(self.roll[i]),
            pitch=float(self.pitch[i]),
        )


def _find_calibration(root: Path, calibration_dir: str | Path | None) -> KinectCalibration | None:
    """`calibration_dir` if given (must load), else `root/cameraParam` if it exists, else None."""
    if calibration_dir is not None:
        folder = Path(calibration_dir).expanduser()
        if not folder.is_dir():
            raise DataError(folder, "calibration folder not found (dataset.calibration_dir)")
        return load_kinect_calibration(folder)
    default = root / CALIBRATION_SUBDIR
    return load_kinect_calibration(default) if default.is_dir() else None
