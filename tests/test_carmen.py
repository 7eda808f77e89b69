"""CARMEN log reader: the real benchmark logs, small handwritten logs, and bad input."""

from __future__ import annotations

import bz2
import gzip
import pickle
import warnings
from pathlib import Path

import numpy as np
import pytest
from omegaconf import OmegaConf

from slamlab.datasets.carmen import flaser_beam_angles, load_carmen
from slamlab.datasets.relations import load_relations
from slamlab.errors import DataError
from slamlab.frames import LazyScans
from slamlab.eval.relations import match_times, relation_errors
from slamlab.geometry import se2_between
from slamlab.slam.scan import project_scans, scan_to_points



# ----------------------------------------------------------------------------- helpers


def flaser(ranges, pose=(0.0, 0.0, 0.0), odom=None, t=1.0, host="nohost", logger_t=0.5) -> str:
    odom = pose if odom is None else odom
    vals = " ".join(str(r) for r in ranges)
    p = " ".join(f"{v:.6f}" for v in (*pose, *odom))
    return f"FLASER {len(ranges)} {vals} {p} {t:.6f} {host} {logger_t:.6f}"


def robotlaser1(ranges, remissions, laser_pose, robot_pose, t, start=-np.pi / 2, res=np.pi / 180, max_range=20.0):
    r = " ".join(str(v) for v in ranges)
    e = " ".join(str(v) for v in remissions)
    lp = " ".join(f"{v:.6f}" for v in laser_pose)
    rp = " ".join(f"{v:.6f}" for v in robot_pose)
    fov = res * (len(ranges) - 1)
    return (
        f"ROBOTLASER1 0 {start:.6f} {fov:.6f} {res:.6f} {max_range} 0.01 0 {len(ranges)} {r} "
        f"{len(remissions)} {e} {lp} {rp} 0.3 0.1 0.5 0.2 0.0 {t:.6f} myhost {t + 0.01:.6f}"
    )


def rawlaser1(ranges, t, start=-np.pi / 2, res=np.pi / 180, max_range=20.0, remissions=()):
    r = " ".join(str(v) for v in ranges)
    e = " ".join(str(v) for v in remissions)
    fov = res * (len(ranges) - 1)
    return (f"RAWLASER1 0 {start:.6f} {fov:.6f} {res:.6f} {max_range} 0.01 0 {len(ranges)} {r} "
            f"{len(remissions)} {e} {t:.6f} myhost {t + 0.01:.6f}").replace("  ", " ")


def odom_line(x, y, th, t):
    return f"ODOM {x:.6f} {y:.6f} {th:.6f} 0.3 0.1 0.0 {t:.6f} nohost {t + 0.01:.6f}"


SMALL_LOG = "\n".join(
    [
        "# message_name [message contents] ipc_timestamp ipc_hostname logger_timestamp",
        "PARAM robot_frontlaser_offset 0.0 nohost 0",
        "ODOM 0.0 0.0 0.0 0.0 0.0 0.0 0.9 nohost 0.1",
        flaser([1.0, 2.0, 20.0, 3.5, 20.0], pose=(0.0, 0.0, 0.1), t=1.0),
        "ODOM 0.1 0.0 0.0 0.0 0.0 0.0 1.1 nohost 0.1",
        flaser([1.1, 20.0, 2.5, 3.4, 4.0], pose=(0.5, 0.2, 0.2), t=1.2),
        # the clock steps back: the scan must stay third
        flaser([1.2, 2.2, 2.4, 20.0, 4.1], pose=(0.9, 0.3, 0.3), t=1.1),
        "SYNC foo 1.3 nohost 0.2",
    ]
)


def write(path: Path, text: str) -> Path:
    path.write_text(text + "\n")
    return path


def assert_same_sequence(a, b) -> None:
    assert len(a) == len(b)
    for s, r in zip(a.scans, b.scans):
        assert s.t == r.t
        np.testing.assert_array_equal(s.odom, r.odom)
        np.testing.assert_array_equal(s.ranges, r.ranges)
        np.testing.assert_array_equal(s.angles, r.angles)
        np.testing.assert_array_equal(s.valid, r.valid)
        np.testing.assert_array_equal(s.lidar_to_body, r.lidar_to_body)


# ----------------------------------------------------------------------------- real logs


@pytest.fixture(scope="module")
def intel(shared_data):
    return load_carmen(shared_data / "carmen" / "intel.clf.bz2")


@pytest.fixture(scope="module")
def aces(shared_data):
    return load_carmen(shared_data / "carmen" / "aces.clf.bz2")


@pytest.mark.data
@pytest.mark.parametrize(
    ("seq_name", "scans", "relations", "saturation_m", "ref_mean", "ref_std"),
    [("intel", 13631, 2984, 81.83, 7.370, 14.352), ("aces", 7374, 1279, 50.0, 0.549, 2.676)],
)
def test_benchmark_log(request, seq_name, scans, relations, saturation_m, ref_mean, ref_std):
    seq = request.getfixturevalue(seq_name)
    assert seq.name == seq_name
    assert len(seq) == scans
    assert [s.index for s in seq.scans] == list(range(scans))
    assert {s.ranges.size for s in seq.scans} == {180}
    s0 = seq.scans[0]
    assert s0.ranges.dtype == np.float32 and s0.angles.dtype == np.float32
    assert np.degrees(s0.angles[[0, 1, -1]]) == pytest.approx([-90.0, -89.0, 89.0], abs=1e-4)
    # No mount offset in these logs (laser pose == robot pose in every record).
    np.testing.assert_array_equal(s0.lidar_to_body, np.eye(4))
    assert seq.body_height_m is None and s0.roll == 0.0 and s0.pitch == 0.0
    # The saturation value is detected and means "no return".
    assert seq.max_range_m == pytest.approx(saturation_m)
    all_r = np.concatenate([s.ranges for s in seq.scans])
    all_v = np.concatenate([s.valid for s in seq.scans])
    assert not all_v[all_r >= np.float32(saturation_m)].any()
    assert all_v[all_r < np.float32(saturation_m)].all()
    # Relations: found beside the log, every time is a scan time.
    assert seq.relations is not None and seq.relations.rel.shape == (relations, 3)
    assert seq.sources[1].endswith(f"{seq_name}.relations")
    times = seq.times
    match_times(times, np.concatenate([seq.relations.t1, seq.relations.t2]))
    # Raw odometry reproduces the published relation error: validates reader and metric.
    e = relation_errors(times, seq.odometry, seq.relations)
    assert e["count"] == relations
    assert e["trans_abs_mean_m"] == pytest.approx(ref_mean, rel=0.01)
    assert e["trans_abs_std_m"] == pytest.approx(ref_std, rel=0.01)


@pytest.mark.data
def test_intel_keeps_file_order_with_backward_clock(intel):
    dt = np.diff(intel.times)
    assert np.count_nonzero(dt < 0) == 631  # README: 631 backward jumps, never re-sorted
    assert dt.min() > -1.0


@pytest.mark.data
def test_plain_gzip_bzip2_read_the_same(shared_data, tmp_path):
    # The head of the real Intel log, written in each container.
    with bz2.open(shared_data / "carmen" / "intel.clf.bz2", "rt", encoding="latin-1") as f:
        head = "".join(next(f) for _ in range(400))
    (tmp_path / "head.clf").write_text(head, encoding="latin-1")
    with gzip.open(tmp_path / "head.clf.gz", "wt", encoding="latin-1") as f:
        f.write(head)
    with bz2.open(tmp_path / "head.clf.bz2", "wt", encoding="latin-1") as f:
        f.write(head)
    plain = load_carmen(tmp_path / "head.clf")
    assert len(plain) == head.count("\nFLASER ")
    assert plain.name == "head" and plain.relations is None
    assert_same_sequence(plain, load_carmen(tmp_path / "head.clf.gz"))
    assert_same_sequence(plain, load_carmen(tmp_path / "head.clf.bz2"))


# ----------------------------------------------------------------------------- small logs


def test_small_flaser_log(tmp_path):
    seq = load_carmen(write(tmp_path / "small.clf", SMALL_LOG))
    assert len(seq) == 3
    assert [s.t for s in seq.scans] == [1.0, 1.2, 1.1]  # file order, not time order
    np.testing.assert_allclose(seq.odometry, [[0, 0, 0.1], [0.5, 0.2, 0.2], [0.9, 0.3, 0.3]])
    # 5 beams over 180 deg: -90, -45, 0, 45, 90.
    np.testing.assert_allclose(np.degrees(seq.scans[0].angles), [-90, -45, 0, 45, 90], atol=1e-5)
    # 20.0 repeats (4 of 15 readings): detected as the saturation value, those beams invalid.
    assert seq.max_range_m == 20.0
    assert seq.scans[0].valid.tolist() == [True, True, False, True, False]
    assert seq.scans[1].valid.tolist() == [True, False, True, True, True]
    assert seq.scans[0].ranges.tolist() == pytest.approx([1.0, 2.0, 20.0, 3.5, 20.0])


def test_the_saturation_value_is_found_across_groups_of_scans(tmp_path):
    # two beam counts (two groups, read as separate blocks): the plateau at 8.0 is counted over
    # both, and NaN, inf, negative and zero readings are not readings of it
    def log(top_readings: int) -> str:
        short = [flaser([1.0, 8.0, float("nan")], t=0.1), flaser([2.0, float("inf"), -1.0], t=0.2)]
        long = [flaser([3.0, 0.0, 4.0, 5.0], t=0.3), flaser([6.0, 7.0, 8.0 if top_readings > 1 else 7.5, 2.0], t=0.4)]
        return "\n".join([*short, *long]) + "\n"

    with pytest.warns(RuntimeWarning, match="negative, NaN or inf"):
        seq = load_carmen(write(tmp_path / "two.clf", log(2)))
    assert seq.max_range_m == 8.0  # 8.0 twice, once in each group: a plateau
    assert seq.scans[0].valid.tolist() == [True, False, False]
    with pytest.warns(RuntimeWarning, match="3 negative, NaN or inf"):
        once = load_carmen(write(tmp_path / "once.clf", log(1)))
    assert once.scans[0].valid.tolist() == [True, True, False]  # 8.0 seen once is no plateau: a reading


def test_frames_are_read_only(tmp_path):
    s = load_carmen(write(tmp_path / "small.clf", SMALL_LOG)).scans[0]
    with pytest.raises(ValueError, match="read-only"):
        s.ranges[0] = 5.0


def test_max_range_argument_and_param(tmp_path):
    path = write(tmp_path / "small.clf", SMALL_LOG)
    seq = load_carmen(path, max_range_m=3.0)
    assert seq.max_range_m == 3.0
    assert seq.scans[0].valid.tolist() == [True, True, False, False, False]
    with_param = SMALL_LOG.replace("PARAM robot_frontlaser_offset", "PARAM robot_front_laser_max 3.5 nohost 0\nPARAM robot_frontlaser_offset")
    seq = load_carmen(write(tmp_path / "param.clf", with_param))
    assert seq.max_range_m == 3.5
    assert seq.scans[0].valid.tolist() == [True, True, False, False, False]


def test_no_plateau_keeps_every_positive_reading(tmp_path):
    log = "\n".join([flaser([1.0, 2.0, 3.0], t=1.0), flaser([0.0, 5.0, 4.0], t=2.0)])
    seq = load_carmen(write(tmp_path / "a.clf", log))
    assert seq.scans[1].valid.tolist() == [False, True, True]  # 0 m is never a return
    assert seq.max_range_m == 5.0


def test_nan_readings_become_invalid_with_one_warning(tmp_path):
    log = "\n".join([flaser([1.0, "nan", 3.0], t=1.0), flaser(["inf", 2.0, "NaN"], t=2.0),
                     flaser([-1.5, 2.0, "-inf"], t=3.0)])
    with pytest.warns(RuntimeWarning, match=r"nan\.clf: 5 negative, NaN or inf range readings dropped as invalid beams") as rec:
        seq = load_carmen(write(tmp_path / "nan.clf", log))
    assert len([w for w in rec if "range readings" in str(w.message)]) == 1
    assert seq.scans[0].valid.tolist() == [True, False, True]
    assert seq.scans[1].valid.tolist() == [False, True, False]
    assert seq.scans[2].valid.tolist() == [False, True, False]


def test_frontlaser_offset_param_sets_the_mount(tmp_path):
    log = SMALL_LOG.replace("robot_frontlaser_offset 0.0", "robot_frontlaser_offset 0.15")
    T = load_carmen(write(tmp_path / "off.clf", log)).scans[0].lidar_to_body
    np.testing.assert_allclose(T, [[1, 0, 0, 0.15], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])


def test_flaser_mount_from_laser_and_robot_poses(tmp_path):
    # Laser 0.2 m ahead of the robot: laser pose = robot (+) (0.2, 0, 0).
    lines = []
    for k, (x, y, th) in enumerate([(0.0, 0.0, 0.0), (1.0, 2.0, np.pi / 2), (3.0, -1.0, -2.0)]):
        laser = (x + 0.2 * np.cos(th), y + 0.2 * np.sin(th), th)
        lines.append(flaser([1.0, 2.0, 3.0], pose=laser, odom=(x, y, th), t=float(k)))
    seq = load_carmen(write(tmp_path / "m.clf", "\n".join(lines)))
    np.testing.assert_allclose(seq.scans[1].odom, [1.0, 2.0, np.pi / 2], atol=1e-6)  # 6 decimals in the log
    np.testing.assert_allclose(seq.scans[2].lidar_to_body[:3, 3], [0.2, 0.0, 0.0], atol=1e-5)
    np.testing.assert_allclose(seq.scans[2].lidar_to_body[:3, :3], np.eye(3), atol=1e-5)


def test_flaser_angle_conventions():
    np.testing.assert_allclose(np.degrees(flaser_beam_angles(180))[[0, 90, 179]], [-90, 0, 89], atol=1e-4)
    np.testing.assert_allclose(np.degrees(flaser_beam_angles(181))[[0, 90, 180]], [-90, 0, 90], atol=1e-4)
    np.testing.assert_allclose(np.degrees(flaser_beam_angles(361))[[0, 180, 360]], [-90, 0, 90], atol=1e-4)
    np.testing.assert_allclose(np.degrees(flaser_beam_angles(100, fov_deg=100, resolution_deg=1.0))[[0, -1]], [-50, 49], atol=1e-4)


def test_robotlaser1_log(tmp_path):
    robot = [(1.0, 2.0, np.pi / 2), (1.5, 2.5, np.pi / 2 + 0.1)]
    lines = ["PARAM robot_frontlaser_offset 0.5 nohost 0"]  # the records' own offset wins
    for k, (x, y, th) in enumerate(robot):
        laser = (x + 0.1 * np.cos(th), y + 0.1 * np.sin(th), th)
        lines.append(robotlaser1([1.0, 25.0, 2.0, 19.99, "nan"], [100, 200, 300, 400, 500],
                                 laser, (x, y, th), t=50.0 + k, max_range=20.0))  # fmt: skip
        lines.append(f"ODOM {x} {y} {th} 0 0 0 {50.0 + k} nohost 0")
    with pytest.warns(RuntimeWarning, match="2 negative, NaN or inf range readings"):
        seq = load_carmen(write(tmp_path / "rl.clf", "\n".join(lines)))
    assert len(seq) == 2
    s = seq.scans[1]
    assert s.t == 51.0
    np.testing.assert_allclose(s.odom, robot[1], atol=1e-6)
    np.testing.assert_allclose(np.degrees(s.angles), [-90, -89, -88, -87, -86], atol=1e-3)
    assert s.valid.tolist() == [True, False, True, True, False]  # >= max_range 20, NaN
    assert seq.max_range_m == 20.0
    np.testing.assert_allclose(s.lidar_to_body[:3, 3], [0.1, 0, 0], atol=1e-5)


def test_a_rawlaser1_log_reads_like_the_same_scans_as_flaser_its_poses_from_odom(tmp_path):
    """RAWLASER1 scans carry no pose: with an ODOM record at each scan's time just before it,
    the log reads as the FLASER log of the same scans and poses, to the bit but for the
    angles (from the record's start and step, written to 6 decimals: 5e-5 rad at the last beam)."""
    rng = np.random.default_rng(3)
    fl, raw = [], []
    for k in range(6):
        t = 100.0 + 0.2 * k - (0.5 if k == 4 else 0.0)  # the clock steps back once, as Intel's does
        pose = (0.3 * k, 0.05 * k * k, -3.1 + 1.3 * k)
        ranges = [round(float(v), 3) for v in rng.uniform(0.5, 25.0, 180)] + [20.0]
        fl.append(flaser(ranges, pose=pose, t=t))
        raw += [odom_line(*pose, t), rawlaser1(ranges, t, max_range=20.0)]
    a = load_carmen(write(tmp_path / "fl.clf", "\n".join(["PARAM robot_front_laser_max 20.0 nohost 0"] + fl)))
    b = load_carmen(write(tmp_path / "raw.clf", "\n".join(raw)))
    assert len(a) == len(b) == 6
    for sa, sb in zip(a.scans, b.scans):
        assert sa.t == sb.t
        np.testing.assert_allclose(sb.odom, sa.odom, rtol=0, atol=1e-12)
        assert np.array_equal(sa.ranges, sb.ranges) and np.array_equal(sa.valid, sb.valid)
        np.testing.assert_allclose(sb.angles, sa.angles, rtol=0, atol=1e-4)
    assert b.max_range_m == 20.0 and not b.scans[0].valid[-1]


def test_a_rawlaser1_scan_between_odom_records_takes_their_pose_at_its_time(tmp_path):
    lines = [
        rawlaser1([1.0, 2.0], t=9.0),  # before any ODOM: the first one's pose
        odom_line(0.0, 0.0, 3.0, 10.0),
        rawlaser1([1.0, 2.0], t=10.25),
        odom_line(1.0, 2.0, -3.0, 11.0),  # the angle crossed +-pi: interpolated the short way
        rawlaser1([1.0, 2.0], t=10.5),  # its timestamp behind the ODOM before it: clamped to that one
        odom_line(2.0, 2.0, -3.0, 10.9),  # the clock stepped back
        rawlaser1([1.0, 2.0], t=11.2),  # after the last ODOM: its pose
    ]
    seq = load_carmen(write(tmp_path / "raw.clf", "\n".join(lines)))
    odom = np.array([s.odom for s in seq.scans])
    np.testing.assert_allclose(odom[0], [0.0, 0.0, 3.0])
    np.testing.assert_allclose(odom[1], [0.25, 0.5, 3.0 + 0.25 * (2 * np.pi - 6.0)], atol=1e-9)
    np.testing.assert_allclose(odom[2], [1.0, 2.0, -3.0])  # 10.5 before 11.0: clamped to the ODOM before it
    np.testing.assert_allclose(odom[3], [2.0, 2.0, -3.0])


def test_rawlaser1_is_read_only_without_scans_that_carry_poses(tmp_path):
    lines = [robotlaser1([1.0, 2.0], [], (0, 0, 0), (0, 0, 0), t=5.0), odom_line(0, 0, 0, 5.0), rawlaser1([1.0, 2.0], t=5.0)]
    with pytest.warns(UserWarning, match="using ROBOTLASER1, ignoring 1 RAWLASER1"):
        assert len(load_carmen(write(tmp_path / "rl.clf", "\n".join(lines)))) == 1
    lines = [flaser([1.0, 2.0], t=5.0), odom_line(0, 0, 0, 5.0), rawlaser1([1.0, 2.0], t=5.0), rawlaser1([1.0, 2.0], t=5.1)]
    with pytest.warns(UserWarning, match="using FLASER, ignoring 2 RAWLASER1"):
        assert len(load_carmen(write(tmp_path / "fl.clf", "\n".join(lines)))) == 1


@pytest.mark.parametrize(("lines", "expected"), [
    ([rawlaser1([1.0, 2.0], t=5.0)], r"raw\.clf: 1 lines read: RAWLASER1 scans carry no robot pose and the log has no ODOM lines"),
    ([odom_line(0, 0, 0, 4.0), "ODOM 0.1 abc 0 0 0 0 4.5 nohost 4.5", rawlaser1([1.0, 2.0], t=5.0)],
     r"raw\.clf: line 2 \(ODOM\), field 'y': expected a number, got 'abc'"),
    (["ODOM 0.1 0.2 0 0 0 0 4.5 nohost", rawlaser1([1.0, 2.0], t=5.0)], r"raw\.clf: line 1 \(ODOM\), field 'logger_timestamp': missing"),
    ([odom_line(0, 0, 0, 4.0), "RAWLASER1 0 -1.57 3.14 0.01745 20 0.01 0 2 1.0 2.0 0 1.5 host"],
     r"raw\.clf: line 2 \(RAWLASER1\), field 'logger_timestamp': missing"),
    ([odom_line(0, 0, 0, 4.0), "RAWLASER1 0 -1.57 3.14 0.01745 20 0.01 0 2 1.0 x2 0 1.5 host 1.6"],
     r"raw\.clf: line 2 \(RAWLASER1\), field 'range\[1\]': expected a number, got 'x2'"),
])
def test_bad_rawlaser1_logs_name_file_line_field(tmp_path, lines, expected):
    with pytest.raises(DataError, match=expected):
        load_carmen(write(tmp_path / "raw.clf", "\n".join(lines)))


def test_scans_of_two_shapes_come_in_file_order_made_on_demand(tmp_path):
    # 3- and 5-beam records interleaved: two blocks of arrays, one scan list in file order
    # whose frames are made when asked for (LazyScans), not held one object per scan
    widths = [3, 5, 3, 3, 5]
    lines = [flaser([1.0 + k] * w, pose=(0.1 * k, 0.0, 0.01 * k), t=10.0 + k) for k, w in enumerate(widths)]
    seq = load_carmen(write(tmp_path / "mixed.clf", "\n".join(lines)))
    assert isinstance(seq.scans, LazyScans) and len(seq) == 5
    frames = list(seq.scans)
    assert [f.index for f in frames] == [0, 1, 2, 3, 4] and [len(f.ranges) for f in frames] == widths
    assert [f.ranges[0] for f in frames] == [1.0, 2.0, 3.0, 4.0, 5.0]
    np.testing.assert_array_equal(seq.times, [f.t for f in frames])
    np.testing.assert_array_equal(seq.odometry, [f.odom for f in frames])
    assert seq.scans[-1].index == 4 and seq.scans[3].odom[0] == pytest.approx(0.3)
    part = seq.scans[1:4]  # a slice is lazy too, over the same arrays
    assert isinstance(part, LazyScans) and [f.index for f in part] == [1, 2, 3]
    np.testing.assert_array_equal(part.times, seq.times[1:4])
    assert part[0].index == 1 and np.array_equal(part[0].ranges, frames[1].ranges)
    back = pickle.loads(pickle.dumps(seq))  # a Sequence still pickles (e.g. to a worker process)
    assert [f.index for f in back.scans] == [0, 1, 2, 3, 4] and np.array_equal(back.scans[4].ranges, frames[4].ranges)


def test_consecutive_scans_project_as_rows_like_frame_by_frame(tmp_path):
    # consecutive records of one shape are handed out as 2D rows (LazyScans.rows) and
    # projected without a frame per scan: the same points, to the bit, as scan_to_points of
    # each frame; a range over records of two shapes has no rows and goes frame by frame
    rng = np.random.default_rng(3)
    widths = [5, 5, 5, 3, 5, 5]
    lines = []
    for k, w in enumerate(widths):
        r = rng.uniform(0.05, 25.0, w).round(3)
        r[rng.random(w) < 0.2] = np.nan  # invalid beams
        lines.append(flaser(r, pose=(0.1 * k, 0.0, 0.01 * k), t=10.0 + k))
    with pytest.warns(RuntimeWarning, match="NaN or inf range readings dropped"):
        seq = load_carmen(write(tmp_path / "rows.clf", "\n".join(lines)))
    scans = seq.scans
    assert scans.rows(0, 3) is not None and scans.rows(4, 6) is not None
    assert scans.rows(2, 5) is None and scans.rows(3, 3) is None  # two shapes; no scans
    rows = scans.rows(0, 3)
    assert rows.ranges.shape == (3, 5) and np.array_equal(rows.ranges[1], scans[1].ranges)
    for start, stop in [(0, 3), (1, 2), (4, 6), (2, 5), (0, 6)]:
        batch = project_scans(scans, start, stop, None, 0.1, 20.0, 0.1)
        want = [scan_to_points(scans[j], None, 0.1, 20.0, 0.1) for j in range(start, stop)]
        assert batch.counts.tolist() == [len(w.xy) for w in want]
        assert batch.xy.tobytes() == np.concatenate([w.xy for w in want]).tobytes()
        assert all(batch.points(i).origin.tobytes() == w.origin.tobytes() for i, w in enumerate(want))


def test_robotlaser1_preferred_over_flaser_copies(tmp_path):
    lines = [
        robotlaser1([1.0, 2.0], [], (0, 0, 0), (0, 0, 0), t=5.0),
        flaser([1.0, 2.0], t=5.0),
    ]
    with pytest.warns(UserWarning, match="ignoring 1 FLASER"):
        seq = load_carmen(write(tmp_path / "both.clf", "\n".join(lines)))
    assert len(seq) == 1


def test_relations_beside_log_and_override(tmp_path):
    write(tmp_path / "small.clf", SMALL_LOG)
    # The odometry motion from the scan at t=1.0 to the one at t=1.2, in the robot frame at 1.0.
    x, y, yaw = se2_between([0.0, 0.0, 0.1], [0.5, 0.2, 0.2])
    write(tmp_path / "small.relations", f"1.000000 1.200000 {x:.9f} {y:.9f} 0 0 0 {yaw:.9f}")
    write(tmp_path / "other.rel", "# comment\n\n1.0 1.1 0.9 0.3 0.0 0.0 0.0 0.2\n1.1 1.2 -0.4 -0.1 0 0 0 -0.1")
    seq = load_carmen(tmp_path / "small.clf")
    np.testing.assert_allclose(seq.relations.rel, [[x, y, yaw]], atol=1e-9)
    assert seq.sources == [str(tmp_path / "small.clf"), str(tmp_path / "small.relations")]
    # The relation is exactly the odometry motion: zero error.
    assert relation_errors(seq.times, seq.odometry, seq.relations)["trans_abs_mean_m"] == pytest.approx(0, abs=1e-9)
    seq = load_carmen(tmp_path / "small.clf", relations=tmp_path / "other.rel", name="mine")
    assert seq.name == "mine"
    np.testing.assert_allclose(seq.relations.t1, [1.0, 1.1])
    np.testing.assert_allclose(seq.relations.rel, [[0.9, 0.3, 0.2], [-0.4, -0.1, -0.1]])


def test_hydra_config_instantiates_the_loader(tmp_path):
    from hydra.utils import instantiate

    from hydra import compose, initialize_config_module

    # the shipped dataset=carmen (its YAML extends slamlab.config.datasets.CarmenDatasetConfig)
    with initialize_config_module(config_module="slamlab.conf", version_base="1.3"):
        cfg = compose(config_name="config", overrides=["dataset=carmen"]).dataset
    assert OmegaConf.is_missing(cfg, "path") and cfg.cache is True and cfg.on_bad_line == "error"
    cfg.path = str(write(tmp_path / "small.clf", SMALL_LOG))
    cfg.cache = False
    seq = instantiate(cfg)
    assert len(seq) == 3 and seq.name == "small"


# ----------------------------------------------------------------------------- bad input


def test_missing_file(tmp_path):
    with pytest.raises(DataError, match=r"nope\.clf\.bz2: file not found"):
        load_carmen(tmp_path / "nope.clf.bz2")


def test_truncated_bzip2(tmp_path):
    data = bz2.compress(("\n".join([SMALL_LOG] * 200) + "\n").encode())
    (tmp_path / "cut.clf.bz2").write_bytes(data[: len(data) // 2])
    with pytest.raises(DataError, match=r"cut\.clf\.bz2: line \d+: bzip2 stream is truncated or corrupt"):
        load_carmen(tmp_path / "cut.clf.bz2")


def test_corrupt_gzip(tmp_path):
    data = bytearray(gzip.compress(("\n".join([SMALL_LOG] * 200) + "\n").encode()))
    data[len(data) // 2 : len(data) // 2 + 16] = b"\x00" * 16
    (tmp_path / "bad.clf.gz").write_bytes(bytes(data))
    with pytest.raises(DataError, match=r"bad\.clf\.gz: line \d+: gzip stream is truncated or corrupt"):
        load_carmen(tmp_path / "bad.clf.gz")


def test_compressed_suffix_on_plain_text(tmp_path):
    write(tmp_path / "fake.clf.bz2", SMALL_LOG)
    with pytest.raises(DataError, match=r"fake\.clf\.bz2: named \.bz2 but is not bzip2 data"):
        load_carmen(tmp_path / "fake.clf.bz2")


def test_gzip_sniffed_despite_plain_suffix(tmp_path):
    (tmp_path / "sneaky.clf").write_bytes(gzip.compress((SMALL_LOG + "\n").encode()))
    assert len(load_carmen(tmp_path / "sneaky.clf")) == 3


def test_empty_log(tmp_path):
    with pytest.raises(DataError, match=r"empty\.clf: 3 lines read: no laser scans"):
        load_carmen(write(tmp_path / "empty.clf", "# nothing\nPARAM a b nohost 0\nODOM 0 0 0 0 0 0 1 nohost 1"))


@pytest.mark.parametrize(
    ("bad_line", "expected"),
    [
        # a reading dropped: the line is one value short
        ("FLASER 3 1.0 2.0 0 0 0 0 0 0 1.5 nohost 0.2", r"line 4 \(FLASER\), field 'logger_timestamp': missing: .*num_readings=3 needs 14"),
        ("FLASER 3 1.0 2.0 3.0 0 0 0 0 0 0 1.5 nohost 0.2 7", r"line 4 \(FLASER\), field 'logger_timestamp': followed by 1 unexpected"),
        ("FLASER 3 1.0 2.0 x3 0 0 0 0 0 0 1.5 nohost 0.2", r"line 4 \(FLASER\), field 'range\[2\]': expected a number, got 'x3'"),
        ("FLASER 3 1.0 2.0 3.0 0 0 0 0 0.1.0 0 1.5 nohost 0.2", r"line 4 \(FLASER\), field 'odom_y': expected a number, got '0.1.0'"),
        ("FLASER 3 1.0 2.0 3.0 0 0 0 nan 0 0 1.5 nohost 0.2", r"line 4 \(FLASER\), field 'odom_x': expected a finite number"),
        ("FLASER three 1.0 2.0 3.0 0 0 0 0 0 0 1.5 nohost 0.2", r"line 4 \(FLASER\), field 'num_readings': expected a non-negative integer"),
        ("FLASER 3 1.0 2.0 3.0 0 0 0 0 0 0 1.5 nohost zz", r"line 4 \(FLASER\), field 'logger_timestamp': expected a number, got 'zz'"),
        ("ROBOTLASER1 0 -1.57 3.14 0.01745 20 0.01 0 2 1.0 2.0 0 0 0 0 0 0 0 0 0 0 0 0 1.5 host", r"line 4 \(ROBOTLASER1\), field 'logger_timestamp': missing"),
        ("ROBOTLASER1 0 -1.57 3.14 0.01745 20 0.01 0 2 1.0 2.0 1 5 0 0 0 0 0 0 0 0 0 0 x 1.5 host 0.1", r"line 4 \(ROBOTLASER1\), field 'turn_axis': expected a number, got 'x'"),
        ("PARAM robot_frontlaser_offset abc nohost 0", r"line 4 \(PARAM robot_frontlaser_offset\), field 'param_value': expected a number"),
    ],
)
@pytest.mark.filterwarnings("ignore:.*has ROBOTLASER1 and FLASER scans")
def test_bad_laser_lines_name_file_line_field(tmp_path, bad_line, expected):
    good = [flaser([1.0, 2.0, 3.0], t=float(k)) for k in range(4)]
    lines = good[:3] + [bad_line] + good[3:]
    laser_line = not bad_line.startswith("PARAM")  # only laser lines may be skipped
    hint = ".*dataset.on_bad_line=skip drops bad lines" if laser_line else ""
    with pytest.raises(DataError, match=r"broken\.clf: " + expected + hint):
        load_carmen(write(tmp_path / "broken.clf", "\n".join(lines)))
    if laser_line:  # skip mode: the laser line is dropped, the rest read
        with pytest.warns(RuntimeWarning, match=r"broken\.clf: skipped 1 bad line\(s\): 4; first: .*" + expected):
            seq = load_carmen(tmp_path / "broken.clf", on_bad_line="skip")
        assert [s.t for s in seq.scans] == [0.0, 1.0, 2.0, 3.0]


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("1 2 0.1 0.2 0 0 0 0.3\n1 2 0.1 0.2 0 0 0", r"line 2, field 'yaw': missing: expected 8 values"),
        ("1 2 0.1 0.2 0 0 0 0.3\n\n1 2 0.1 abc 0 0 0 0.3", r"line 3, field 'y': expected a number, got 'abc'"),
        ("1 inf 0.1 0.2 0 0 0 0.3", r"line 1, field 't2': expected a finite number"),
        ("1 2 0.1 0.2 0 0 0 0.3 9", r"line 1, field 'yaw': followed by extra values"),
        ("# only a comment", r"no relations in file"),
    ],
)
def test_bad_relations(tmp_path, text, expected):
    with pytest.raises(DataError, match=r"bad\.relations: " + expected):
        load_relations(write(tmp_path / "bad.relations", text))


def test_relations_read_in_one_pass_equal_the_line_by_line_read(tmp_path):
    # a well-formed file is converted in one NumPy call; files with comments, or any error,
    # go line by line: both must give the same values and line numbers (blank lines and
    # comments skipped, numbers as Python's float reads them)
    from slamlab.datasets.relations import _parse_line_by_line, _parse_well_formed, _read_relations

    rng = np.random.default_rng(3)
    rows = [" ".join(repr(float(v)) for v in rng.normal(0, 100, 8)) for _ in range(50)] + ["1e-3 2E+2 -0 .5 5. 0 0 -1.25e-7"]
    text = "\n".join(rows[:20]) + "\n\n  \n" + "\n".join(rows[20:]) + "\n"
    assert _parse_well_formed(text)[0] is not None  # the one-pass read is the one compared first
    assert _parse_well_formed("# a comment first\n" + text)[0] is None
    for body in (text, "# a comment first\n" + text):
        path = write(tmp_path / "ok.relations", body)
        got, lines = _read_relations(path)
        want, want_lines = _parse_line_by_line(path, body)
        assert lines == want_lines and len(lines) == 51 and lines[20] == (23 if body is text else 24)
        assert np.array_equal(got.t1, want[:, 0]) and np.array_equal(got.t2, want[:, 1])
        assert np.array_equal(got.rel, want[:, [2, 3, 7]])
        assert got.rel[-1].tolist() == [0.0, 0.5, -1.25e-7] and np.signbit(got.rel[-1, 0])  # "-0" stays -0.0


def test_missing_relations_file_given_explicitly(tmp_path):
    write(tmp_path / "small.clf", SMALL_LOG)
    with pytest.raises(DataError, match=r"nowhere\.relations: file not found"):
        load_carmen(tmp_path / "small.clf", relations=tmp_path / "nowhere.relations")


def test_no_warnings_on_a_clean_log(tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_carmen(write(tmp_path / "small.clf", SMALL_LOG))


def test_crlf_tabs_and_extra_spaces_read_like_the_clean_log(tmp_path):
    clean = load_carmen(write(tmp_path / "clean.clf", SMALL_LOG))
    messy = SMALL_LOG.replace("FLASER 5 ", "FLASER\t5  ").replace(" nohost ", "  nohost\t") + "   "
    messy_seq = load_carmen(write(tmp_path / "messy.clf", messy.replace("\n", "\r\n")))
    assert_same_sequence(clean, messy_seq)


def test_relations_of_another_log_are_rejected_at_load(tmp_path):
    write(tmp_path / "small.clf", SMALL_LOG)
    write(tmp_path / "wrong.relations", "1.0 1.2 0.5 0.2 0 0 0 0.1\n1.2 7.5 0.5 0.2 0 0 0 0.1")
    with pytest.raises(DataError, match=r"wrong\.relations: line 2, field 't2': stamp 7\.500000 has no scan in small\.clf "
                       r"within 0\.0001 s \(nearest scan time 1\.200000, 6\.300000 s away; 1 stamps affected; wrong relations file\?\)"):
        load_carmen(tmp_path / "small.clf", relations=tmp_path / "wrong.relations")


def test_bad_max_range_argument(tmp_path):
    with pytest.raises(ValueError, match="max_range_m must be a positive"):
        load_carmen(write(tmp_path / "small.clf", SMALL_LOG), max_range_m=-1.0)
