"""People walking through a simulated building: moving vertical cylinders the lidar and the
Kinect see, which a map should not keep (the THOR sequence's `n_people`, and the CARMEN
probe's `--people` in benchmarks/sim_carmen.py)."""

from __future__ import annotations

import numpy as np

from slamlab.datasets.sim.world import World

RADIUS_M = 0.25  # a person's cylinder (m)
HEIGHT_M = 1.75


def walking_people(world: World, n: int, seed: int, t_rel: np.ndarray) -> np.ndarray:
    """(len(t_rel), n, 4) cylinders [x, y, radius, height] (m) at the times `t_rel` (s from the
    start): people pacing up and down at 0.6-1.0 m/s, each on a lane of its own choosing. In the
    `loops` layout a lane is a corridor between two junctions, 0.65 m to either side of its
    centre line (`World.lanes`: clear of the route and of everything standing in the
    corridor); in the `campus` layout (`sim.campus`) a street between two junctions, 0.65 m to
    either side of a sidewalk line 2 m off its centre line; in the `ring` layout a leg of the
    loop, 0.9 m to the side of the robot's route.
    Seeded by `seed` alone: the same people for the same seed whatever else is simulated."""
    out = np.zeros((t_rel.size, n, 4))
    if n == 0:
        return out
    rng = np.random.default_rng([seed, 505])
    if world.lanes:
        for j in range(n):
            (ax, ay), (bx, by) = world.lanes[int(rng.integers(0, len(world.lanes)))]
            off = 0.65 * (1.0 if rng.random() < 0.5 else -1.0)
            a = np.array([ax, ay]) + (np.array([0.0, off]) if ay == by else np.array([off, 0.0]))
            b = a + np.array([bx - ax, by - ay])
            _pace(out[:, j], a, b, rng, t_rel)
        return out
    (x0, y0), (x1, y1) = world.loop_min, world.loop_max
    legs = [((x0, y0 - 0.9), (x1, y0 - 0.9)), ((x1 + 0.9, y0), (x1 + 0.9, y1)), ((x1, y1 + 0.9), (x0, y1 + 0.9)), ((x0 - 0.9, y1), (x0 - 0.9, y0))]
    for j in range(n):
        a, b = (np.array(v) for v in legs[int(rng.integers(0, 4))])
        _pace(out[:, j], a, b, rng, t_rel)
    return out


def _pace(person: np.ndarray, a: np.ndarray, b: np.ndarray, rng: np.random.Generator, t_rel: np.ndarray) -> None:
    """Fill `person` (T, 4) with a walk from `a` to `b` and back, from a random place on it."""
    length = float(np.linalg.norm(b - a))
    speed = rng.uniform(0.6, 1.0)
    s = (rng.uniform(0, 2 * length) + speed * t_rel) % (2 * length)
    s = np.where(s > length, 2 * length - s, s) / length  # walk there and back
    person[:, :2] = a + s[:, None] * (b - a)
    person[:, 2] = RADIUS_M
    person[:, 3] = HEIGHT_M
