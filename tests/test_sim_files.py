"""The simulated sequence as files: reproducible, readable by load_thor and by a course-style
loader, physically consistent with its ground truth, and cached."""

from __future__ import annotations

import hashlib
import pickle
from pathlib import Path

import numpy as np
import pytest
import scipy.io

from slamlab import robot
from slamlab.datasets.sim import SimParams, generate_atomic, load_sim
from slamlab.datasets.sim import generate as gen
from slamlab.datasets.sim.sensors import BEAM_ANGLES
from slamlab.frames import Sequence
from slamlab.geometry import body_to_world, transform_points, wrap_angle

SHORT = dict(duration_s=12.0, label_every=2)


@pytest.fixture(scope="module")
def seq(sim_cache: Path) -> Sequence:
    return load_sim(seed=0, cache_dir=str(sim_cache), **SHORT)


@pytest.fixture(scope="module")
def folder(seq: Sequence, sim_cache: Path) -> Path:
    return gen.sim_folder(SimParams(seed=0, **SHORT), cache_dir=sim_cache)


@pytest.fixture(scope="module")
def states(folder: Path) -> dict[str, np.ndarray]:
    with np.load(folder / "truth" / "body_states.npz") as z:
        return {k: z[k] for k in z.files}


def digest(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_same_seed_same_bytes_other_seed_differs(tmp_path: Path) -> None:
    p = SimParams(seed=5, duration_s=3.0, kinect_scale=0.1)
    a = digest(generate_atomic(tmp_path / "a", p))
    b = digest(generate_atomic(tmp_path / "b", p))
    assert a == b
    assert {"train_lidar0.mat", "train_joint0.mat", "DEPTH_0.mat", "RGB_0_1.mat", "truth/trajectory.tum", "truth/ground_labels.npz"} <= set(a)
    c = digest(generate_atomic(tmp_path / "c", SimParams(seed=6, duration_s=3.0, kinect_scale=0.1)))
    for name in ("train_lidar0.mat", "DEPTH_0.mat", "RGB_0_1.mat", "truth/floor_texture.png"):
        assert a[name] != c[name]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temp folders left


def test_round_trip_through_load_thor(seq: Sequence, folder: Path) -> None:
    assert len(seq) == 12 * 40
    t = seq.times
    np.testing.assert_allclose(t - t[0], np.arange(len(seq)) / 40.0, atol=1e-6)
    assert t[0] == pytest.approx(gen.T0_UNIX_S)
    assert seq.body_height_m == pytest.approx(robot.COM_HEIGHT_M)
    assert seq.ground_truth is not None and seq.ground_truth.poses.shape == (len(seq), 3)
    assert seq.rgbd_count == 24 and seq.calibration is not None
    assert (seq.calibration.ir.width, seq.calibration.ir.height) == (128, 106)
    assert (seq.calibration.rgb.width, seq.calibration.rgb.height) == (480, 270)
    assert seq.calibration.ir.fc[0] == pytest.approx(364.4573624856433 * 0.25)
    s = seq.scans[100]
    assert s.ranges.dtype == np.float32 and s.ranges.shape == (1081,)
    np.testing.assert_allclose(s.angles, BEAM_ANGLES, atol=1e-6)
    assert 0.9 < s.valid.mean() <= 1.0


def test_course_style_loader_reads_the_files(seq: Sequence, folder: Path) -> None:
    """Indexing exactly as THOR_FORMAT.md (fields by position), as students' code does."""
    lidar = scipy.io.loadmat(str(folder / "train_lidar0.mat"))["lidar"]
    assert lidar.shape == (1, len(seq))
    for i in (0, 123, len(seq) - 1):
        rec = lidar[0][i][0][0]
        assert len(rec) in (5, 6)
        t, pose, res, rpy, scan = rec[0][0][0], rec[-4][0], rec[-3][0][0], rec[-2][0], rec[-1][0]
        assert t == seq.scans[i].t
        np.testing.assert_array_equal(pose, seq.scans[i].odom)
        assert res == pytest.approx(0.0044)
        assert rpy.shape == (3,) and scan.dtype == np.float32 and scan.shape == (1081,)
        np.testing.assert_array_equal(scan, seq.scans[i].ranges)
    joint = scipy.io.loadmat(str(folder / "train_joint0.mat"))
    m = joint["ts"].shape[1]
    assert joint["head_angles"].shape == (2, m) and joint["rpy"].shape == (3, m)
    assert m == pytest.approx(12 * 100 + 10, abs=2)
    depth = scipy.io.loadmat(str(folder / "DEPTH_0.mat"))["DEPTH"][0]
    d0 = depth[0][0][0]
    assert len(d0) == 16 and d0[-1].shape == (106, 128) and d0[-1].dtype == np.uint16
    rgb = scipy.io.loadmat(str(folder / "RGB_0_1.mat"))["RGB"][0]
    assert rgb.shape == (24,) and rgb[0][0][0][-1].shape == (270, 480, 3)


def test_camera_params_use_the_real_format(folder: Path, shared_data: Path) -> None:
    real = shared_data / "thor" / "cameraParam"
    for name in ("IRcam_Calib_result.pkl", "RGBcamera_Calib_result.pkl", "exParams.pkl"):
        with (real / name).open("rb") as f:
            want = pickle.load(f, encoding="latin1")
        with (folder / "cameraParam" / name).open("rb") as f:
            got = pickle.load(f, encoding="latin1")
        assert set(got) == set(want)
    with (real / "exParams.pkl").open("rb") as f:
        ext = pickle.load(f, encoding="latin1")
    with (folder / "cameraParam" / "exParams.pkl").open("rb") as f:
        ours = pickle.load(f, encoding="latin1")
    np.testing.assert_allclose(ours["T"], ext["T"])
    np.testing.assert_allclose(ours["R"], ext["R"])


def test_truth_is_continuous_and_odometry_drifts(seq: Sequence, states: dict[str, np.ndarray]) -> None:
    gt = seq.ground_truth.poses
    np.testing.assert_allclose(gt, np.column_stack([states["pose"][:, :2], wrap_angle(states["pose"][:, 2])]), atol=2e-6)
    step = np.linalg.norm(np.diff(gt[:, :2], axis=0), axis=1)
    assert step.max() <= 0.45 / 40 * 1.01  # never faster than the walking speed
    assert np.abs(wrap_angle(np.diff(gt[:, 2]))).max() <= np.deg2rad(35) / 40 * 1.01
    assert gt[0] == pytest.approx([0, 0, 0])
    odom = seq.odometry
    # standing start: odometry does not move; then it over-counts distance (scale bias)
    standing = seq.times - seq.times[0] < 2.4
    assert np.all(odom[standing] == odom[0]) and np.all(odom[0] == 0)
    d_odo = np.linalg.norm(np.diff(odom[:, :2], axis=0), axis=1).sum()
    d_true = step.sum()
    assert d_true > 3.0
    assert d_odo / d_true == pytest.approx(1.025, abs=0.015)
    assert np.linalg.norm(odom[-1, :2] - gt[-1, :2]) > 0.05


def test_beams_hit_the_floor_when_the_head_pitches_down(seq: Sequence, states: dict[str, np.ndarray]) -> None:
    """World z of the beam endpoints, through the true body pose and head angles: about 0
    for the forward beams while the head looks down; well above the floor when level."""
    down = np.flatnonzero(states["head_pitch"] > 0.35)
    level = np.flatnonzero(np.abs(states["head_pitch"]) < 0.01)
    assert down.size > 20 and level.size > 100

    def world_z(i: int) -> tuple[np.ndarray, np.ndarray]:
        s = seq.scans[i]
        x, y, th = states["pose"][i]
        T = body_to_world(x, y, th, states["roll"][i], states["pitch"][i], robot.COM_HEIGHT_M) @ robot.lidar_to_body(states["neck_yaw"][i], states["head_pitch"][i])
        r = s.ranges.astype(np.float64)
        pts = np.stack([r * np.cos(BEAM_ANGLES), r * np.sin(BEAM_ANGLES), np.zeros_like(r)], axis=1)
        return transform_points(T, pts)[:, 2], s.valid

    fwd = np.abs(BEAM_ANGLES) < np.deg2rad(10)
    zs = np.concatenate([world_z(i)[0][fwd & world_z(i)[1]] for i in down])
    assert np.mean(np.abs(zs) < 0.05) > 0.6
    assert np.median(np.abs(zs)) < 0.02
    for i in level[::10]:
        z, valid = world_z(i)
        assert np.all(z[valid] > 0.3)


def test_ground_labels_agree_with_depth_and_colour(seq: Sequence, folder: Path, states: dict[str, np.ndarray]) -> None:
    """Labelled floor pixels back-project (reader's un-mirrored depth, real camera chain) to
    z = 0; other valid pixels are mostly above the floor; and the colour seen there by the
    RGB camera (through the real R, T) is the floor texture at that point."""
    gt = seq.ground_truth
    calib = seq.calibration
    assert set(gt.ground_labels) == set(range(0, 24, 2))
    t_scan = seq.times
    tex = gt.floor_texture
    n_floor = 0
    for fr in seq.rgbd():
        if fr.index not in gt.ground_labels:
            continue
        label = gt.ground_labels[fr.index]
        assert label.shape == fr.depth_m.shape
        assert np.all(fr.depth_m[label] > 0)
        i = int(np.argmin(np.abs(t_scan - fr.t)))
        assert abs(t_scan[i] - fr.t) < 1e-6  # Kinect frames fall on scan instants
        x, y, th = states["pose"][i]
        T = body_to_world(x, y, th, states["roll"][i], states["pitch"][i], robot.COM_HEIGHT_M) @ fr.camera_to_body
        v, u = np.nonzero(fr.depth_m > 0)
        z = fr.depth_m[v, u].astype(np.float64)
        p_ir = np.stack([(u - calib.ir.cc[0]) / calib.ir.fc[0] * z, (v - calib.ir.cc[1]) / calib.ir.fc[1] * z, z], axis=1)
        pw = transform_points(T, p_ir)
        is_floor = label[v, u]
        if is_floor.any():
            assert np.abs(pw[is_floor, 2]).max() < 0.03
        if (~is_floor).sum() > 50:
            assert np.mean(pw[~is_floor, 2] > 0.03) > 0.9
        # colour of floor points: project into the RGB camera
        q = p_ir[is_floor] @ calib.R.T + calib.T_mm / 1000.0
        ur = np.round(q[:, 0] / q[:, 2] * calib.rgb.fc[0] + calib.rgb.cc[0]).astype(int)
        vr = np.round(q[:, 1] / q[:, 2] * calib.rgb.fc[1] + calib.rgb.cc[1]).astype(int)
        ok = (ur >= 0) & (ur < calib.rgb.width) & (vr >= 0) & (vr < calib.rgb.height)
        seen = fr.rgb[vr[ok], ur[ok]].astype(int)
        c = np.floor((pw[is_floor][ok, 0] - tex.origin_xy[0]) / tex.resolution_m).astype(int)
        r = np.floor((pw[is_floor][ok, 1] - tex.origin_xy[1]) / tex.resolution_m).astype(int)
        truth = tex.data[r, c].astype(int)
        if ok.sum() > 50:
            assert np.mean(np.abs(seen - truth).max(axis=1) <= 2) > 0.6
        n_floor += int(is_floor.sum())
    assert n_floor > 1000


def test_cache_is_reused_and_regenerated_on_request(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    kw = dict(seed=1, duration_s=2.0, rgbd=False, cache_dir=str(tmp_path))
    a = load_sim(**kw)
    assert a.rgbd is None and a.ground_truth is not None
    calls = []
    real = gen.generate_sequence
    monkeypatch.setattr(gen, "generate_sequence", lambda *args, **kws: calls.append(1) or real(*args, **kws))
    b = load_sim(**kw)
    assert calls == [] and b.sources[0] == a.sources[0]
    np.testing.assert_array_equal(b.scans[5].ranges, a.scans[5].ranges)
    load_sim(**kw, regenerate=True)
    assert calls == [1]
    load_sim(**{**kw, "seed": 2})
    assert calls == [1, 1]
    assert len([p for p in tmp_path.iterdir() if not p.name.startswith(".")]) == 2
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_hydra_config_instantiates_load_sim(tmp_path: Path) -> None:
    from hydra import compose, initialize_config_module
    from hydra.utils import instantiate

    with initialize_config_module(config_module="slamlab.conf", version_base=None):
        cfg = compose("config", overrides=["dataset=sim", "dataset.seed=3", "dataset.duration_s=2", "dataset.rgbd=false", f"dataset.cache_dir={tmp_path}"])
    s = instantiate(cfg.dataset)
    assert s.name == "sim-seed3" and len(s) == 80


def test_joint_rate_truth_matches_the_joint_file(folder: Path) -> None:
    joint = scipy.io.loadmat(str(folder / "train_joint0.mat"))
    with np.load(folder / "truth" / "body_states_joint.npz") as z:
        np.testing.assert_array_equal(z["t"], joint["ts"][0])
        np.testing.assert_array_equal(z["neck_yaw"], joint["head_angles"][0])
        np.testing.assert_array_equal(z["head_pitch"], joint["head_angles"][1])
        assert np.abs(z["roll"] - joint["rpy"][0]).max() < np.deg2rad(1.5)  # IMU noise 0.2 deg
        assert np.ptp(z["head_pitch"]) > 0.3 and np.ptp(z["neck_yaw"]) > 0.2  # the head moves


def test_people_walk_through_the_scans(tmp_path: Path) -> None:
    quiet = load_sim(seed=4, duration_s=3.0, rgbd=False, cache_dir=str(tmp_path))
    busy = load_sim(seed=4, duration_s=3.0, rgbd=False, n_people=3, cache_dir=str(tmp_path))
    a = np.stack([s.ranges for s in quiet.scans])
    b = np.stack([s.ranges for s in busy.scans])
    closer = (b > 0) & (a > 0) & (b < a - 0.3)  # something now stands in front of the walls
    assert closer.any(axis=1).mean() > 0.5
    moved = [np.flatnonzero(closer[i]) for i in (0, len(b) - 1)]
    assert not np.array_equal(moved[0], moved[1])  # and it moves


def test_generation_race_keeps_the_first_finished_folder(tmp_path: Path) -> None:
    target = tmp_path / "seq"
    target.mkdir()
    (target / "winner").write_text("other job")
    generate_atomic(target, SimParams(duration_s=1.0, rgbd=False))
    assert (target / "winner").read_text() == "other job"
    assert [p.name for p in tmp_path.iterdir()] == ["seq"]


def test_calibration_dir_gives_the_same_numbers(tmp_path: Path, shared_data: Path) -> None:
    kw = dict(seed=0, duration_s=1.0, kinect_scale=0.1, cache_dir=str(tmp_path))
    a = load_sim(**kw, calibration_dir=str(shared_data / "thor" / "cameraParam"))
    b = load_sim(**kw)
    np.testing.assert_allclose(a.calibration.ir.fc, np.array([364.4573624856433 * 51 / 512, 364.5428106269892 * 42 / 424]))  # 512x424 -> 51x42
    assert a.sources[0] == b.sources[0]  # same numbers -> same cached sequence


def test_stale_temp_folders_are_cleaned(tmp_path: Path) -> None:
    import os

    stale = tmp_path / ".tmp-seq-123-abcd"
    fresh = tmp_path / ".tmp-seq-456-ef01"
    stale.mkdir()
    fresh.mkdir()
    os.utime(stale, (0, 0))
    generate_atomic(tmp_path / "seq", SimParams(duration_s=1.0, rgbd=False))
    assert not stale.exists() and fresh.exists()  # a running job's folder is left alone


def test_cli_writes_a_sequence(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    from slamlab.cli.sim import main

    out = tmp_path / "cli"
    assert main([str(out), "--seed", "2", "--duration-s", "1.5", "--rgbd", "false"]) == 0
    assert "60 scans" in capsys.readouterr().out
    assert (out / "train_lidar0.mat").is_file() and not (out / "DEPTH_0.mat").exists()
    assert main([str(out), "--duration-s", "1"]) == 2  # exists, no --force
    assert "exists" in capsys.readouterr().err
    assert main([str(out), "--kinect-scale", "7", "--force"]) == 2
    assert "dataset.kinect_scale" in capsys.readouterr().err
