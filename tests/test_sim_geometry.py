"""Simulator building blocks against analytic cases: ray casting, lidar, Kinect, world."""

from __future__ import annotations

import numpy as np
import pytest

from slamlab import robot
from slamlab.datasets.sim.calib import sim_calibration
from slamlab.datasets.sim.kinect import camera_rays, render_depth, rgb_to_ir, visible_boxes
from slamlab.datasets.sim.raycast import HIT_FLOOR, cast_ray, cast_ray_reference
from slamlab.datasets.sim.sensors import BEAM_ANGLES, sensor_poses, simulate_scans
from slamlab.datasets.sim.trajectory import simulate_motion
from slamlab.datasets.sim.world import build_world, occupancy_grid
from slamlab.geometry import body_to_world

NO_CYL = np.zeros((0, 4))


def wall_at(x: float, height: float = 2.5) -> np.ndarray:
    """One wall whose near face is the plane x = `x`, 20 m wide."""
    return np.array([[x, -10.0, x + 0.1, 10.0, height]])


def test_raycast_matches_reference() -> None:
    world = build_world(1)
    rng = np.random.default_rng(0)
    for _ in range(300):
        o = np.array([rng.uniform(-2, 6), rng.uniform(-1, 5), rng.uniform(0.2, 2.0)])
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        t, h = cast_ray(*o, *d, world.boxes, NO_CYL, 30.0)
        t_ref, h_ref = cast_ray_reference(o, d, world.boxes, 30.0)
        assert h == h_ref
        assert t == pytest.approx(t_ref, abs=1e-9)


def test_lidar_centre_beam_range_to_a_wall() -> None:
    """A level robot at the origin facing a wall 3 m ahead: the centre beam reads 3 m
    (lidar origin is on the body's vertical axis), the beams along the wall read 3/cos(a)."""
    state = {"pose": np.zeros((1, 3)), "roll": np.zeros(1), "pitch": np.zeros(1), "neck_yaw": np.zeros(1), "head_pitch": np.zeros(1)}
    poses = sensor_poses(state, "lidar")
    assert poses[0, 2, 3] == pytest.approx(robot.COM_HEIGHT_M + robot.HEAD_ABOVE_COM_M + robot.LIDAR_ABOVE_HEAD_M)
    ranges, true_r, ids = simulate_scans(poses, wall_at(3.0), np.zeros((1, 0, 4)), seed=0, range_noise_m=0.0, dropout_fraction=0.0)
    assert BEAM_ANGLES[540] == 0.0
    assert ranges[0, 540] == pytest.approx(3.0, abs=1e-6)
    front = np.abs(BEAM_ANGLES) < np.deg2rad(70)
    np.testing.assert_allclose(true_r[0, front], 3.0 / np.cos(BEAM_ANGLES[front]), rtol=1e-9)
    # beams pointing away from the wall, level: no return -> 0, like the sensor reports
    assert np.all(ranges[0, np.abs(BEAM_ANGLES) > np.deg2rad(100)] == 0.0)
    # noise and dropouts behave as configured
    many = np.repeat(poses, 200, axis=0)
    noisy, _, _ = simulate_scans(many, wall_at(3.0), np.zeros((200, 0, 4)), seed=1, range_noise_m=0.01, dropout_fraction=0.01)
    centre = noisy[:, 500:580]
    assert np.std(centre[centre > 0] - true_r[0, 500:580][None, :].repeat(200, 0)[centre > 0]) == pytest.approx(0.01, rel=0.1)
    assert (centre == 0).mean() == pytest.approx(0.01, abs=0.006)


def test_pitched_head_beam_hits_floor_analytically() -> None:
    """Head pitched down 30 deg, nothing but the floor: the centre beam meets z = 0 at
    range h / sin(30 deg) with h the lidar height (pitch about the head joint)."""
    hp = np.deg2rad(30.0)
    state = {"pose": np.zeros((1, 3)), "roll": np.zeros(1), "pitch": np.zeros(1), "neck_yaw": np.zeros(1), "head_pitch": np.array([hp])}
    poses = sensor_poses(state, "lidar")
    ranges, _, ids = simulate_scans(poses, np.zeros((0, 5)), np.zeros((1, 0, 4)), seed=0, range_noise_m=0.0, dropout_fraction=0.0)
    z0 = poses[0, 2, 3]
    assert ids[0, 540] == HIT_FLOOR
    assert ranges[0, 540] == pytest.approx(z0 / np.sin(hp), abs=1e-5)


def test_people_are_seen_by_the_lidar() -> None:
    state = {"pose": np.zeros((1, 3)), "roll": np.zeros(1), "pitch": np.zeros(1), "neck_yaw": np.zeros(1), "head_pitch": np.zeros(1)}
    poses = sensor_poses(state, "lidar")
    person = np.array([[[2.0, 0.0, 0.25, 1.75]]])  # a 1.75 m tall person 2 m ahead (lidar at 1.41 m)
    ranges, _, ids = simulate_scans(poses, wall_at(5.0), person, seed=0, range_noise_m=0.0, dropout_fraction=0.0)
    assert ids[0, 540] == -3
    assert ranges[0, 540] == pytest.approx(1.75, abs=1e-6)


def test_kinect_depth_to_a_wall_and_rgb_baseline() -> None:
    """Camera level, facing a wall 4 m ahead: every wall pixel reads 4000 mm (depth is
    z, not ray length); the RGB camera sits ~52 mm to the IR camera's side (real extrinsics)."""
    calib = sim_calibration(0.25)
    state = {"pose": np.zeros((1, 3)), "roll": np.zeros(1), "pitch": np.zeros(1), "neck_yaw": np.zeros(1), "head_pitch": np.zeros(1)}
    cam = sensor_poses(state, "camera")[0]
    # camera optical axis is body +x, image x to the right (-y), image y down (-z)
    np.testing.assert_allclose(cam[:3, :3], robot.HEAD_R_CAMERA, atol=1e-12)
    depth, floor = render_depth(cam, calib.ir, camera_rays(calib.ir), wall_at(4.0, height=6.0), NO_CYL, np.random.default_rng(0), noise_mm=0.0)
    assert depth.shape == (calib.ir.height, calib.ir.width)
    wall_px = depth[: calib.ir.height // 3]  # upper third: the wall, not the floor
    assert np.all(wall_px == 4000)
    assert floor[-1].all() and not floor[0].any()
    rgb_in_ir = rgb_to_ir(calib)
    assert np.linalg.norm(rgb_in_ir[:3, 3]) == pytest.approx(0.0523, abs=1e-3)


def test_frustum_culling_is_conservative() -> None:
    world = build_world(0)
    calib = sim_calibration(0.25)
    rays = camera_rays(calib.ir)
    motion = simulate_motion(0, 30.0, world.loop_min, world.loop_max)
    state = motion.sample(np.arange(0.5, 30.0, 1.5))
    for cam in sensor_poses(state, "camera"):
        keep = visible_boxes(cam, calib.ir, world.boxes, 60.0)
        hit = set()
        for r in rays[::7]:
            d = cam[:3, :3] @ r
            _, h = cast_ray(*cam[:3, 3], *d, world.boxes, NO_CYL, 60.0)
            if h >= 0:
                hit.add(h)
        assert hit <= set(keep.tolist())
        assert len(keep) < len(world.boxes)


def test_world_layout_and_occupancy() -> None:
    a, b = build_world(0), build_world(0)
    np.testing.assert_array_equal(a.boxes, b.boxes)
    np.testing.assert_array_equal(a.floor.data, b.floor.data)
    c = build_world(1)
    assert not np.array_equal(a.boxes, c.boxes)
    # start (origin) and the whole loop route are clear of obstacles
    for x, y in [(0, 0), a.loop_min, a.loop_max, (a.loop_min[0], a.loop_max[1]), (a.loop_max[0], a.loop_min[1])]:
        inside = (a.boxes[:, 0] - 0.3 < x) & (x < a.boxes[:, 2] + 0.3) & (a.boxes[:, 1] - 0.3 < y) & (y < a.boxes[:, 3] + 0.3)
        assert not inside.any()
    occ = occupancy_grid(a, 0.05)
    assert occ.data.dtype == bool and 0.03 < occ.data.mean() < 0.3
    # the cell holding the origin is free; a cell on the outer south wall is occupied
    r0 = int((0 - occ.origin_xy[1]) / 0.05)
    c0 = int((0 - occ.origin_xy[0]) / 0.05)
    assert not occ.data[r0, c0]
    ys = int((a.bounds[1] - occ.origin_xy[1]) / 0.05)
    assert occ.data[ys, c0]
    # floor texture: many distinct colours (texture errors are measurable)
    assert len(np.unique(a.floor.data.reshape(-1, 3), axis=0)) > 200


def test_body_to_world_matches_the_course_chain() -> None:
    x, y, th, roll, pitch, ny, hp = 1.0, -2.0, 0.7, 0.03, -0.02, 0.4, 0.3
    T = body_to_world(x, y, th, roll, pitch, robot.COM_HEIGHT_M) @ robot.lidar_to_body(ny, hp)
    from slamlab.geometry import rot_x, rot_y, rot_z, trans

    course = trans(x, y, 0.93) @ rot_z(th) @ rot_y(pitch) @ rot_x(roll) @ trans(z=0.33) @ rot_z(ny) @ rot_y(hp) @ trans(z=0.15)
    np.testing.assert_allclose(T, course, atol=1e-12)
    # the simulator's lidar poses go through the same chain
    state = {"pose": np.array([[x, y, th]]), "roll": np.array([roll]), "pitch": np.array([pitch]),
             "neck_yaw": np.array([ny]), "head_pitch": np.array([hp])}
    np.testing.assert_allclose(sensor_poses(state, "lidar")[0], course, atol=1e-12)


def test_world_scale_sets_the_building_size():
    small, big = build_world(0), build_world(0, scale=1.5)
    span = lambda w: (w.bounds[2] - w.bounds[0], w.bounds[3] - w.bounds[1])  # noqa: E731
    assert span(big) == pytest.approx(tuple(1.5 * v for v in span(small)))
    # the route grows with the building and still starts at the origin, inside it
    assert big.loop_max[0] - big.loop_min[0] == pytest.approx(1.5 * (small.loop_max[0] - small.loop_min[0]))
    assert big.bounds[0] < 0 < big.bounds[2] and big.bounds[1] < 0 < big.bounds[3]
    occ = occupancy_grid(big, 0.05)
    for x, y in [(0, 0), big.loop_min, big.loop_max]:  # the route stays clear of walls
        r = int((y - occ.origin_xy[1]) / occ.resolution_m)
        c = int((x - occ.origin_xy[0]) / occ.resolution_m)
        assert not occ.data[r, c]
