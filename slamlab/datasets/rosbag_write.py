"""Write a scan `Sequence` (e.g. a CARMEN log) as a ROS bag, for tests and benchmarks.

The bag holds what `slamlab.datasets.rosbag` reads: `sensor_msgs/LaserScan` on `/scan`
(header stamp = scan time, frame `laser`), the odometry either as `nav_msgs/Odometry` on
`/odom` or as `odom -> base_link` transforms on `/tf`, and the laser mount as a
`base_link -> laser` transform on `/tf_static`. Each odometry message carries the same stamp
as its scan and is written just before it.

Receive times (the bag's own clock, which orders messages) are made strictly increasing so
that a log whose clock steps back (Intel) keeps its file order in the bag.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from slamlab.frames import Sequence
from slamlab.geometry import se2_to_matrix

BASE_FRAME = "base_link"
ODOM_FRAME = "odom"
LASER_FRAME = "laser"
STORAGES = ("sqlite3", "mcap")


def _time(types: dict[str, Any], t_s: float) -> Any:
    """ROS time of t (s): whole seconds and nanoseconds. Split before scaling: t * 1e9 of an
    epoch time would be rounded to 128 ns in float64, while t - floor(t) is exact."""
    sec = math.floor(t_s)
    ns = round((t_s - sec) * 1e9)
    sec, ns = sec + ns // 1_000_000_000, ns % 1_000_000_000
    return types["builtin_interfaces/msg/Time"](sec=sec, nanosec=ns)


class RosMessages:
    """Builds and serialises the messages of one ROS flavour (ROS 1 has a `seq` in its headers)."""

    def __init__(self, typestore: Any, ros: int):
        self.ts = typestore
        self.types = typestore.types
        self.ros = ros

    def header(self, t_s: float, frame: str) -> Any:
        extra = {"seq": 0} if self.ros == 1 else {}
        return self.types["std_msgs/msg/Header"](stamp=_time(self.types, t_s), frame_id=frame, **extra)

    def transform(self, T: np.ndarray) -> Any:
        ty = self.types
        q = Rotation.from_matrix(T[:3, :3]).as_quat()  # x, y, z, w
        return ty["geometry_msgs/msg/Transform"](
            translation=ty["geometry_msgs/msg/Vector3"](x=float(T[0, 3]), y=float(T[1, 3]), z=float(T[2, 3])),
            rotation=ty["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
        )

    def tf(self, t_s: float, parent: str, child: str, T: np.ndarray) -> Any:
        ty = self.types
        stamped = ty["geometry_msgs/msg/TransformStamped"](header=self.header(t_s, parent), child_frame_id=child,
                                                           transform=self.transform(T))  # fmt: skip
        return ty["tf2_msgs/msg/TFMessage"](transforms=[stamped])

    def odometry(self, t_s: float, pose: np.ndarray) -> Any:
        ty = self.types
        x, y, th = (float(v) for v in pose)
        p = ty["geometry_msgs/msg/Pose"](
            position=ty["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
            orientation=ty["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=np.sin(th / 2), w=np.cos(th / 2)),
        )
        zero6 = np.zeros(36, dtype=np.float64)
        twist = ty["geometry_msgs/msg/Twist"](linear=ty["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                                              angular=ty["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0))  # fmt: skip
        return ty["nav_msgs/msg/Odometry"](
            header=self.header(t_s, ODOM_FRAME), child_frame_id=BASE_FRAME,
            pose=ty["geometry_msgs/msg/PoseWithCovariance"](pose=p, covariance=zero6),
            twist=ty["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=zero6),
        )  # fmt: skip

    def scan(self, t_s: float, ranges: np.ndarray, angles: np.ndarray, range_max_m: float, range_min_m: float = 0.0,
             frame: str = LASER_FRAME) -> Any:
        n = len(angles)
        inc = float(angles[-1] - angles[0]) / (n - 1) if n > 1 else 0.0
        return self.types["sensor_msgs/msg/LaserScan"](
            header=self.header(t_s, frame), angle_min=float(angles[0]), angle_max=float(angles[-1]),
            angle_increment=inc, time_increment=0.0, scan_time=0.0, range_min=range_min_m, range_max=float(range_max_m),
            ranges=np.asarray(ranges, dtype=np.float32), intensities=np.zeros(0, dtype=np.float32),
        )  # fmt: skip

    def serialize(self, msg: Any) -> bytes:
        if self.ros == 1:
            return self.ts.serialize_ros1(msg, msg.__msgtype__)
        return self.ts.serialize_cdr(msg, msg.__msgtype__)


def open_bag_writer(out: str | Path, ros: int = 1, storage: str = "sqlite3") -> tuple[Any, RosMessages]:
    """An unopened rosbags writer (use it in a `with` block) and the message builder for it.

    ros: 1 (`out` is a `.bag` file) or 2 (`out` is a new folder; storage `sqlite3` or `mcap`).
    """
    from rosbags.typesys import Stores, get_typestore

    if ros not in (1, 2) or storage not in STORAGES:
        raise ValueError(f"ros must be 1 or 2 and storage one of {STORAGES}, got {ros}, {storage!r}")
    typestore = get_typestore(Stores.ROS1_NOETIC if ros == 1 else Stores.ROS2_HUMBLE)
    if "tf2_msgs/msg/TFMessage" not in typestore.types:  # rosbags' Noetic store lacks tf2_msgs
        from rosbags.typesys import get_types_from_msg

        typestore.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"))
    if ros == 1:
        from rosbags.rosbag1 import Writer as Writer1

        return Writer1(Path(out)), RosMessages(typestore, ros)
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2

    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    return Writer2(Path(out), version=9, storage_plugin=plugin), RosMessages(typestore, ros)


def write_rosbag(
    seq: Sequence,
    out: str | Path,
    ros: int = 1,
    storage: str = "sqlite3",
    odometry: str = "odom",
    max_scans: int | None = None,
) -> Path:
    """Write `seq` as a ROS bag at `out` and return its path.

    ros: 1 (a `.bag` file; `out` must end in `.bag`) or 2 (a bag folder; `storage` is
    `sqlite3` or `mcap`). odometry: `odom` (nav_msgs/Odometry on /odom) or `tf`
    (odom -> base_link on /tf). max_scans: only the first N scans. Ranges are written as
    they are, with range_min 0 and range_max = `seq.max_range_m` (m).
    """
    out = Path(out)
    scans = seq.scans[:max_scans] if max_scans is not None else seq.scans
    if odometry not in ("odom", "tf"):
        raise ValueError(f"odometry must be 'odom' or 'tf', got {odometry!r}")
    writer, m = open_bag_writer(out, ros, storage)
    with writer:
        kw = {"typestore": m.ts}
        c_scan = writer.add_connection("/scan", "sensor_msgs/msg/LaserScan", **kw)
        c_static = writer.add_connection("/tf_static", "tf2_msgs/msg/TFMessage", **kw)
        if odometry == "odom":
            c_odom = writer.add_connection("/odom", "nav_msgs/msg/Odometry", **kw)
        else:
            c_odom = writer.add_connection("/tf", "tf2_msgs/msg/TFMessage", **kw)
        t0 = scans[0].t if scans else 0.0
        writer.write(c_static, round(t0 * 1e9), m.serialize(m.tf(t0, BASE_FRAME, LASER_FRAME, np.asarray(scans[0].lidar_to_body))))
        received = round(t0 * 1e9)
        for s in scans:
            received = max(received + 2_000, round(s.t * 1e9))  # ns, strictly increasing
            if odometry == "odom":
                odo = m.odometry(s.t, s.odom)
            else:
                T = np.eye(4)
                T[np.ix_([0, 1, 3], [0, 1, 3])] = se2_to_matrix(s.odom)
                odo = m.tf(s.t, ODOM_FRAME, BASE_FRAME, T)
            writer.write(c_odom, received, m.serialize(odo))
            writer.write(c_scan, received + 1_000, m.serialize(m.scan(s.t, s.ranges, s.angles, seq.max_range_m)))
    return out
