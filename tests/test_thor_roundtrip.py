"""THOR format round trip: what thor_write writes, load_thor and a course-style loader read back."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
import scipy.io

from slamlab import robot
from slamlab.datasets.thor import beam_angles, load_thor
from slamlab.datasets.thor_rgbd import iter_struct_cell
from slamlab.datasets.thor_write import (
    DepthRecord,
    RGBRecord,
    write_depth_mat,
    write_joint_mat,
    write_lidar_mat,
    write_rgb_mats,
)

T0 = 1_426_800_000.0  # a 2015 Unix time, as in the course logs
N_SCANS, N_JOINT = 50, 120


def make_log(root: Path, seq: int = 0, **lidar_kwargs) -> dict:
    """50 scans at 40 Hz and 120 joint samples at 100 Hz; returns what was written."""
    rng = np.random.default_rng(seq)
    t = T0 + np.arange(N_SCANS) * 0.025 + rng.uniform(0, 1e-3, N_SCANS)
    pose = np.cumsum(rng.normal(0, 0.01, (N_SCANS, 3)), axis=0)
    pose[:, 2] = (pose[:, 2] + np.pi) % (2 * np.pi) - np.pi
    rpy = rng.normal(0, 0.02, (N_SCANS, 3))
    scans = rng.uniform(0.0, 32.0, (N_SCANS, 1081)).astype(np.float32)
    ts = T0 - 0.05 + np.arange(N_JOINT) * 0.0125  # starts before the lidar, ends after it
    head = np.vstack([0.3 * np.sin(np.arange(N_JOINT) / 7.0), np.linspace(-0.2, 0.4, N_JOINT)])
    jrpy = rng.normal(0, 0.02, (3, N_JOINT))
    write_lidar_mat(root / f"train_lidar{seq}.mat", t, pose, rpy, scans, **lidar_kwargs)
    write_joint_mat(root / f"train_joint{seq}.mat", ts, head, jrpy)
    return dict(t=t, pose=pose, rpy=rpy, scans=scans, ts=ts, head=head, jrpy=jrpy)


def course_load_lidar(path: Path) -> list[dict]:
    """A user's own loader, as the course writes it: plain loadmat indexing by position."""
    out = []
    for m in scipy.io.loadmat(path)["lidar"][0]:
        rec = m[0][0]
        nn = len(rec)
        out.append(
            {
                "t": rec[0][0][0],
                "pose": rec[nn - 4][0],
                "res": rec[nn - 3][0][0],
                "rpy": rec[nn - 2][0],
                "scan": rec[nn - 1][0],
            }
        )
    return out


@pytest.mark.parametrize("extra_field", [False, True], ids=["5-fields", "6-fields"])
def test_lidar_joint_round_trip(tmp_path: Path, extra_field: bool) -> None:
    w = make_log(tmp_path, extra_field=extra_field)
    seq = load_thor(tmp_path, 0)
    assert len(seq) == N_SCANS and seq.rgbd is None and seq.calibration is None
    assert seq.body_height_m == robot.COM_HEIGHT_M
    assert seq.times.dtype == np.float64
    np.testing.assert_array_equal(seq.times, w["t"])  # absolute Unix time kept exactly
    np.testing.assert_array_equal(seq.odometry, w["pose"])
    for i, s in enumerate(seq.scans):
        assert s.index == i
        assert s.ranges.dtype == np.float32
        np.testing.assert_array_equal(s.ranges, w["scans"][i])  # float32 exact
        np.testing.assert_array_equal(s.valid, (w["scans"][i] >= 0.1) & (w["scans"][i] < 30.0))
        assert s.roll == w["rpy"][i, 0] and s.pitch == w["rpy"][i, 1]  # IMU of the lidar record
        k = int(np.argmin(np.abs(w["ts"] - w["t"][i])))  # nearest joint sample, brute force
        np.testing.assert_allclose(s.lidar_to_body, robot.lidar_to_body(*w["head"][:, k]), atol=0)
    # The course-style loader reads the very same values from the same file.
    course = course_load_lidar(tmp_path / "train_lidar0.mat")
    assert len(course) == N_SCANS
    for i, c in enumerate(course):
        assert c["t"] == seq.scans[i].t and c["res"] == 0.0044
        np.testing.assert_array_equal(c["pose"], seq.scans[i].odom)
        np.testing.assert_array_equal(c["rpy"], w["rpy"][i])
        assert c["scan"].dtype == np.float32 and c["scan"].shape == (1081,)
        np.testing.assert_array_equal(c["scan"], seq.scans[i].ranges)


def test_joint_file_course_layout(tmp_path: Path) -> None:
    w = make_log(tmp_path)
    j = scipy.io.loadmat(tmp_path / "train_joint0.mat")
    assert j["ts"].shape == (1, N_JOINT) and j["head_angles"].shape == (2, N_JOINT)
    assert j["rpy"].shape == j["acc"].shape == j["gyro"].shape == (3, N_JOINT)
    assert j["pos"].shape == (35, N_JOINT) and j["ft_l"].shape == (6, N_JOINT)
    np.testing.assert_array_equal(j["head_angles"], w["head"])
    np.testing.assert_array_equal(j["ts"][0], w["ts"])


def test_lidar_to_body_hand_computed(tmp_path: Path) -> None:
    """A beam straight ahead of the lidar, with the head yawed 90 deg / pitched 0.3 rad."""
    t = T0 + np.arange(3) * 0.025
    write_lidar_mat(tmp_path / "train_lidar0.mat", t, np.zeros((3, 3)), np.zeros((3, 3)), np.ones((3, 1081), np.float32))
    ts = t + 0.002  # joint samples just after each scan
    head = np.array([[np.pi / 2, 0.0, 0.0], [0.0, 0.3, 0.0]])
    write_joint_mat(tmp_path / "train_joint0.mat", ts, head, np.zeros((3, 3)))
    seq = load_thor(tmp_path)
    p = np.array([2.0, 0.0, 0.0, 1.0])  # 2 m along the lidar's +x
    # Yaw 90 deg: the beam points left (+y), 0.33 + 0.15 m above the centre of mass.
    np.testing.assert_allclose(seq.scans[0].lidar_to_body @ p, [0.0, 2.0, 0.48, 1.0], atol=1e-12)
    # Pitch 0.3 rad (nose down about +y): x = 2 cos + 0.15 sin, z = 0.33 - 2 sin + 0.15 cos.
    c, s = np.cos(0.3), np.sin(0.3)
    np.testing.assert_allclose(seq.scans[1].lidar_to_body @ p, [2 * c + 0.15 * s, 0.0, 0.33 - 2 * s + 0.15 * c, 1.0], atol=1e-12)
    np.testing.assert_allclose(seq.scans[2].lidar_to_body @ p, [2.0, 0.0, 0.48, 1.0], atol=1e-12)


def test_beam_angles() -> None:
    a = beam_angles(0.0044)  # the rounded value the files store means exactly 0.25 deg
    assert a.shape == (1081,) and a.dtype == np.float32
    assert np.isclose(a[0], np.deg2rad(-135.0)) and np.isclose(a[-1], np.deg2rad(135.0)) and a[540] == 0.0
    b = beam_angles(0.005)  # any other resolution is taken as given
    assert np.isclose(b[1] - b[0], 0.005, atol=1e-6)


def test_ucsd_delta_pose_variant(tmp_path: Path) -> None:
    w = make_log(tmp_path, ucsd_delta_pose=True)
    rec = scipy.io.loadmat(tmp_path / "train_lidar0.mat")["lidar"][0][3][0][0]
    assert rec.dtype.names == ("t", "scan", "delta_pose")
    seq = load_thor(tmp_path)
    np.testing.assert_allclose(seq.odometry, w["pose"], atol=1e-12)  # integrated back
    np.testing.assert_array_equal(seq.scans[7].ranges, w["scans"][7])
    # No rpy in the record: the joint file's IMU at the nearest time.
    k = int(np.argmin(np.abs(w["ts"] - w["t"][7])))
    assert seq.scans[7].roll == w["jrpy"][0, k] and seq.scans[7].pitch == w["jrpy"][1, k]


def test_test_log_file_names_and_name(tmp_path: Path) -> None:
    make_log(tmp_path)
    (tmp_path / "train_lidar0.mat").rename(tmp_path / "test_lidar.mat")
    (tmp_path / "train_joint0.mat").rename(tmp_path / "test_joint.mat")
    seq = load_thor(tmp_path, lidar_file="test_lidar.mat", joint_file="test_joint.mat", name="test")
    assert seq.name == "test" and len(seq) == N_SCANS
    assert seq.sources[0].endswith("test_lidar.mat")


def test_nan_ranges_are_invalid_with_one_warning(tmp_path: Path) -> None:
    t = T0 + np.arange(4) * 0.025
    scans = np.full((4, 1081), 5.0, np.float32)
    scans[1, :3] = np.nan
    scans[2, 100] = np.inf
    scans[3, 7] = -2.0
    write_lidar_mat(tmp_path / "train_lidar0.mat", t, np.zeros((4, 3)), np.zeros((4, 3)), scans)
    write_joint_mat(tmp_path / "train_joint0.mat", t, np.zeros((2, 4)), np.zeros((3, 4)))
    with pytest.warns(UserWarning, match=r"5 negative, NaN or inf ranges in 3 scans dropped as invalid beams") as rec:
        seq = load_thor(tmp_path)
    assert len(rec) == 1
    assert not seq.scans[1].valid[:3].any() and seq.scans[1].valid[3:].all()
    assert np.all(np.isfinite(seq.scans[1].ranges)) and seq.scans[1].ranges[0] == 0.0
    assert not seq.scans[2].valid[100]
    assert not seq.scans[3].valid[7] and seq.scans[3].ranges[7] == 0.0


# ------------------------------------------------------------------------------- RGB-D

H, W = 6, 8  # small images: the code paths are those of 424x512 / 1080x1920


def make_rgbd(root: Path, seq: int = 0, rgb_dt: float = 0.01) -> dict:
    rng = np.random.default_rng(1)
    td = T0 + np.array([0.1, 0.4, 0.7])
    depth = [rng.integers(0, 6000, (H, W)).astype(np.uint16) for _ in td]
    head = np.array([[0.1, -0.05], [0.2, 0.0], [-0.3, 0.25]])
    odom = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.01], [0.2, 0.01, 0.02]])
    rpy = np.array([[0.01, -0.02, 0.3], [0.0, 0.01, 0.31], [0.02, 0.0, 0.32]])
    write_depth_mat(root / f"DEPTH_{seq}.mat", (DepthRecord(td[k], depth[k], rpy[k], odom[k], head[k]) for k in range(3)))
    tr = td + rgb_dt
    imgs = [rng.integers(0, 256, (H, W, 3)).astype(np.uint8) for _ in tr]
    paths = write_rgb_mats(root, seq, (RGBRecord(tr[k], imgs[k], rpy[k], odom[k], head[k]) for k in range(3)), frames_per_file=2)
    return dict(td=td, depth=depth, head=head, odom=odom, rpy=rpy, tr=tr, imgs=imgs, paths=paths)


def test_rgbd_round_trip(tmp_path: Path) -> None:
    make_log(tmp_path)
    w = make_rgbd(tmp_path)
    assert [p.name for p in w["paths"]] == ["RGB_0_1.mat", "RGB_0_2.mat"]
    seq = load_thor(tmp_path)
    assert seq.rgbd is not None and seq.rgbd_count == 3
    assert any(s.endswith("DEPTH_0.mat") for s in seq.sources) and any(s.endswith("RGB_0_2.mat") for s in seq.sources)
    for _ in range(2):  # each call is a fresh iterator
        frames = list(seq.rgbd())
        assert [f.index for f in frames] == [0, 1, 2]
        for k, f in enumerate(frames):
            assert f.t == w["td"][k] and f.rgb_t == w["tr"][k]
            mm = w["depth"][k].astype(np.float32)
            expect = np.where((mm >= 400) & (mm <= 4500), mm / 1000, 0).astype(np.float32)
            assert f.depth_m.dtype == np.float32
            np.testing.assert_array_equal(f.depth_m, expect)  # un-mirrored, metres
            np.testing.assert_array_equal(f.rgb, w["imgs"][k])
            np.testing.assert_array_equal(f.head_angles, w["head"][k])
            np.testing.assert_array_equal(f.odom, w["odom"][k])
            assert (f.roll, f.pitch) == (w["rpy"][k, 0], w["rpy"][k, 1])
            np.testing.assert_allclose(f.camera_to_body, robot.camera_to_body(*w["head"][k]))


def test_kinect_files_course_layout_and_mirroring(tmp_path: Path) -> None:
    w = make_rgbd(tmp_path)
    d = scipy.io.loadmat(tmp_path / "DEPTH_0.mat")["DEPTH"][0]
    assert len(d) == 3
    rec = d[1][0][0]
    assert rec.dtype.names == ("t", "width", "imu_rpy", "id", "odom", "head_angles", "c", "sz", "vel", "rsz",
                               "body_height", "tr", "bpp", "name", "height", "depth")  # fmt: skip
    assert rec[0][0][0] == w["td"][1] and rec[1][0][0] == W and rec[14][0][0] == H
    np.testing.assert_array_equal(rec[5][0], w["head"][1])
    np.testing.assert_array_equal(rec[15], np.flip(w["depth"][1], 1))  # stored mirrored
    np.testing.assert_array_equal(np.flip(rec[15], 1), w["depth"][1])  # the course viewer's flip
    r2 = scipy.io.loadmat(tmp_path / "RGB_0_2.mat")["RGB"][0]
    assert len(r2) == 1 and r2[0][0][0][3][0][0] == 3  # frame 3 overall, file 2
    np.testing.assert_array_equal(np.flip(r2[0][0][0][15], 1), w["imgs"][2])


def test_streaming_reader_matches_loadmat(tmp_path: Path) -> None:
    """The record-by-record MAT reader returns loadmat's values, also for compressed files."""
    make_rgbd(tmp_path)
    ref = scipy.io.loadmat(tmp_path / "DEPTH_0.mat")
    scipy.io.savemat(tmp_path / "c.mat", {"before": np.eye(3), "DEPTH": ref["DEPTH"]}, do_compression=True)
    for f in (tmp_path / "DEPTH_0.mat", tmp_path / "c.mat"):
        recs = list(iter_struct_cell(f, "DEPTH"))
        assert len(recs) == 3
        for m, r in zip(ref["DEPTH"][0], recs):
            m = m[0][0]
            assert tuple(r) == m.dtype.names
            for a, b in zip(m, r.values()):
                if isinstance(b, str):
                    assert a[0] == b
                else:
                    assert a.dtype == b.dtype and a.shape == b.shape
                    np.testing.assert_array_equal(a, b)
        meta = list(iter_struct_cell(f, "DEPTH", want_last=lambda k: False))
        assert "depth" not in meta[0] and len(meta[0]) == 15


def test_rgbd_pairs_nearest_and_none_beyond_gap(tmp_path: Path) -> None:
    make_log(tmp_path)
    w = make_rgbd(tmp_path)
    # Colour only near the first two depth frames: the third gets rgb=None, with a warning.
    (tmp_path / "RGB_0_2.mat").unlink()
    with pytest.warns(UserWarning, match="1 of 3 depth frames have no colour"):
        seq = load_thor(tmp_path)
    frames = list(seq.rgbd())
    assert frames[2].rgb is None and np.isnan(frames[2].rgb_t)
    np.testing.assert_array_equal(frames[1].rgb, w["imgs"][1])


def test_calibration_found_in_root(tmp_path: Path, shared_data: Path) -> None:
    import shutil

    make_log(tmp_path)
    shutil.copytree(shared_data / "thor" / "cameraParam", tmp_path / "cameraParam")
    seq = load_thor(tmp_path)
    assert seq.calibration is not None and seq.calibration.ir.width == 512
    seq2 = load_thor(tmp_path, calibration_dir=shared_data / "thor" / "cameraParam")
    np.testing.assert_array_equal(seq2.calibration.R, seq.calibration.R)


test_calibration_found_in_root = pytest.mark.data(test_calibration_found_in_root)


def test_hydra_config_instantiates(tmp_path: Path) -> None:
    from hydra.utils import instantiate
    from omegaconf import OmegaConf

    from hydra import compose, initialize_config_module

    # the shipped dataset=thor (its YAML extends slamlab.config.datasets.ThorDatasetConfig)
    with initialize_config_module(config_module="slamlab.conf", version_base="1.3"):
        cfg = compose(config_name="config", overrides=["dataset=thor"]).dataset
    assert OmegaConf.is_missing(cfg, "root")  # users must say where their logs are
    make_log(tmp_path, seq=2)
    cfg.root = str(tmp_path)
    cfg.sequence = 2
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        seq = instantiate(cfg)
    assert len(seq) == N_SCANS and seq.name == "thor-train_lidar2"


def test_rgbd_memory_is_bounded_by_a_frame_not_a_file(tmp_path: Path) -> None:
    """Streaming reads one colour frame at a time, never a whole RGB file."""
    import tracemalloc

    make_log(tmp_path)
    z3, z2 = np.zeros(3), np.zeros(2)
    img = np.random.default_rng(0).integers(0, 256, (120, 160, 3)).astype(np.uint8)  # 57.6 kB
    td = T0 + np.arange(40) * 0.1
    write_depth_mat(tmp_path / "DEPTH_0.mat", [DepthRecord(t, np.full((12, 16), 900, np.uint16), z3, z3, z2) for t in td])
    write_rgb_mats(tmp_path, 0, (RGBRecord(t, img, z3, z3, z2) for t in td), frames_per_file=20)  # 1.15 MB files
    seq = load_thor(tmp_path)
    tracemalloc.start()
    n = same = 0
    for f in seq.rgbd():
        same += int(f.rgb is not None and f.rgb.shape == img.shape and f.rgb[7, 9, 1] == img[7, 9, 1])
        n += 1
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert n == same == 40
    # About: the frame being handed out + the one being read (+ its raw buffer); a file is 20.
    assert peak < 5 * img.nbytes, f"peak {peak} bytes while streaming"


def test_writer_is_byte_reproducible(tmp_path: Path) -> None:
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    make_log(tmp_path / "a")
    make_log(tmp_path / "b")
    for f in ("train_lidar0.mat", "train_joint0.mat"):
        data = (tmp_path / "a" / f).read_bytes()
        assert data.startswith(b"MATLAB 5.0 MAT-file") and data == (tmp_path / "b" / f).read_bytes()
    assert not list(tmp_path.glob("*/.*.tmp"))  # no temporary files left behind
