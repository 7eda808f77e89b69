"""The simulator's hard `loops` layout (dataset.layout=loops, preset +experiment=sim_loops):
a long route that closes loops, never touches anything, drifts by metres, and leaves the
default `ring` layout exactly as it was."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
from omegaconf import OmegaConf

import slamlab
from slamlab.datasets.sim import SimParams, generate_atomic, load_sim
from slamlab.datasets.sim import calib as simcalib
from slamlab.datasets.sim import generate as gen
from slamlab.datasets.sim.generate import params_record, simulate_truth
from slamlab.datasets.sim.world import build_world, occupancy_grid

pytestmark = pytest.mark.slow  # generates the 300 m loops world and its walks

PRESET = Path(slamlab.__file__).parent / "conf" / "experiment" / "sim_loops.yaml"


def preset_params(**overrides: object) -> SimParams:
    """SimParams exactly as +experiment=sim_loops sets them (on top of SimParams' defaults,
    which conf/dataset/sim.yaml repeats)."""
    ds = OmegaConf.to_container(OmegaConf.load(PRESET))["dataset"]
    return SimParams(**{**ds, **overrides})


@pytest.fixture(scope="module")
def truth() -> tuple:
    """World, true motion and odometry of the preset (no sensor rendered: ~2 s)."""
    params = preset_params()
    world, motion, odo = simulate_truth(params)
    t = np.arange(int(params.duration_s * 40)) / 40.0  # lidar times
    return params, world, motion, odo, t


def arclength_samples(pose: np.ndarray, step_m: float = 0.25) -> tuple[np.ndarray, np.ndarray]:
    """Positions every `step_m` of distance walked along a path (N, 2+), and those distances."""
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(pose[:, :2], axis=0).T))])
    at = np.arange(0.0, s[-1], step_m)
    idx = np.minimum(np.searchsorted(s, at), len(s) - 1)
    return pose[idx, :2], at


def test_preset_selects_the_loops_layout() -> None:
    p = preset_params()
    assert p.layout == "loops" and p.n_people >= 3 and p.jerk_deg > 0 and p.neck_sweep_deg > 0
    assert p.kinect_rate_hz <= 1.0 and p.kinect_scale <= 0.25
    gen.validate_params(p)


def test_building_route_and_long_corridor() -> None:
    scale = preset_params().world_scale
    world = build_world(0, layout="loops", texture_res_m=0.1, scale=scale)
    xmin, ymin, xmax, ymax = world.bounds
    assert xmax - xmin == pytest.approx(40.0 * scale) and ymax - ymin == pytest.approx(30.0 * scale)
    route = world.route
    legs = np.hypot(*np.diff(route, axis=0).T)
    assert legs.sum() >= 150.0
    assert legs.max() >= 25.0  # one straight corridor walked end to end
    assert np.allclose(route[0], 0.0) and route[1, 1] == 0.0 and route[1, 0] > 0  # starts at the origin facing +x


def test_walk_is_long_and_closes_two_loops(truth) -> None:
    params, world, motion, odo, t = truth
    pts, s = arclength_samples(motion.pose)
    assert s[-1] >= 150.0
    d = np.hypot(pts[:, None, 0] - pts[None, :, 0], pts[:, None, 1] - pts[None, :, 1])
    later = (s[:, None] - s[None, :]) >= 30.0  # i walked at least 30 m after j
    back = (d < 1.0) & later
    first = np.flatnonzero(back.any(axis=1))  # samples that return to an earlier place
    assert first.size > 0
    # distinct closure events: returns separated by more than 10 m of walking, at places 5 m apart
    events = [first[0]]
    for i in first[1:]:
        if s[i] - s[events[-1]] > 10.0 and all(np.hypot(*(pts[i] - pts[e])) > 5.0 for e in events):
            events.append(i)
    assert len(events) >= 2, f"closures at {s[events]} m"
    assert s[events[0]] >= 30.0


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_route_never_touches_walls_clutter_or_people(seed: int) -> None:
    params = preset_params(seed=seed)
    params = dataclasses.replace(params, duration_s=params.duration_s + 7.5)  # a little past the end: the U-turn too
    world, motion, _ = simulate_truth(dataclasses.replace(params, texture_res_m=0.1))
    xy = motion.sample(np.arange(0.0, params.duration_s, 0.1))["pose"][:, :2]
    # the true occupancy grid (walls, tall clutter) is free within 0.4 m of the path
    occ = occupancy_grid(world, 0.05)
    r = np.floor((xy[:, 1] - occ.origin_xy[1]) / occ.resolution_m).astype(int)
    c = np.floor((xy[:, 0] - occ.origin_xy[0]) / occ.resolution_m).astype(int)
    k = int(round(0.4 / occ.resolution_m))
    for dr in range(-k, k + 1):
        for dc in range(-k, k + 1):
            assert not occ.data[r + dr, c + dc].any()
    # every box, low clutter included, keeps 0.8 m from the path
    b = world.boxes
    dx = np.maximum(np.maximum(b[None, :, 0] - xy[:, None, 0], xy[:, None, 0] - b[None, :, 2]), 0.0)
    dy = np.maximum(np.maximum(b[None, :, 1] - xy[:, None, 1], xy[:, None, 1] - b[None, :, 3]), 0.0)
    assert np.hypot(dx, dy).min() >= 0.8
    # people walk clear of the robot (centres 0.6 m apart at least)
    tt = np.arange(0.0, params.duration_s, 0.1)
    people = gen._people(params, world, tt)
    assert people.shape[1] == params.n_people
    gap = np.hypot(people[:, :, 0] - xy[:, None, 0], people[:, :, 1] - xy[:, None, 1])
    assert gap.min() >= 0.6


def test_odometry_drifts_by_metres(truth) -> None:
    params, world, motion, odo, t = truth
    true_xy = motion.sample(t)["pose"][:, :2]
    odo_xy = np.stack([np.interp(t, motion.t, odo[:, k]) for k in range(2)], axis=1)
    err = np.hypot(*(odo_xy - true_xy).T)
    assert np.sqrt(np.mean(err**2)) >= 1.0


def test_gait_jerks_and_neck_sweep(truth) -> None:
    params, world, motion, odo, t = truth
    ring = simulate_truth(dataclasses.replace(params, jerk_deg=0.0, neck_sweep_deg=0.0, texture_res_m=0.1))[1]
    np.testing.assert_array_equal(ring.pose, motion.pose)  # same walk, only body and head differ
    jerk = np.rad2deg(np.abs(motion.roll - ring.roll))
    assert jerk.max() > 0.6 * params.jerk_deg and (jerk > 1.0).mean() < 0.2  # occasional and large
    assert np.rad2deg(np.abs(motion.neck_yaw - ring.neck_yaw)).max() == pytest.approx(params.neck_sweep_deg, rel=0.02)


def test_loops_files_and_ground_truth(tmp_path: Path) -> None:
    """A short loops sequence reads back like the ring one, with all its ground truth."""
    kw = dict(layout="loops", duration_s=8.0, kinect_scale=0.1, kinect_rate_hz=1.0, label_every=2, n_people=3, jerk_deg=5.0, neck_sweep_deg=30.0)
    seq = load_sim(cache_dir=str(tmp_path), **kw)
    gt = seq.ground_truth
    assert len(seq) == 320 and gt.poses.shape == (320, 3)
    # occupancy (0.05 m, 0.5 m margin) and floor texture (0.02 m) cover the 40 x 30 m building
    assert gt.occupancy is not None and gt.occupancy.data.shape == (620, 820) and 0.02 < gt.occupancy.data.mean() < 0.2
    assert gt.floor_texture is not None and gt.floor_texture.data.shape == (1500, 2000, 3)
    assert gt.floor_texture.origin_xy == pytest.approx((-8.0, -4.0))
    assert set(gt.ground_labels) == {0, 2, 4, 6}
    folder = gen.sim_folder(SimParams(**kw), cache_dir=tmp_path)
    record = json.loads((folder / "sim.json").read_text())
    assert record["params"]["layout"] == "loops" and record["sim_version"] != gen.SIM_VERSION


def digest(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_ring_layout_is_unchanged(tmp_path: Path) -> None:
    """The new knobs at their defaults change neither the ring's files nor its cache key: the
    key is the one computed without them (as before they existed), and spelling them out
    gives the same key and the same bytes as leaving them out."""
    short = dict(seed=3, duration_s=3.0, kinect_scale=0.1, n_people=2)
    implicit = SimParams(**short)
    explicit = SimParams(**short, layout="ring", jerk_deg=0.0, jerk_every_s=8.0, neck_sweep_deg=0.0, neck_sweep_period_s=12.0)
    calib = simcalib.sim_calibration(0.1)
    old_fields = {k: v for k, v in dataclasses.asdict(implicit).items() if k not in gen.OMITTED_AT_DEFAULT}
    old_blob = json.dumps(
        {"version": gen.SIM_VERSION, "params": old_fields,
         "calib": [np.asarray(a, dtype=np.float64).round(12).tolist() for a in (calib.ir.fc, calib.ir.cc, calib.rgb.fc, calib.rgb.cc, calib.R, calib.T_mm)]},
        sort_keys=True,
    )  # fmt: skip
    old_key = hashlib.sha256(old_blob.encode()).hexdigest()[:16]
    assert gen._cache_key(implicit, calib) == gen._cache_key(explicit, calib) == old_key
    assert params_record(implicit) == old_fields
    a = digest(generate_atomic(tmp_path / "a", implicit))
    b = digest(generate_atomic(tmp_path / "b", explicit))
    assert a == b
    assert "layout" not in json.loads((tmp_path / "a" / "sim.json").read_text())["params"]
    # any new knob away from its default is a different sequence, with a different key
    for change in (dict(layout="loops"), dict(jerk_deg=3.0), dict(neck_sweep_deg=20.0)):
        assert gen._cache_key(dataclasses.replace(implicit, **change), calib) != old_key
