"""run_texture end to end on synthetic RGB-D: accuracy, bad input, outputs, memory."""

from __future__ import annotations

import dataclasses
import weakref

import numpy as np
import pytest
from slamlab.config.texture import TextureConfig, ThresholdGroundConfig
from slamlab.datasets.sim.calib import default_calibration
from slamlab.errors import ConfigError, DataError
from slamlab.eval.texture import texture_metrics
from slamlab.frames import GridImage
from slamlab.io.rundir import RunDirectory
from slamlab.texture.pipeline import (
    TextureResult,
    interpolate_poses,
    run_texture,
    run_textures,
    save_texture_outputs,
    texture_enabled,
)
from synthetic_rgbd import scaled_calibration, synthetic_sequence

GROUND = ThresholdGroundConfig()


def texture_cfg(**over) -> TextureConfig:
    # only the detection test needs the detectors' comparison (it is slow)
    return TextureConfig(**{"evaluate_detectors": [], **over})


@pytest.fixture(scope="module")
def seq():
    calib = scaled_calibration(default_calibration(), 0.25)
    poses = np.array([[0.25 * i, 0.05 * i, 0.08 * i] for i in range(8)])
    return synthetic_sequence(calib, poses, head_pitch_rad=0.6, wall_x_m=3.5, noise_mm=2.0)


@pytest.fixture(scope="module")
def grid():
    return GridImage(np.zeros((160, 200), dtype=np.float32), 0.05, (-3.0, -4.0))


def _times(seq):
    return np.arange(seq.rgbd_count, dtype=np.float64)


def test_true_poses_give_an_accurate_texture_and_drift_blurs_it(seq, grid):
    truth = seq.ground_truth
    good = run_texture(seq, _times(seq), truth.poses, grid, GROUND, texture_cfg())
    assert isinstance(good, TextureResult)
    assert good.color.shape == grid.data.shape + (3,) and good.count.shape == grid.data.shape
    assert good.resolution_m == grid.resolution_m and good.origin_xy == grid.origin_xy
    assert good.frames_used == seq.rgbd_count and not good.skipped
    m_good = texture_metrics(good, truth)
    assert m_good["covered_area_m2"] > 3.0
    assert m_good["colour_error"] < 8.0, m_good

    drift = truth.poses.copy()
    drift[:, 0] *= 1.05  # 5 % scale error, like walking odometry
    drift[:, 2] += np.linspace(0, 0.08, len(drift))
    bad = run_texture(seq, _times(seq), drift, grid, GROUND, texture_cfg())
    m_bad = texture_metrics(bad, truth)
    assert m_bad["colour_error"] > m_good["colour_error"] + 5.0, (m_good, m_bad)
    # Unobserved cells stay blank.
    assert np.all(good.color[~good.covered] == 0)
    # One cloud point per covered cell, on the floor.
    assert good.floor_points.shape == (int(good.covered.sum()), 3)
    assert np.abs(good.floor_points[:, 2]).max() < 0.05


def test_detection_metrics_per_detector(seq, grid):
    cfg = texture_cfg(evaluate_detectors=["threshold", "plane", "image_plane"])
    res = run_texture(seq, _times(seq), seq.ground_truth.poses, grid, GROUND, cfg)
    m = texture_metrics(res, seq.ground_truth)
    assert set(m["detection"]) == {"threshold", "plane", "image_plane"}
    for name, d in m["detection"].items():
        assert d["frames"] == seq.rgbd_count
        assert d["precision"] > 0.95 and d["recall"] > 0.95, (name, d)
    # Without truth: counters only, no colour error, and it is JSON-friendly.
    plain = texture_metrics(res, None)
    assert "colour_error" not in plain and plain["frames_used"] == seq.rgbd_count
    import json

    json.dumps(plain)


def test_robust_average_ignores_a_misplaced_frame(seq, grid):
    truth = seq.ground_truth
    frames = list(seq.rgbd())
    # The last frame's colour is garbage (e.g. a frame paired with the wrong RGB image).
    garbage = dataclasses.replace(frames[-1], rgb=np.full_like(frames[-1].rgb, 255))
    bad_seq = dataclasses.replace(seq, rgbd=lambda: iter(frames[:-1] + [garbage]))
    mean = texture_metrics(run_texture(bad_seq, _times(seq), truth.poses, grid, GROUND, texture_cfg()), truth)
    robust_res = run_texture(bad_seq, _times(seq), truth.poses, grid, GROUND, texture_cfg(average="robust"))
    robust = texture_metrics(robust_res, truth)
    assert robust_res.points_rejected > 0
    assert robust["colour_error"] < mean["colour_error"]


def test_bad_frames_are_skipped_and_counted(seq, grid):
    frames = list(seq.rgbd())
    f = frames
    bad = [
        f[0],
        dataclasses.replace(f[1], rgb=None),  # depth without colour
        dataclasses.replace(f[2], rgb_t=f[2].t + 0.5),  # colour from another time
        dataclasses.replace(f[3], depth_m=np.zeros_like(f[3].depth_m)),  # no valid depth
        dataclasses.replace(f[4], t=100.0),  # far outside the trajectory
        dataclasses.replace(f[5], depth_m=np.zeros(7, dtype=np.float32)),  # not an image
        dataclasses.replace(f[6], rgb=np.zeros((4, 4), dtype=np.uint8)),  # not a colour image
        dataclasses.replace(f[7], camera_to_body=np.eye(3)),  # malformed transform
    ]
    s = dataclasses.replace(seq, rgbd=lambda: iter(bad))
    calls = []
    res = run_texture(s, _times(seq), seq.ground_truth.poses, grid, GROUND, texture_cfg(), progress=lambda d, t: calls.append((d, t)))
    assert res.frames_total == 8 and res.frames_used == 1
    assert res.skipped == {
        "no_rgb": 1,
        "rgb_time_mismatch": 1,
        "no_valid_depth": 1,
        "outside_trajectory": 1,
        "bad_depth": 1,
        "bad_rgb": 1,
        "bad_frame": 1,
    }
    assert calls[-1] == (8, 8)
    assert res.summary()["frames_skipped"] == 7


def test_reader_error_midway_keeps_what_was_built(seq, grid):
    frames = list(seq.rgbd())

    def stream():
        yield frames[0]
        yield frames[1]
        raise DataError("RGB_0_2.mat", "truncated file", record=301, field="image")

    s = dataclasses.replace(seq, rgbd=stream)
    res = run_texture(s, _times(seq), seq.ground_truth.poses, grid, GROUND, texture_cfg())
    assert res.frames_used == 2 and res.covered.any()
    assert "RGB_0_2.mat" in res.messages[0]


def test_missing_inputs_are_clear_errors(seq, grid):
    poses = seq.ground_truth.poses
    with pytest.raises(DataError, match="calibration"):
        run_texture(dataclasses.replace(seq, calibration=None), _times(seq), poses, grid, GROUND, texture_cfg())
    with pytest.raises(DataError, match="no RGB-D"):
        run_texture(dataclasses.replace(seq, rgbd=None), _times(seq), poses, grid, GROUND, texture_cfg())
    with pytest.raises(ConfigError, match="times"):
        run_texture(seq, _times(seq)[:3], poses, grid, GROUND, texture_cfg())
    with pytest.raises(ConfigError, match="texture.stride"):
        run_texture(seq, _times(seq), poses, grid, GROUND, texture_cfg(stride=0))
    with pytest.raises(ConfigError, match="texture.average"):
        run_texture(seq, _times(seq), poses, grid, GROUND, texture_cfg(average="median"))
    assert texture_enabled(seq, texture_cfg())
    assert not texture_enabled(seq, texture_cfg(enabled=False))
    assert not texture_enabled(dataclasses.replace(seq, rgbd=None), texture_cfg())


def test_frames_are_streamed_not_kept(seq, grid):
    frames = list(seq.rgbd())
    alive: list[weakref.ref] = []

    def stream():
        for f in frames:
            # A fresh copy per frame, as a reader does; older copies must be gone by now.
            rgb = f.rgb.copy()
            alive.append(weakref.ref(rgb))
            assert sum(r() is not None for r in alive) <= 2
            yield dataclasses.replace(f, rgb=rgb)

    s = dataclasses.replace(seq, rgbd=stream)
    res = run_texture(s, _times(seq), seq.ground_truth.poses, grid, GROUND, texture_cfg())
    assert res.frames_used == len(frames)


def test_stride_and_frame_thinning(seq, grid):
    poses = seq.ground_truth.poses
    full = run_texture(seq, _times(seq), poses, grid, GROUND, texture_cfg())
    half = run_texture(seq, _times(seq), poses, grid, GROUND, texture_cfg(stride=2, frame_every=2))
    assert half.frames_used == 4 and half.frames_thinned == 4
    assert half.points_added < full.points_added / 4
    capped = run_texture(seq, _times(seq), poses, grid, GROUND, texture_cfg(max_frames=3))
    assert capped.frames_used == 3


def test_interpolate_poses():
    t = np.array([0.0, 1.0, 2.0])
    p = np.array([[0.0, 0.0, 3.0], [1.0, 2.0, -3.0], [2.0, 4.0, -2.9]])
    q, gap = interpolate_poses(t, p, np.array([0.5, 1.5, -1.0, 3.5]))
    assert q[0, 0] == pytest.approx(0.5) and q[0, 1] == pytest.approx(1.0)
    # 3.0 -> -3.0 is +0.283 rad through pi, not -6 rad through 0.
    assert abs(q[0, 2]) == pytest.approx(np.pi, abs=0.2)
    assert gap.tolist() == [0.0, 0.0, 1.0, 1.5]
    assert q[2].tolist() == p[0].tolist()  # clamped
    # Unsorted times (CARMEN clocks step back) are sorted first.
    order = [2, 0, 1]
    q2, _ = interpolate_poses(t[order], p[order], 0.5)
    assert np.allclose(q2, q[0])


def test_save_outputs(seq, grid, tmp_path):
    res = run_texture(seq, _times(seq), seq.ground_truth.poses, grid, GROUND, texture_cfg())
    occ = np.full(grid.data.shape, 0.5)
    out = save_texture_outputs(res, occ, RunDirectory(tmp_path).texture_files("slam"))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["floor.ply", "texture.png", "texture_over_map.png"]
    import matplotlib.pyplot as plt
    import open3d as o3d

    img = plt.imread(out["texture"])
    assert img.shape == grid.data.shape + (4,)
    # Top row of the PNG is the highest y (row 0 of the grid is the lowest).
    assert np.array_equal(img[::-1, :, 3] > 0, res.covered)
    over = plt.imread(out["over_map"])
    assert over.shape[:2] == grid.data.shape
    cloud = o3d.io.read_point_cloud(str(out["cloud"]))
    assert 0 < len(cloud.points) <= res.floor_points.shape[0] and cloud.has_colors()
    save_texture_outputs(res, occ, RunDirectory(tmp_path).texture_files("odometry"))
    assert {"texture_odometry.png", "texture_odometry_over_map.png", "floor_odometry.ply"} <= {p.name for p in tmp_path.iterdir()}
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".partial")]
    with pytest.raises(ValueError):
        save_texture_outputs(res, np.zeros((3, 3)), RunDirectory(tmp_path / "x").texture_files("slam"))


def test_save_empty_result(seq, grid, tmp_path):
    s = dataclasses.replace(seq, rgbd=lambda: iter([]))
    res = run_texture(s, _times(seq), seq.ground_truth.poses, grid, GROUND, texture_cfg())
    assert res.frames_total == 0 and res.messages
    save_texture_outputs(res, np.zeros(grid.data.shape), RunDirectory(tmp_path).texture_files("slam"))
    assert (tmp_path / "texture.png").is_file() and (tmp_path / "floor.ply").is_file()


def test_covered_fraction_counts_floor_not_walls():
    # truth: a 2 x 2 m floor texture; the true occupancy (coarser, other origin) marks its
    # left half as wall. A texture grid (finer, other origin) that covers exactly the right
    # half has covered all of the floor.
    from slamlab.frames import GridImage, GroundTruth
    from slamlab.texture.pipeline import TextureResult

    tex = GridImage(np.full((100, 100, 3), 128, np.uint8), 0.02, (0.0, 0.0))
    occ = np.zeros((12, 12), bool)
    occ[:, :6] = True  # x in [-0.2, 1.0): wall
    truth = GroundTruth(poses=np.zeros((1, 3)), occupancy=GridImage(occ, 0.2, (-0.2, -0.2)), floor_texture=tex)
    res_m, origin = 0.05, (-0.5, -0.5)
    count = np.zeros((60, 60), np.int64)
    xs = origin[0] + (np.arange(60) + 0.5) * res_m
    count[:, (xs > 1.0) & (xs < 2.0)] = 1
    result = TextureResult(color=np.full((60, 60, 3), 128, np.uint8), count=count, resolution_m=res_m, origin_xy=origin,
                           floor_points=np.zeros((0, 3)), floor_colors=np.zeros((0, 3), np.uint8), detector="threshold")
    m = texture_metrics(result, truth)
    assert m["covered_fraction"] == pytest.approx(1.0)
    assert m["colour_error"] == pytest.approx(0.0)


def test_one_pass_over_the_stream_equals_a_run_per_trajectory(seq, grid):
    """`run_textures` reads each frame once and places it with every trajectory: each result
    is what `run_texture` builds for that trajectory alone (colours, counts, cloud, counters,
    frames outside the trajectory's span, `max_frames`). Only the first one scores the other
    detectors."""
    truth = seq.ground_truth.poses
    drift = truth.copy()
    drift[:, 0] *= 1.05
    times = _times(seq)
    cfg = texture_cfg(max_frames=6, evaluate_detectors=["threshold", "image_plane"])
    both = run_textures(seq, times, {"truth": truth, "drift": drift}, grid, GROUND, cfg)
    for name, poses in (("truth", truth), ("drift", drift)):
        alone = run_texture(seq, times, poses, grid, GROUND, cfg)
        got = both[name]
        assert np.array_equal(got.color, alone.color) and np.array_equal(got.count, alone.count)
        assert np.array_equal(got.floor_points, alone.floor_points) and np.array_equal(got.floor_colors, alone.floor_colors)
        assert (got.frames_used, got.frames_thinned, got.skipped) == (alone.frames_used, alone.frames_thinned, alone.skipped)
    assert both["truth"].frames_used == 6 and both["truth"].frames_thinned == seq.rgbd_count - 6
    assert not np.array_equal(both["truth"].color, both["drift"].color)
    assert set(both["truth"].detection) == {"threshold", "image_plane"} and set(both["drift"].detection) <= {"threshold"}
    # trajectories that end after 5 frames: the last frames are skipped, as alone
    cfg = texture_cfg(max_pose_gap_s=0.5)
    short = run_textures(seq, times[:5], {"truth": truth[:5], "drift": drift[:5]}, grid, GROUND, cfg)
    alone = run_texture(seq, times[:5], drift[:5], grid, GROUND, cfg)
    assert short["drift"].skipped == alone.skipped == {"outside_trajectory": seq.rgbd_count - 5}
    assert np.array_equal(short["drift"].color, alone.color) and short["drift"].frames_used == 5
