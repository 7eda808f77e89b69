"""ROS bags (ROS 1 `.bag`; ROS 2 folders with sqlite3 or mcap storage) as a `Sequence` of 2D scans.

Read through the `rosbags` package (pure Python: no ROS install). What is read:
- scans: `sensor_msgs/LaserScan` on `scan_topic` (found automatically when the bag has exactly
  one LaserScan topic). Scan time `t` = header stamp (s). Beam i is at
  `angle_min + i * angle_increment` (rad, per message). A reading is valid when it is finite,
  > 0, >= `range_min` and < `range_max`: a reading at `range_max` means "no return", as in
  CARMEN logs and in drivers that clamp misses to the maximum.
- odometry: `nav_msgs/Odometry` on `odom_topic` (pose.pose, frames from the message), or the
  `odom_frame -> base_frame` transform on a `tf2_msgs/TFMessage` topic (`/tf`). When
  `odom_topic` is not given: the one Odometry topic if there is exactly one, else `/tf`.
  The pose at a scan is interpolated (x, y linearly, yaw along the shorter arc) between the
  odometry messages whose stamps bracket the scan stamp; a stamp equal to a scan's is used
  as it is. Scans outside the odometry's time span are dropped with a warning.
- laser mount (`lidar_to_body`): the chain of `/tf_static` transforms from the base frame to
  the scan's `header.frame_id`; `laser_pose` from the config ([x m, y m, yaw rad]) replaces it
  when given; with neither, the identity (and a warning when the frames differ).

Scans stay in bag order (receive time), never re-sorted by stamp, as for CARMEN. Header
stamps may step back a little (the Intel log's clock steps back by up to 0.9 s); a step back
larger than `max_time_back_s` is refused as bad input.

Messages are streamed one at a time (memory: the scans kept, not the bag). Bad input raises
DataError naming the bag, the topic and the message index on that topic.
"""

from __future__ import annotations

import math
import warnings
from collections import deque
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from slamlab.datasets.relations import DEFAULT_RELATIONS_TOL_S, relations_for_log
from slamlab.errors import ConfigError, DataError
from slamlab.frames import ScanFrame, Sequence
from slamlab.geometry import FloatArray, rot_z, trans, wrap_angle
from slamlab.config.datasets import RosbagDatasetConfig

LASER_SCAN = "sensor_msgs/msg/LaserScan"
ODOMETRY = "nav_msgs/msg/Odometry"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
TF_TYPES = (TF_MESSAGE, "tf/msg/tfMessage")  # ROS 1 bags may carry the older tf type
TF_STATIC_TOPIC = "/tf_static"
TF_TOPIC = "/tf"

# Odometry messages kept for interpolation: enough for a few seconds of 100 Hz odometry
# arriving ahead of (or behind) the scans.
_ODOM_WINDOW = 1024


# ----------------------------------------------------------------------------- small helpers


def stamp_s(stamp: Any) -> float:
    """A ROS time (sec, nanosec) as seconds (float64)."""
    return float(stamp.sec) + 1e-9 * float(stamp.nanosec)


def quaternion_yaw(q: Any) -> float:
    """Yaw (rad) of a quaternion message (x, y, z, w): rotation about z of its heading."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def transform_matrix(tf: Any) -> FloatArray:
    """4x4 SE(3) matrix (m) of a geometry_msgs/Transform: child frame in the parent frame."""
    T = np.eye(4)
    q = tf.rotation
    T[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    T[:3, 3] = (tf.translation.x, tf.translation.y, tf.translation.z)
    return T


def _frame(name: str) -> str:
    """ROS 1 frames may carry a leading '/' (tf_prefix era); compare without it."""
    return name.lstrip("/")


def _interpolate(a: tuple[float, FloatArray], b: tuple[float, FloatArray], t: float) -> FloatArray:
    """Pose at time t (s) between two stamped SE(2) poses (x m, y m, yaw rad)."""
    (ta, pa), (tb, pb) = a, b
    if t == ta or tb == ta:
        return pa.copy()
    if t == tb:
        return pb.copy()
    w = (t - ta) / (tb - ta)
    out = pa + w * (pb - pa)
    out[2] = pa[2] + w * float(wrap_angle(pb[2] - pa[2]))
    return out


# ----------------------------------------------------------------------------- topics


@dataclass(frozen=True)
class _Topics:
    scan: str
    odom: str  # an Odometry topic or a TFMessage topic
    odom_is_tf: bool


def _topics_of(connections: Iterable[Any]) -> dict[str, str]:
    """topic -> message type of every connection in the bag."""
    return {c.topic: c.msgtype for c in connections}


def _pick(path: Path, types: dict[str, str], wanted: str | None, msgtypes: tuple[str, ...], key: str, what: str) -> str | None:
    """The topic named by config key `key`, or the only topic of `msgtypes` when not named."""
    if wanted is not None:
        if wanted not in types:
            listing = ", ".join(f"{t} ({m})" for t, m in sorted(types.items())) or "none"
            raise ConfigError(f"dataset.{key}", f"{wanted!r} is not a topic of {path}; its topics: {listing}")
        if types[wanted] not in msgtypes:
            raise ConfigError(f"dataset.{key}", f"{wanted!r} in {path} carries {types[wanted]}, not {' or '.join(msgtypes)}")
        return wanted
    found = sorted(t for t, m in types.items() if m in msgtypes)
    if len(found) > 1:
        raise ConfigError(f"dataset.{key}", f"{path} has {len(found)} {what} topics ({', '.join(found)}); "
                          f"choose one, e.g. dataset.{key}={found[0]}")  # fmt: skip
    return found[0] if found else None


def _choose_topics(path: Path, types: dict[str, str], scan_topic: str | None, odom_topic: str | None) -> _Topics:
    scan = _pick(path, types, scan_topic, (LASER_SCAN,), "scan_topic", "LaserScan")
    if scan is None:
        raise DataError(path, "no sensor_msgs/LaserScan topic in the bag", record=f"topics: {', '.join(sorted(types)) or 'none'}")
    if odom_topic is not None:
        odom = _pick(path, types, odom_topic, (ODOMETRY, *TF_TYPES), "odom_topic", "odometry")
    else:  # the one Odometry topic, else the transforms on /tf
        odom = _pick(path, types, None, (ODOMETRY,), "odom_topic", "nav_msgs/Odometry")
        if odom is None and types.get(TF_TOPIC) in TF_TYPES:
            odom = TF_TOPIC
    if odom is None:
        raise DataError(path, "no odometry: neither a nav_msgs/Odometry topic nor /tf in the bag "
                        "(name one with dataset.odom_topic=...)", record=f"topics: {', '.join(sorted(types))}")  # fmt: skip
    return _Topics(scan=scan, odom=odom, odom_is_tf=types[odom] in TF_TYPES)


# ----------------------------------------------------------------------------- mount


def _static_edges(reader: Any, path: Path) -> dict[tuple[str, str], FloatArray]:
    """(parent, child) -> 4x4 transform of every /tf_static transform in the bag."""
    conns = [c for c in reader.connections if c.topic == TF_STATIC_TOPIC and c.msgtype in TF_TYPES]
    edges: dict[tuple[str, str], FloatArray] = {}
    if not conns:  # (rosbags reads every topic when given no connections)
        return edges
    for k, (conn, _, raw) in enumerate(reader.messages(connections=conns)):
        msg = _deserialize(reader, path, conn, raw, k)
        for ts in msg.transforms:
            edges[(_frame(ts.header.frame_id), _frame(ts.child_frame_id))] = transform_matrix(ts.transform)
    return edges


def _chain(edges: dict[tuple[str, str], FloatArray], start: str, goal: str) -> FloatArray | None:
    """Transform of frame `goal` in frame `start` through the tf tree (edges either way)."""
    graph: dict[str, list[tuple[str, FloatArray]]] = {}
    for (parent, child), T in edges.items():
        graph.setdefault(parent, []).append((child, T))
        graph.setdefault(child, []).append((parent, np.linalg.inv(T)))
    todo = deque([(start, np.eye(4))])
    seen = {start}
    while todo:
        frame, T = todo.popleft()
        if frame == goal:
            return T
        for nxt, step in graph.get(frame, []):
            if nxt not in seen:
                seen.add(nxt)
                todo.append((nxt, T @ step))
    return None


def _mount(path: Path, edges: dict[tuple[str, str], FloatArray], base: str, laser: str,
           laser_pose: list[float] | None) -> FloatArray:  # fmt: skip
    """lidar_to_body (4x4, read-only): config, else /tf_static, else identity."""
    if laser_pose is not None:
        if len(laser_pose) != 3 or not all(math.isfinite(float(v)) for v in laser_pose):
            raise ConfigError("dataset.laser_pose", f"must be [x_m, y_m, yaw_rad], got {laser_pose}")
        T = trans(float(laser_pose[0]), float(laser_pose[1])) @ rot_z(float(laser_pose[2]))
    elif laser == base:
        T = np.eye(4)
    else:
        found = _chain(edges, base, laser)
        if found is None:
            warnings.warn(f"{path}: no /tf_static chain from {base!r} to the scan frame {laser!r}; "
                          "using the identity as the laser mount (set dataset.laser_pose=[x,y,yaw] if it is not)",
                          stacklevel=3)  # fmt: skip
            T = np.eye(4)
        else:
            T = found
    T.flags.writeable = False
    return T


# ----------------------------------------------------------------------------- messages


def _deserialize(reader: Any, path: Path, conn: Any, raw: bytes, k: int) -> Any:
    try:
        return reader.deserialize(raw, conn.msgtype)
    except Exception as exc:  # rosbags raises several types for a corrupt payload
        raise DataError(path, f"cannot decode {conn.msgtype}: {exc}", record=f"topic {conn.topic}, message {k}") from None


def _check_time(path: Path, topic: str, k: int, t: float, latest: float, max_back_s: float) -> None:
    """Refuse stamp t (s) of message k when it lies more than max_back_s before the latest one."""
    if t < latest - max_back_s:
        raise DataError(path, f"time runs backwards: stamp {t:.6f} s is {latest - t:.3f} s before an earlier message "
                        f"(more than max_time_back_s = {max_back_s} s)",
                        record=f"topic {topic}, message {k}", field="header.stamp")  # fmt: skip


@dataclass
class _Odometry:
    """Stamped odometry poses (x m, y m, yaw rad) in arrival order, a bounded window."""

    window: deque = field(default_factory=lambda: deque(maxlen=_ODOM_WINDOW))
    last_t: float = -math.inf
    count: int = 0

    def add(self, t: float, pose: FloatArray) -> None:
        self.window.append((t, pose))
        self.last_t = max(self.last_t, t)
        self.count += 1

    def at(self, t: float) -> FloatArray | None | bool:
        """Pose at t; None when t precedes every kept message; False when no message at or
        after t has arrived yet (ask again after the next one)."""
        newer = None
        for item in reversed(self.window):  # newest first: the most recent clock wins
            if item[0] <= t:
                if item[0] == t:
                    return item[1].copy()
                if newer is None:
                    return False
                return _interpolate(item, newer, t)
            newer = item
        return None


def _odom_poses(msg: Any, is_tf: bool, odom_frame: str, base_frame: str) -> Iterator[tuple[float, FloatArray, str]]:
    """(stamp s, pose, child frame) of the odometry in one message."""
    if not is_tf:
        p = msg.pose.pose
        yield stamp_s(msg.header.stamp), np.array([p.position.x, p.position.y, quaternion_yaw(p.orientation)]), _frame(msg.child_frame_id)
        return
    for ts in msg.transforms:
        if _frame(ts.header.frame_id) == odom_frame and _frame(ts.child_frame_id) == base_frame:
            tr = ts.transform
            yield stamp_s(ts.header.stamp), np.array([tr.translation.x, tr.translation.y, quaternion_yaw(tr.rotation)]), base_frame


@dataclass
class _ScanMaker:
    """Turns LaserScan messages into ScanFrame pieces; shares angle arrays between scans."""

    path: Path
    topic: str
    angles: dict[tuple[float, float, int], np.ndarray] = field(default_factory=dict)
    range_max: float = 0.0
    range_min: float = 0.0

    def beams(self, msg: Any, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(ranges float32 m, angles float32 rad, valid) of message k, read-only."""
        r = np.array(msg.ranges, dtype=np.float32)
        if r.size == 0:
            raise DataError(self.path, "empty scan (no ranges)", record=f"topic {self.topic}, message {k}", field="ranges")
        rmin, rmax = np.float32(msg.range_min), np.float32(msg.range_max)
        if not (np.isfinite(rmax) and rmax > 0 and np.isfinite(rmin) and rmin < rmax):
            raise DataError(self.path, f"range_min {msg.range_min} / range_max {msg.range_max} do not form a range",
                            record=f"topic {self.topic}, message {k}", field="range_max")  # fmt: skip
        if not (math.isfinite(msg.angle_min) and math.isfinite(msg.angle_increment)):
            raise DataError(self.path, "angles are not finite", record=f"topic {self.topic}, message {k}", field="angle_increment")
        self.range_max = max(self.range_max, float(rmax))
        self.range_min = max(self.range_min, float(rmin))
        key = (float(msg.angle_min), float(msg.angle_increment), r.size)
        ang = self.angles.get(key)
        if ang is None:
            ang = (key[0] + key[1] * np.arange(r.size)).astype(np.float32)
            ang.flags.writeable = False
            self.angles[key] = ang
        with np.errstate(invalid="ignore"):
            valid = np.isfinite(r) & (r > 0) & (r >= rmin) & (r < rmax)
        r.flags.writeable = False
        valid.flags.writeable = False
        return r, ang, valid


# ----------------------------------------------------------------------------- loader


def _open(path: Path) -> Any:
    """An open AnyReader for a ROS 1 `.bag` file or a ROS 2 bag folder."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    if not path.exists():
        raise DataError(path, "file not found")
    if path.is_file() and path.suffix != ".bag":
        raise DataError(path, "not a ROS bag: expected a ROS 1 .bag file or a ROS 2 bag folder holding metadata.yaml")
    if path.is_dir() and not (path / "metadata.yaml").is_file():
        raise DataError(path, "not a ROS 2 bag folder: metadata.yaml is missing")
    # Bags of ROS 1 carry their message definitions; the typestore covers ROS 2 bags without them.
    reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
    try:
        reader.open()
    except Exception as exc:  # rosbags' ReaderError / AnyReaderError, or a storage error beneath
        raise DataError(path, f"not a readable ROS bag: {exc}") from None
    return reader


def load_rosbag(
    path: str | Path,
    scan_topic: str | None = None,
    odom_topic: str | None = None,
    relations: str | Path | None = None,
    base_frame: str | None = None,
    odom_frame: str = RosbagDatasetConfig.odom_frame,
    laser_pose: list[float] | None = None,
    max_time_back_s: float = RosbagDatasetConfig.max_time_back_s,
    name: str | None = None,
    relations_time_tol_s: float = DEFAULT_RELATIONS_TOL_S,
) -> Sequence:
    """Load the 2D scans and odometry of a ROS bag as a `Sequence` (see the module docstring).

    path: a ROS 1 `.bag` file or a ROS 2 bag folder (sqlite3 or mcap). scan_topic /
    odom_topic: topics (default: the only candidate; several -> ConfigError listing them).
    relations: a benchmark relations file (default: `<stem>.relations` beside the bag, if any).
    base_frame: the robot frame (default: the Odometry's child_frame_id, else `base_link`);
    odom_frame: the odometry frame for /tf (default `odom`). laser_pose: [x m, y m, yaw rad]
    of the laser in the base frame, overriding /tf_static. max_time_back_s: the largest step
    back of scan stamps accepted (s). name: sequence name (default: the bag's stem).
    relations_time_tol_s: a relation stamp is matched to the nearest scan within this (s).
    """
    path = Path(path)
    reader = _open(path)
    try:
        return _read(reader, path, scan_topic, odom_topic, relations, base_frame, odom_frame, laser_pose,
                     max_time_back_s, name, relations_time_tol_s)  # fmt: skip
    finally:
        reader.close()


def _read(reader: Any, path: Path, scan_topic: str | None, odom_topic: str | None, relations: str | Path | None,
          base_frame: str | None, odom_frame: str, laser_pose: list[float] | None, max_time_back_s: float,
          name: str | None, relations_time_tol_s: float) -> Sequence:  # fmt: skip
    topics = _choose_topics(path, _topics_of(reader.connections), scan_topic, odom_topic)
    edges = _static_edges(reader, path)
    odom_frame = _frame(odom_frame)
    base = _frame(base_frame) if base_frame else None
    if topics.odom_is_tf and base is None:
        base = "base_link"

    conns = [c for c in reader.connections if c.topic in (topics.scan, topics.odom)]
    maker = _ScanMaker(path, topics.scan)
    odom = _Odometry()
    scans: list[ScanFrame] = []
    pending: deque = deque()  # (k, t, ranges, angles, valid): scans waiting for odometry
    counters = {topics.scan: 0, topics.odom: 0}
    mount: FloatArray | None = None
    laser_frame = ""
    dropped_before = 0
    last_scan_t = -math.inf

    def flush(final: bool = False) -> None:
        nonlocal dropped_before, mount
        while pending:
            k, t, r, a, v = pending[0]
            pose = odom.at(t)
            if pose is False and not final:
                return  # wait for the next odometry message (keeps scans in bag order)
            pending.popleft()
            if pose is None or pose is False:
                dropped_before += 1
                continue
            pose.flags.writeable = False
            if mount is None:  # once the base frame is known from the odometry
                mount = _mount(path, edges, base or "base_link", laser_frame, laser_pose)
            scans.append(ScanFrame(index=k, t=t, odom=pose, ranges=r, angles=a, valid=v, lidar_to_body=mount))

    for conn, _, raw in reader.messages(connections=conns):
        k = counters[conn.topic]
        counters[conn.topic] = k + 1
        msg = _deserialize(reader, path, conn, raw, k)
        if conn.topic == topics.odom:
            for t, pose, child in _odom_poses(msg, topics.odom_is_tf, odom_frame, base or ""):
                if base is None:
                    base = child or "base_link"
                if not np.isfinite(pose).all():
                    raise DataError(path, f"odometry pose is not finite: {pose.tolist()}",
                                    record=f"topic {conn.topic}, message {k}", field="pose")  # fmt: skip
                _check_time(path, conn.topic, k, t, odom.last_t, max_time_back_s)
                odom.add(t, pose)
            flush()
            continue
        t = stamp_s(msg.header.stamp)
        _check_time(path, conn.topic, k, t, last_scan_t, max_time_back_s)
        last_scan_t = max(last_scan_t, t)
        r, a, v = maker.beams(msg, k)
        if not laser_frame:
            laser_frame = _frame(msg.header.frame_id)
        pending.append((k, t, r, a, v))
        flush()
    flush(final=True)

    n_scans = counters[topics.scan]
    if n_scans == 0:
        raise DataError(path, "the scan topic holds no messages", record=f"topic {topics.scan}")
    if odom.count == 0:
        what = f"no {odom_frame} -> {base} transform on" if topics.odom_is_tf else "no messages on"
        raise DataError(path, f"no odometry: {what} {topics.odom}", record=f"topic {topics.odom}")
    if dropped_before:
        warnings.warn(f"{path}: {dropped_before} of {n_scans} scans on {topics.scan} lie outside the odometry's time "
                      f"span ({topics.odom}) and were dropped", stacklevel=3)  # fmt: skip
    if not scans:
        raise DataError(path, f"no scan on {topics.scan} lies within the odometry's time span ({topics.odom})")

    rel, rel_path = relations_for_log(path, path.stem, relations, np.array([s.t for s in scans]), relations_time_tol_s)
    seq = Sequence(
        name=name if name is not None else path.stem,
        scans=scans,
        body_height_m=None,
        sources=[str(path)] + ([str(rel_path)] if rel_path is not None else []),
        relations=rel,
        max_range_m=maker.range_max,
    )
    if maker.range_min > 0:  # else keep the Sequence default (a bag's range_min of 0 says nothing)
        seq.min_range_m = maker.range_min
    return seq
