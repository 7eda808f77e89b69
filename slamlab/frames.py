"""The one frame type every dataset adapter produces, and what comes with a sequence.

Data flows one way: an adapter (sim | thor | carmen) turns files into a `Sequence`; the
SLAM engine and the texture mapper read only these types and never learn the file format.

Conventions (units in names where not obvious):
- times are seconds (float64); poses SE(2) are (x m, y m, theta rad) in the odometry frame;
- the body frame is x forward, y left, z up; its world pose is
  Txyz(x, y, body_height_m) Rz(theta) Ry(pitch) Rx(roll);
- `lidar_to_body` / `camera_to_body` are 4x4 SE(3) matrices (metres) at that instant.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from collections.abc import Sequence as SequenceABC
from dataclasses import dataclass, field
from typing import overload

import numpy as np

from slamlab.geometry import FloatArray


@dataclass(frozen=True, slots=True)
class ScanFrame:
    """One 2D lidar scan with everything needed to place it in the world.

    `index` is the record number in the source (0-based, file order); `t` the scan time (s).
    `ranges` (m, float32) and `angles` (rad, float32, lidar frame, CCW from +x) have equal
    length; `valid` marks usable beams (False for no-return, out-of-range, NaN/inf).
    `roll`/`pitch` (rad) are the body attitude; 0.0 when the source does not know it.
    """

    index: int
    t: float
    odom: FloatArray
    ranges: np.ndarray
    angles: np.ndarray
    valid: np.ndarray
    lidar_to_body: FloatArray
    roll: float = 0.0
    pitch: float = 0.0


@dataclass(frozen=True, slots=True)
class ScanRows:
    """Consecutive scans of one shape held as rows of a log's arrays: `ranges` ((m, n)
    float32, metres) and `valid` (m, n) of the scans in order, their one beam `angles` array
    (n,) and lidar mount `lidar_to_body`; roll and pitch 0 (a planar log). Row k is the `ScanFrame` of the
    k-th scan without making one."""

    ranges: np.ndarray
    valid: np.ndarray
    angles: np.ndarray
    lidar_to_body: FloatArray


class LazyScans(SequenceABC[ScanFrame]):
    """Scans in file order, each `ScanFrame` made when it is asked for (by `frame(i)`, i the
    scan's index in the log), so that a long log keeps its arrays and no object per scan.
    A `ScanFrame` is a few views into the log's arrays, ~500 bytes: Intel's 13,631 of them held
    7 MB. `times` and `odometry` are the scans' times (s) and odometry poses (N, 3) as arrays;
    slicing gives another `LazyScans` over the same arrays."""

    __slots__ = ("_frame", "_index", "times", "odometry")

    def __init__(self, frame: Callable[[int], ScanFrame], index: np.ndarray, times: FloatArray, odometry: FloatArray) -> None:
        if not (len(index) == len(times) == len(odometry)):
            raise ValueError(f"LazyScans: {len(index)} indices, {len(times)} times, {len(odometry)} odometry poses")
        self._frame = frame
        self._index = index
        self.times = times
        self.odometry = odometry

    def __len__(self) -> int:
        return len(self._index)

    @overload
    def __getitem__(self, i: int) -> ScanFrame: ...

    @overload
    def __getitem__(self, i: slice) -> LazyScans: ...

    def __getitem__(self, i: int | slice) -> ScanFrame | LazyScans:
        if isinstance(i, slice):
            return LazyScans(self._frame, self._index[i], self.times[i], self.odometry[i])
        return self._frame(int(self._index[i]))

    def __iter__(self) -> Iterator[ScanFrame]:
        return map(self._frame, self._index.tolist())

    def rows(self, start: int, stop: int) -> ScanRows | None:
        """Scans start..stop-1 as one `ScanRows` when the source holds them so (consecutive
        records of one shape sharing their beam angles, as a CARMEN log's are); None
        otherwise: read them frame by frame."""
        records = self._index[start:stop]
        rows = getattr(self._frame, "rows", None)  # a source that holds its scans as rows (`carmen._RecordFrame`)
        return rows(records) if rows is not None and 0 < len(records) == stop - start else None


def scan_times(scans: SequenceABC[ScanFrame]) -> FloatArray:
    """(N,) scan times (s) of a scan list, without making a frame per scan when it is lazy."""
    if isinstance(scans, LazyScans):
        return np.array(scans.times, dtype=np.float64)
    return np.array([s.t for s in scans], dtype=np.float64)


def scan_odometry(scans: SequenceABC[ScanFrame]) -> FloatArray:
    """(N, 3) odometry poses of a scan list (see `scan_times`)."""
    if isinstance(scans, LazyScans):
        return np.array(scans.odometry, dtype=np.float64).reshape(-1, 3)
    return np.array([s.odom for s in scans], dtype=np.float64).reshape(-1, 3)


@dataclass(frozen=True, slots=True)
class RGBDFrame:
    """One Kinect v2 frame, images already un-mirrored (as a person would see them).

    `depth_m`: (H, W) float32 metres, 0 where invalid, in the IR camera.
    `rgb`: (H, W, 3) uint8 colour image, or None if this depth frame has no colour match.
    `t` is the depth time (s), `rgb_t` the colour time. `camera_to_body` places the IR
    optical frame (z forward, x right, y down) in the body frame at time `t`.
    `odom` is the odometry pose (x, y, theta) at `t`; `roll`/`pitch` body attitude (rad).
    """

    index: int
    t: float
    depth_m: np.ndarray
    rgb: np.ndarray | None
    rgb_t: float
    head_angles: FloatArray  # (neck yaw, head pitch) rad
    camera_to_body: FloatArray
    odom: FloatArray
    roll: float = 0.0
    pitch: float = 0.0


@dataclass(frozen=True, slots=True)
class CameraIntrinsics:
    """Pinhole + distortion (Bouguet toolbox convention), pixels."""

    fc: FloatArray  # (2,) focal lengths px
    cc: FloatArray  # (2,) principal point px
    kc: FloatArray  # (5,) distortion k1 k2 p1 p2 k3
    alpha_c: float
    width: int
    height: int


# The Kinect v2's usable depth range (m): the simulator writes 0 outside it and the texture
# stage ignores depth outside it by default (`texture.min_depth_m` / `max_depth_m`).
KINECT_MIN_DEPTH_M = 0.4
KINECT_MAX_DEPTH_M = 4.5


@dataclass(frozen=True, slots=True)
class KinectCalibration:
    """The Kinect v2 pair: `P_rgb = R @ P_ir + T_mm / 1000` (metres)."""

    ir: CameraIntrinsics
    rgb: CameraIntrinsics
    R: FloatArray  # (3, 3)
    T_mm: FloatArray  # (3,)


@dataclass(frozen=True, slots=True)
class GridImage:
    """A raster aligned with the world: cell (row r, col c) covers
    x in [origin_x + c*res, +res), y in [origin_y + r*res, +res) (row 0 = lowest y)."""

    data: np.ndarray
    resolution_m: float
    origin_xy: tuple[float, float]


@dataclass(frozen=True, slots=True)
class GroundTruth:
    """What the simulator knows. `poses` (N, 3) is the true body pose at each scan time
    (same order as `Sequence.scans`); `occupancy` is a bool GridImage (True = wall);
    `floor_texture` a uint8 (H, W, 3) GridImage; `ground_labels` maps RGB-D frame index to a
    bool (H, W) mask in the un-mirrored depth image (True = pixel sees the floor)."""

    poses: FloatArray
    occupancy: GridImage | None = None
    floor_texture: GridImage | None = None
    ground_labels: dict[int, np.ndarray] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class Relations:
    """Benchmark relations (Kuemmerle et al. 2009): pose at t2 seen from t1, (x, y, theta)."""

    t1: FloatArray
    t2: FloatArray
    rel: FloatArray  # (M, 3)
    path: str = ""


@dataclass(slots=True)
class Sequence:
    """A time-ordered scan log plus what comes with it.

    `scans` are in file order (never re-sorted: some logs have clocks that step back).
    `body_height_m` is the body origin's height above the floor (m), or None for a planar
    robot whose lidar never sees the floor (ground filtering is then off).
    `rgbd` returns a fresh lazy iterator over RGB-D frames (memory bounded by one file), or
    is None when the sequence has no RGB-D. `sources` lists the files read, for fingerprints.
    `max_range_m` / `min_range_m` are the sensor's limits (a reading at the maximum means no
    return); the engine may use a shorter range of its own for mapping.
    """

    name: str
    scans: SequenceABC[ScanFrame]  # a list, or `LazyScans` for a long log
    body_height_m: float | None
    sources: list[str]
    rgbd: Callable[[], Iterator[RGBDFrame]] | None = None
    rgbd_count: int = 0
    calibration: KinectCalibration | None = None
    ground_truth: GroundTruth | None = None
    relations: Relations | None = None
    max_range_m: float = 30.0
    min_range_m: float = 0.1

    def __len__(self) -> int:
        return len(self.scans)

    @property
    def times(self) -> FloatArray:
        """Scan times (s), file order."""
        return scan_times(self.scans)

    @property
    def odometry(self) -> FloatArray:
        """(N, 3) odometry poses, file order."""
        return scan_odometry(self.scans)
