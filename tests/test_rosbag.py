"""ROS bag reader: bags written from the Intel CARMEN log read back as the CARMEN reader reads
the log (ROS 1 and ROS 2, Odometry and /tf), small handmade bags for the mount, odometry
interpolation, topic choice and range limits, and bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_module

from slamlab import artifacts
from slamlab.datasets.carmen import load_carmen
from slamlab.datasets.rosbag import load_rosbag
from slamlab.datasets.rosbag_write import open_bag_writer, write_rosbag
from slamlab.errors import ConfigError, DataError
from slamlab.geometry import rot_z, trans, wrap_angle
from slamlab.pipeline import run_pipeline

N_SCANS = 600  # the first scans of Intel: enough for turns, loops of odometry and clock steps back

# (ros version, storage, odometry source); the file or folder name the bag gets
VARIANTS = [(1, "sqlite3", "odom"), (1, "sqlite3", "tf"), (2, "sqlite3", "odom"), (2, "mcap", "tf")]


def bag_name(ros: int, storage: str, odometry: str) -> str:
    return f"intel_ros{ros}_{storage}_{odometry}" + (".bag" if ros == 1 else "")


@pytest.fixture(scope="module")
def intel(shared_data):
    return load_carmen(shared_data / "carmen" / "intel.clf.bz2")


@pytest.fixture(scope="module")
def intel_bags(intel, tmp_path_factory) -> dict[tuple, Path]:
    folder = tmp_path_factory.mktemp("bags")
    return {v: write_rosbag(intel, folder / bag_name(*v), ros=v[0], storage=v[1], odometry=v[2], max_scans=N_SCANS)
            for v in VARIANTS}  # fmt: skip


# ----------------------------------------------------------------------------- the Intel log as bags


@pytest.mark.data
@pytest.mark.parametrize("variant", VARIANTS, ids=lambda v: "-".join(map(str, v)))
def test_bag_reads_as_the_carmen_log(variant, intel, intel_bags):
    bag = load_rosbag(intel_bags[variant])
    ref = intel.scans[:N_SCANS]
    assert len(bag) == N_SCANS
    assert np.count_nonzero(np.diff(bag.times) < 0) > 0  # Intel's clock steps back: file order is kept
    np.testing.assert_array_equal(bag.times, intel.times[:N_SCANS])  # stamps survive sec/nanosec exactly
    for a, b in zip(ref, bag.scans):
        np.testing.assert_array_equal(a.ranges, b.ranges)
        np.testing.assert_array_equal(a.valid, b.valid)
        # angle_min / angle_increment are float32 in a LaserScan: one float32 ulp at most
        np.testing.assert_allclose(a.angles, b.angles, rtol=0, atol=2.4e-7)
        np.testing.assert_array_equal(a.odom[:2], b.odom[:2])
        assert abs(float(wrap_angle(a.odom[2] - b.odom[2]))) < 1e-12
        np.testing.assert_allclose(b.lidar_to_body, a.lidar_to_body, atol=1e-12)
    assert bag.max_range_m == pytest.approx(intel.max_range_m, rel=1e-6)
    assert bag.min_range_m == intel.min_range_m


@pytest.mark.data
@pytest.mark.slow
def test_lidar2d_preset_on_the_bag_follows_the_carmen_trajectory(intel_bags, shared_data, tmp_path):
    """`+experiment=lidar2d dataset=rosbag dataset.path=BAG` composes and runs, and its path is
    the CARMEN run's. LaserScan's float32 beam angles come back one ulp off, which flips no
    resampling draw in these 400 scans (the whole-log runs part after scan 754: README)."""
    runs = {}
    log = shared_data / "carmen" / "intel.clf.bz2"
    for name, data in (("bag", ["dataset=rosbag", f"dataset.path={intel_bags[(2, 'mcap', 'tf')]}"]),
                       ("clf", [f"dataset.path={log}"])):  # fmt: skip
        overrides = ["+experiment=lidar2d", *data, "steps.max_scans=400", "report=false"]
        with initialize_config_module(config_module="slamlab.conf", version_base="1.3"):
            cfg = compose(config_name="config", overrides=overrides)
        run_pipeline(cfg, tmp_path / name, overrides=overrides, progress="off")
        runs[name] = artifacts.read_tum(tmp_path / name / "trajectory.tum")
    (t_bag, p_bag), (t_clf, p_clf) = runs["bag"], runs["clf"]
    np.testing.assert_array_equal(t_bag, t_clf)
    assert np.abs(p_bag - p_clf).max() < 1e-6  # m, rad
    m = json.loads((tmp_path / "bag" / "metrics.json").read_text())
    assert m["status"] == "ok" and m["scans"] == 400 and m["dataset"] == "intel_ros2_mcap_tf"


@pytest.mark.data
def test_relations_beside_the_bag_score_it(intel, intel_bags, shared_data, tmp_path):
    bag = tmp_path / "intel.bag"
    bag.symlink_to(intel_bags[(1, "sqlite3", "odom")])
    times = intel.times[:N_SCANS]
    lines = (shared_data / "carmen" / "intel.relations").read_text().splitlines()
    inside = [ln for ln in lines if ln.split() and all(np.isclose(times, float(v), rtol=0, atol=1e-6).any()
                                                       for v in ln.split()[:2])]  # fmt: skip
    assert 5 < len(inside) < len(lines)
    (tmp_path / "intel.relations").write_text("\n".join(inside) + "\n")
    seq = load_rosbag(bag)
    assert seq.relations is not None and len(seq.relations.t1) == len(inside)
    assert seq.sources == [str(bag), str(tmp_path / "intel.relations")]
    # the whole log's relations name scans the bag does not have: refused, with the line
    with pytest.raises(DataError, match=r"intel.relations: line \d+, field 't[12]'.*has no scan in intel.bag within"):
        load_rosbag(bag, relations=shared_data / "carmen" / "intel.relations")


# ----------------------------------------------------------------------------- small handmade bags

ANGLES = np.linspace(-1.0, 1.0, 5).astype(np.float32)


def write_small(path: Path, ros: int = 2, scans=None, odoms=None, tfs=(), statics=(), extra_scan_topic=None,
                storage: str = "sqlite3", laser_frame: str = "base_link") -> Path:  # fmt: skip
    """A bag of given messages. scans: (t, ranges[, range_min, range_max]) on /scan in `laser_frame`;
    odoms: (t, x, y, yaw) on /odom; tfs: (t, parent, child, x, y, yaw) on /tf; statics:
    (parent, child, 4x4) on /tf_static."""
    writer, m = open_bag_writer(path, ros, storage)
    scans = [(1.0 + 0.1 * i, [1.0, 2.0, 3.0, 4.0, 5.0]) for i in range(5)] if scans is None else scans
    odoms = [(1.0 + 0.1 * i, 0.1 * i, 0.0, 0.0) for i in range(5)] if odoms is None else odoms
    events = []  # (receive time s, order, topic, message)
    received = -np.inf
    for t, ranges, *lim in scans:
        rmin, rmax = (lim + [0.0, 10.0][len(lim):])[:2]
        received = max(received + 1e-6, t)  # the bag's clock never steps back, stamps may
        events.append((received, 1, "/scan", m.scan(t, np.asarray(ranges, np.float32), ANGLES, rmax, rmin, laser_frame)))
        if extra_scan_topic:
            events.append((received, 2, extra_scan_topic, m.scan(t, np.asarray(ranges, np.float32), ANGLES, rmax, 0.0, laser_frame)))
    for t, x, y, yaw in odoms:
        events.append((t, 0, "/odom", m.odometry(t, np.array([x, y, yaw]))))
    for t, parent, child, x, y, yaw in tfs:
        events.append((t, 0, "/tf", m.tf(t, parent, child, trans(x, y) @ rot_z(yaw))))
    for parent, child, T in statics:
        events.append((0.5, 0, "/tf_static", m.tf(0.5, parent, child, T)))
    with writer:
        conns = {}
        for t, order, topic, msg in sorted(events, key=lambda e: (e[0], e[1])):
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msg.__msgtype__, typestore=m.ts)
            writer.write(conns[topic], int(round(t * 1e9)) + order, m.serialize(msg))
    return path


@pytest.mark.parametrize("ros", [1, 2])
def test_mount_comes_from_a_tf_static_chain_or_the_config(tmp_path, ros):
    a = trans(0.2, 0.0, 0.3) @ rot_z(0.1)
    b = trans(0.05, -0.1, 0.0) @ rot_z(0.4)
    path = write_small(tmp_path / ("m.bag" if ros == 1 else "m"), ros=ros, laser_frame="laser",
                       statics=[("base_link", "mount", a), ("laser", "mount", np.linalg.inv(b))])  # fmt: skip
    seq = load_rosbag(path)
    np.testing.assert_allclose(seq.scans[0].lidar_to_body, a @ b, atol=1e-12)
    assert seq.scans[-1].lidar_to_body is seq.scans[0].lidar_to_body
    seq = load_rosbag(path, laser_pose=[0.3, 0.1, 0.5])
    np.testing.assert_allclose(seq.scans[0].lidar_to_body, trans(0.3, 0.1) @ rot_z(0.5), atol=1e-12)
    with pytest.warns(UserWarning, match="no /tf_static chain from 'base_link' to the scan frame 'laser'"):
        seq = load_rosbag(write_small(tmp_path / "nostatic", ros=2, laser_frame="laser"))
    np.testing.assert_array_equal(seq.scans[0].lidar_to_body, np.eye(4))


def test_odometry_is_interpolated_at_the_scan_stamps(tmp_path):
    # odometry at 2 Hz, scans at 10 Hz: poses in between, yaw across +-pi on the shorter arc
    odoms = [(1.0, 0.0, 0.0, 3.0), (1.5, 1.0, 2.0, -3.0), (2.0, 2.0, 2.0, -3.0)]
    scans = [(t, [1.0] * 5) for t in (0.9, 1.0, 1.1, 1.25, 1.5, 1.9, 2.1)]
    with pytest.warns(UserWarning, match="2 of 7 scans on /scan lie outside the odometry's time span"):
        seq = load_rosbag(write_small(tmp_path / "o", scans=scans, odoms=odoms))
    assert [s.index for s in seq.scans] == [1, 2, 3, 4, 5]  # message numbers on /scan
    mid_yaw = 3.0 + 0.5 * (2 * np.pi - 6.0)
    expect = [(0.0, 0.0, 3.0), (0.2, 0.4, 3.0 + 0.2 * (2 * np.pi - 6.0)), (0.5, 1.0, mid_yaw),
              (1.0, 2.0, -3.0), (1.8, 2.0, -3.0)]  # fmt: skip
    for s, e in zip(seq.scans, expect):
        np.testing.assert_allclose(s.odom[:2], e[:2], atol=1e-9)
        assert abs(float(wrap_angle(s.odom[2] - e[2]))) < 1e-9


def test_odometry_from_tf_with_named_frames(tmp_path):
    tfs = [(1.0 + 0.1 * i, "odom", "base_footprint", 0.1 * i, 0.0, 0.0) for i in range(5)]
    tfs += [(1.0 + 0.1 * i, "map", "odom", 5.0, 5.0, 1.0) for i in range(5)]  # another edge on /tf, ignored
    path = write_small(tmp_path / "tf", odoms=[], tfs=tfs, laser_frame="base_footprint")
    seq = load_rosbag(path, base_frame="base_footprint")
    np.testing.assert_allclose(seq.odometry[:, 0], [0.0, 0.1, 0.2, 0.3, 0.4], atol=1e-12)
    with pytest.raises(DataError, match=r"topic /tf: no odometry: no odom -> base_link transform on /tf"):
        load_rosbag(path)


def test_ranges_outside_the_messages_limits_are_invalid(tmp_path):
    scans = [(1.0, [0.05, 0.3, 9.99, 10.0, np.nan], 0.1, 10.0), (1.1, [0.05, 0.3, 9.99, 10.0, np.inf], 0.0, 5.0)]
    seq = load_rosbag(write_small(tmp_path / "r", scans=scans, odoms=[(1.0, 0, 0, 0), (1.1, 0, 0, 0)]))
    assert seq.scans[0].valid.tolist() == [False, True, True, False, False]
    assert seq.scans[1].valid.tolist() == [True, True, False, False, False]
    assert seq.max_range_m == 10.0 and seq.min_range_m == pytest.approx(0.1)
    np.testing.assert_allclose(seq.scans[0].angles, ANGLES, atol=1e-7)


# ----------------------------------------------------------------------------- topics and bad input


def test_topics_are_found_or_listed(tmp_path):
    two = write_small(tmp_path / "two", extra_scan_topic="/scan_rear")
    with pytest.raises(ConfigError, match=r"dataset.scan_topic.*2 LaserScan topics \(/scan, /scan_rear\)"):
        load_rosbag(two)
    assert len(load_rosbag(two, scan_topic="/scan_rear")) == 5
    with pytest.raises(ConfigError, match=r"dataset.scan_topic.*'/nope' is not a topic of .*its topics: /odom"):
        load_rosbag(two, scan_topic="/nope")
    with pytest.raises(ConfigError, match=r"dataset.odom_topic.*'/scan' in .* carries sensor_msgs/msg/LaserScan"):
        load_rosbag(two, scan_topic="/scan", odom_topic="/scan")
    with pytest.raises(DataError, match="no odometry: neither a nav_msgs/Odometry topic nor /tf"):
        load_rosbag(write_small(tmp_path / "noodom", odoms=[]))


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"scans": [(1.0, [1.0] * 5), (1.1, [1.0] * 5), (1.2, [])]}, r"topic /scan, message 2, field 'ranges': empty scan"),
        ({"scans": [(5.0, [1.0] * 5), (6.0, [1.0] * 5), (2.0, [1.0] * 5)]},
         r"topic /scan, message 2, field 'header.stamp': time runs backwards: stamp 2.000000 s is 4.000 s before"),
        ({"scans": [(1.0, [1.0] * 5, 0.0, -1.0)]}, r"topic /scan, message 0, field 'range_max'"),
        ({"odoms": [(1.0, 0.0, 0.0, 0.0), (1.1, np.nan, 0.0, 0.0)]}, r"topic /odom, message 1, field 'pose': .* not finite"),
    ],
    ids=["empty", "backwards", "range_max", "nan_odometry"],
)
def test_bad_messages_name_topic_and_index(tmp_path, kwargs, message):
    odoms = [(t, 0.0, 0.0, 0.0) for t in np.arange(0.0, 7.0, 0.5)]
    with pytest.raises(DataError, match=message) as err:
        load_rosbag(write_small(tmp_path / "bad", **{"odoms": odoms, **kwargs}))
    assert str(tmp_path / "bad") in str(err.value)


def test_not_a_bag(tmp_path):
    text = tmp_path / "notes.bag"
    text.write_text("hello\n")
    with pytest.raises(DataError, match=r"notes.bag: not a readable ROS bag"):
        load_rosbag(text)
    with pytest.raises(DataError, match="not a ROS 2 bag folder: metadata.yaml is missing"):
        load_rosbag(tmp_path)
    with pytest.raises(DataError, match="file not found"):
        load_rosbag(tmp_path / "missing.bag")


def test_cli_bad_bag_is_one_clear_line(tmp_path, slamlab_app):
    text = tmp_path / "notes.bag"
    text.write_text("hello\n")
    proc = slamlab_app(["+experiment=lidar2d", "dataset=rosbag", f"dataset.path={text}", f"hydra.run.dir={tmp_path / 'r'}"],
                       cwd=tmp_path)
    assert proc.returncode == 2
    assert f"{text}: not a readable ROS bag" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_writer_refuses_unknown_options(tmp_path):
    with pytest.raises(ValueError, match="storage"):
        open_bag_writer(tmp_path / "x", ros=2, storage="parquet")
