"""Scan to points: lidar polar readings to 2D points in the body-yaw frame.

For one scan the chain `Tz(body_height) Ry(pitch) Rx(roll) lidar_to_body` is the same for
every particle (particles differ only in x, y, yaw), so it is applied once here; a particle
then only rotates the 2D points by its yaw and translates them (`points_to_world`).
The body-yaw frame has its origin below/at the body origin, axes x forward, y left of the
robot's heading, z up from the floor.

Dropped: invalid beams (`ScanFrame.valid`), beams shorter than `min_range_m` or longer than
`max_range_m` (m), and, when the sequence knows the body height, points whose height above
the floor is below `ground_threshold_m` (they hit the ground, not a wall).
"""

from __future__ import annotations

from collections.abc import Sequence as SequenceABC
from dataclasses import dataclass
from functools import lru_cache
from typing import TYPE_CHECKING

import numpy as np

from slamlab.frames import LazyScans, ScanFrame, ScanRows, Sequence
from slamlab.geometry import FloatArray, body_to_world

if TYPE_CHECKING:
    from slamlab.slam.grid import MapSettings


@dataclass(frozen=True, slots=True)
class ScanPoints:
    """`xy` (M, 2) points (m) in the body-yaw frame; `origin` (2,) the lidar centre there."""

    xy: FloatArray
    origin: FloatArray


@dataclass(frozen=True, slots=True)
class ScanBatch:
    """Several scans' points in one array: scan i's points (body-yaw frame, m) are rows
    `ends[i]:ends[i + 1]` of `xy` (N, 2) (`ends` (m + 1,) int64 starts at 0) and its lidar
    centre is `origins[i]` (m, 2), as `ScanPoints` holds them for one scan (`origins` may be a
    read-only view of one shared centre)."""

    xy: FloatArray
    ends: np.ndarray
    origins: FloatArray

    def __len__(self) -> int:
        return len(self.ends) - 1

    @property
    def counts(self) -> np.ndarray:
        """(m,) points per scan."""
        return np.diff(self.ends)

    def points(self, i: int) -> ScanPoints:
        """Scan i (its points a view)."""
        return ScanPoints(xy=self.xy[self.ends[i] : self.ends[i + 1]], origin=self.origins[i])

    def scans(self, start: int, stop: int) -> ScanBatch:
        """Scans start..stop-1 (views)."""
        lo, hi = int(self.ends[start]), int(self.ends[stop])
        return ScanBatch(self.xy[lo:hi], self.ends[start : stop + 1] - lo, self.origins[start:stop])

    def nonempty(self) -> ScanBatch:
        """The scans that have points (the same points: an empty scan holds none)."""
        keep = self.counts > 0
        return ScanBatch(self.xy, np.concatenate([[0], self.ends[1:][keep]]).astype(np.int64), self.origins[keep])

    @staticmethod
    def of(scans: SequenceABC[ScanPoints]) -> ScanBatch:
        """The batch of these scans (their points copied into one array)."""
        ends = np.concatenate([[0], np.cumsum([len(q.xy) for q in scans], dtype=np.int64)]).astype(np.int64)
        xy = np.concatenate([q.xy for q in scans]).reshape(-1, 2) if len(scans) else np.empty((0, 2))
        return ScanBatch(xy, ends, np.array([q.origin for q in scans], dtype=np.float64).reshape(-1, 2))


def scan_to_points(
    frame: ScanFrame,
    body_height_m: float | None,
    min_range_m: float,
    max_range_m: float,
    ground_threshold_m: float,
) -> ScanPoints:
    """Project one scan into the body-yaw frame, dropping unusable and ground points.

    `body_height_m` None means a planar robot (CARMEN): no ground filtering, heights ignored.
    """
    r, keep = _used_beams(frame.ranges, frame.valid, min_range_m, max_range_m)
    r = r[keep]
    cos, sin = _beam_trig(frame.angles)
    T = _frame_transform(frame, body_height_m)
    p = np.stack([r * cos[keep], r * sin[keep]], axis=1)
    # transform of (x, y, 0): only the first two columns of the rotation matter
    pts = p @ T[:3, :2].T + T[:3, 3]
    if body_height_m is not None:
        pts = pts[pts[:, 2] > ground_threshold_m]
    return ScanPoints(xy=np.ascontiguousarray(pts[:, :2]), origin=T[:2, 3].copy())


def scans_to_points(
    frames: list[ScanFrame],
    body_height_m: float | None,
    min_range_m: float,
    max_range_m: float,
    ground_threshold_m: float,
) -> list[ScanPoints]:
    """`scan_to_points` of each frame, the same arrays to the bit, in fewer NumPy calls.

    Planar logs whose lidar is mounted unrotated (the transform's rotation is the identity:
    every CARMEN log slamlab has read) are projected in one pass over all the frames. There
    `scan_to_points`' product with the rotation sums x * 1 and y * 0 (in whatever order),
    which is x exactly when x is not zero; likewise y. A zero sum's sign may depend on the
    order, but it then meets a +0.0 or nonzero offset: one result either way. So adding the
    mount's offset alone gives the same bits, where a one-pass product would not (NumPy's
    product of a one-row array can differ in its last bit from the same row in a larger
    one). Anything else (a rotated mount, roll and pitch, a body height, a zero-length beam,
    a -0.0 offset) goes through `scan_to_points` one frame at a time. Why: NumPy's call
    overhead was half of the ~20 us a scan took, for the ~12,000 scans between Intel's
    filter steps."""
    def one_by_one() -> list[ScanPoints]:
        return [scan_to_points(f, body_height_m, min_range_m, max_range_m, ground_threshold_m) for f in frames]

    if body_height_m is not None or not frames:
        return one_by_one()
    # a log's frames share their mount array: one transform per distinct (roll, pitch, mount)
    mounts: dict[tuple, int] = {}
    which = np.empty(len(frames), dtype=np.int64)  # each frame's transform in `T`
    T: list[FloatArray] = []
    for i, f in enumerate(frames):
        key = (f.roll, f.pitch, id(f.lidar_to_body))
        if key not in mounts:
            mounts[key] = len(T)
            T.append(_frame_transform(f, None))
        which[i] = mounts[key]
    offsets = [_unrotated_offset(t) for t in T]
    if any(o is None for o in offsets):
        return one_by_one()
    offset = np.array(offsets)
    origins = [t[:2, 3].copy() for t in T]
    r, keep = _used_beams(np.concatenate([f.ranges for f in frames]), np.concatenate([f.valid for f in frames]), min_range_m, max_range_m)
    frame_of = np.repeat(np.arange(len(frames)), [len(f.ranges) for f in frames])[keep]
    r = r[keep]
    if np.any(r == 0):
        return one_by_one()
    trig = [_beam_trig(f.angles) for f in frames]
    cos = np.concatenate([c for c, _ in trig])[keep]
    sin = np.concatenate([s for _, s in trig])[keep]
    point_offset = offset[which[frame_of]]
    xy = np.empty((len(r), 2))
    xy[:, 0] = r * cos + point_offset[:, 0]
    xy[:, 1] = r * sin + point_offset[:, 1]
    ends = np.searchsorted(frame_of, np.arange(len(frames) + 1)).tolist()
    # each frame's points: its rows of `xy` (a view, C-contiguous as `scan_to_points`' copy)
    return [ScanPoints(xy=xy[ends[i] : ends[i + 1]], origin=origins[w].copy()) for i, w in enumerate(which.tolist())]


_UNROTATED = np.eye(3)[:, :2]  # x and y columns of an unrotated transform's rotation


def _used_beams(ranges: np.ndarray, valid: np.ndarray, min_range_m: float, max_range_m: float) -> tuple[FloatArray, np.ndarray]:
    """The ranges as float64 (m) and which beams a run uses: valid, finite and within the limits."""
    r = ranges.astype(np.float64)
    return r, valid & np.isfinite(r) & (r >= min_range_m) & (r <= max_range_m)


def _unrotated_offset(T: FloatArray) -> FloatArray | None:
    """The lidar's x / y offset (m) in the body-yaw frame when its transform `T` does not
    rotate and neither offset is -0.0: then r cos + x, r sin + y are `scan_to_points`' bits
    (see `scans_to_points`); None otherwise."""
    offset = T[:2, 3]
    if not np.array_equal(T[:3, :2], _UNROTATED) or np.any((offset == 0) & np.signbit(offset)):
        return None
    return offset


def project_scans(
    scans: SequenceABC[ScanFrame],
    start: int,
    stop: int,
    body_height_m: float | None,
    min_range_m: float,
    max_range_m: float,
    ground_threshold_m: float,
) -> ScanBatch:
    """Scans start..stop-1 of `scans` in one `ScanBatch`: each scan's points are
    `scan_to_points`' to the bit. A planar log whose scans the source holds as rows of one
    array (`LazyScans.rows`: a CARMEN log's), with the lidar mounted unrotated, is projected as
    those 2D arrays, without a frame or a NumPy call per scan (`scans_to_points`' reasoning on
    the bits holds row by row); anything else goes through `scans_to_points`. Why: the ~12,000
    scans between Intel's filter steps cost ~80 us each in Python, most of it per-scan calls."""
    rows = scans.rows(start, stop) if body_height_m is None and isinstance(scans, LazyScans) else None
    batch = _rows_to_points(rows, min_range_m, max_range_m) if rows is not None else None
    if batch is None:
        batch = ScanBatch.of(scans_to_points([scans[j] for j in range(start, stop)], body_height_m, min_range_m, max_range_m, ground_threshold_m))
    return batch


def _rows_to_points(rows: ScanRows, min_range_m: float, max_range_m: float) -> ScanBatch | None:
    """`project_scans` of `rows` (a planar log, no body height), or None where the mount is
    rotated, has a -0.0 offset or a kept beam has zero length (`scans_to_points`' fallbacks)."""
    T = _lidar_in_body_yaw(0.0, 0.0, 0.0, np.asarray(rows.lidar_to_body, dtype=np.float64).tobytes())
    offset = _unrotated_offset(T)
    if offset is None:
        return None
    r, keep = _used_beams(rows.ranges, rows.valid, min_range_m, max_range_m)
    r = r[keep]
    if np.any(r == 0):
        return None
    cos, sin = _beam_trig(rows.angles)
    xy = np.empty((len(r), 2))
    xy[:, 0] = r * np.broadcast_to(cos, keep.shape)[keep] + offset[0]
    xy[:, 1] = r * np.broadcast_to(sin, keep.shape)[keep] + offset[1]
    origins = np.broadcast_to(T[:2, 3], (len(keep), 2))  # one mount: one lidar centre (read-only)
    return ScanBatch(xy, np.concatenate([[0], np.cumsum(keep.sum(axis=1))]).astype(np.int64), origins)


def _beam_trig(angles: np.ndarray) -> tuple[FloatArray, FloatArray]:
    """cos and sin (float64) of a scan's beam angles (rad), computed once per distinct angle
    array (a CARMEN log's scans all share one): ~9 us of the ~20 us a scan took. np.cos /
    np.sin give an angle the same value in any array (every scan of Intel, ACES and the
    hospital log, and the simulated THOR sequence, projected to the same bytes as before)."""
    return _beam_trig_of(angles.tobytes(), angles.dtype.str)


@lru_cache(maxsize=16)
def _beam_trig_of(angles: bytes, dtype: str) -> tuple[FloatArray, FloatArray]:
    a = np.frombuffer(angles, dtype=dtype).astype(np.float64)
    with np.errstate(invalid="ignore"):  # an invalid beam's inf angle: its NaN is never kept
        cos, sin = np.cos(a), np.sin(a)
    cos.flags.writeable = False  # shared between calls
    sin.flags.writeable = False
    return cos, sin


def _frame_transform(frame: ScanFrame, body_height_m: float | None) -> FloatArray:
    """The frame's lidar pose in the body-yaw frame (`_lidar_in_body_yaw`, cached)."""
    height = 0.0 if body_height_m is None else float(body_height_m)
    return _lidar_in_body_yaw(float(frame.roll), float(frame.pitch), height, np.asarray(frame.lidar_to_body, dtype=np.float64).tobytes())


@lru_cache(maxsize=16)
def _lidar_in_body_yaw(roll: float, pitch: float, height_m: float, lidar_to_body: bytes) -> FloatArray:
    """4x4 pose of the lidar in the body-yaw frame (the body at the origin with zero yaw:
    particles add x, y, theta later, in 2D). Cached: a planar log's scans all share one (the
    engine projects every scan, ~10,000 on Intel), a THOR walk's change with the IMU."""
    T = body_to_world(0.0, 0.0, 0.0, roll, pitch, height_m) @ np.frombuffer(lidar_to_body, dtype=np.float64).reshape(4, 4)
    T.flags.writeable = False  # shared between calls
    return T


def range_limits(settings: MapSettings, sequence: Sequence) -> tuple[float, float]:
    """(min, max) beam range (m) a run uses: the map settings' own limits where set
    (`map.min_range_m` / `map.max_range_m`), else the sequence's sensor limits."""
    lo = settings.min_range_m if settings.min_range_m is not None else sequence.min_range_m
    hi = settings.max_range_m if settings.max_range_m is not None else sequence.max_range_m
    return float(lo), float(hi)


def beam_spacing_rad(sequence: Sequence) -> float:
    """The angle (rad) between neighbouring beams of the sequence's lidar: the median step of
    the first scan's beam angles (0 when its first scan has fewer than two beams)."""
    if not len(sequence.scans):
        return 0.0
    angles = np.asarray(sequence.scans[0].angles, dtype=np.float64)
    return float(np.median(np.abs(np.diff(angles)))) if len(angles) > 1 else 0.0


def points_to_world(points_xy: FloatArray, pose: FloatArray) -> FloatArray:
    """Rotate (M, 2) body-yaw points by pose[2] (rad) and translate by pose[:2] (m)."""
    return place(points_xy, pose[0], pose[1], np.cos(pose[2]), np.sin(pose[2]))


def place(points_xy: FloatArray, x: float | FloatArray, y: float | FloatArray, cos: float | FloatArray, sin: float | FloatArray) -> FloatArray:
    """(M, 2) body-yaw points rotated by the yaw whose cos / sin are given and moved by
    (x, y) m: scalars for one pose, or (M,) arrays for a pose per point (the same operations
    in the same order, so the same bits as `points_to_world` of each point's pose)."""
    return np.stack([x + cos * points_xy[:, 0] - sin * points_xy[:, 1], y + sin * points_xy[:, 0] + cos * points_xy[:, 1]], axis=1)
