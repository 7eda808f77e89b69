"""Schemas of the file datasets (`dataset=carmen | thor | rosbag`): keys, defaults and types.

The loaders (`slamlab.datasets.carmen.load_carmen`, `thor.load_thor`, `rosbag.load_rosbag`)
check the values against the files (a relations file that is not there, an unknown topic)
and name the file, record and field; the schema says which keys exist and their types, so a
misspelt key or a wrong type is refused before any file is read. `path` / `root` are
required (`???`): `slamlab +experiment=lidar2d dataset.path=LOG`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

from omegaconf import MISSING

# a relation stamp matches the nearest scan within this (s); some files round to 10 us
RELATIONS_TIME_TOL_S = 1e-4


@dataclass
class CarmenDatasetConfig:
    """A CARMEN log (`.clf`, `.clf.gz`, `.clf.bz2`, `.clf.xz`)."""

    _target_: str = "slamlab.datasets.carmen.load_carmen"
    path: str = MISSING  # the log file
    relations: Optional[str] = None  # relations file; null = <stem>.relations beside the log, if any
    max_range_m: Optional[float] = None  # readings >= this (m) mean "no return"; null = from the log
    name: Optional[str] = None  # run/sequence name; null = the file stem (intel)
    relations_time_tol_s: float = RELATIONS_TIME_TOL_S
    on_bad_line: str = "error"  # error | skip: an unreadable laser line stops the run, or is dropped
    cache: bool = True  # keep the parsed log under $SLAMLAB_CACHE_DIR/carmen (keyed by sha256)


@dataclass
class ThorDatasetConfig:
    """Recorded THOR-OP files (`train_lidarK.mat`, `train_joint{K}.mat`, RGB-D, cameraParam/)."""

    _target_: str = "slamlab.datasets.thor.load_thor"
    root: str = MISSING  # folder holding the .mat files
    sequence: int = 0  # K in train_lidarK.mat
    calibration_dir: Optional[str] = None  # Kinect calibration folder; null = root/cameraParam if present
    lidar_file: Optional[str] = None  # e.g. test_lidar.mat (relative to root) for the test log
    joint_file: Optional[str] = None  # e.g. test_joint.mat
    name: Optional[str] = None  # run label; null = thor-train_lidar{sequence}


@dataclass
class RosbagDatasetConfig:
    """A ROS 1 `.bag` file or a ROS 2 bag folder (sqlite3 or mcap)."""

    _target_: str = "slamlab.datasets.rosbag.load_rosbag"
    path: str = MISSING
    scan_topic: Optional[str] = None  # null = the bag's only LaserScan topic
    odom_topic: Optional[str] = None  # an Odometry or TFMessage topic; null = the only Odometry topic, else /tf
    relations: Optional[str] = None  # null = <stem>.relations beside the bag, if any
    relations_time_tol_s: float = RELATIONS_TIME_TOL_S
    base_frame: Optional[str] = None  # robot frame; null = the Odometry's child_frame_id
    odom_frame: str = "odom"  # parent frame of the odometry transform on /tf
    laser_pose: Optional[list[float]] = None  # [x_m, y_m, yaw_rad] of the laser in base_frame
    max_time_back_s: float = 2.0  # stamps may step back this much (s) before it is an error
    name: Optional[str] = None  # run/sequence name; null = the bag's stem
