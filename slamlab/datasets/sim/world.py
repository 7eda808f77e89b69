"""The simulated building: a floor plan of axis-aligned 3D boxes on the floor z = 0, and a
floor texture.

Layout (plan coordinates, metres; shifted so the robot starts at the origin facing +x):
a 2.8 m wide corridor ring around a central block of two rooms, with side rooms in the
band between the corridor and the outer walls. The robot walks the ring, so every lap
closes a loop. Door positions, partitions, clutter and floor colours vary with the seed;
the corridor itself is always clear so the route never collides.

Every obstacle is a box [x0, x1] x [y0, y1] x [0, height]: walls are thin boxes (2.5 m),
pillars are tall narrow boxes, and clutter is often lower than the lidar (1.41 m) so that a
horizontal scan misses it but a scan with the head pitched down sees it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slamlab.frames import GridImage

# The route: a rectangle (plan coordinates) walked counter-clockwise; start on the south leg.
LOOP_MIN = (4.0, 3.5)
LOOP_MAX = (12.0, 9.5)
START_PLAN = (6.0, 3.5)  # becomes the world origin
CORRIDOR_HALF_WIDTH_M = 1.4
WORLD_SIZE_PLAN = (17.0, 13.5)  # outer walls enclose [0, 17] x [0, 13.5]
WALL_HEIGHT_M = 2.5
WALL_THICKNESS_M = 0.12


@dataclass(frozen=True, slots=True)
class World:
    """Boxes (K, 5) [x0, y0, x1, y1, height] in metres, world frame (robot start = origin);
    `colors` (K, 3) uint8 plain colour per box; `kind` (K,) 0 wall, 1 pillar, 2 clutter.
    `floor` is the floor texture (uint8 RGB GridImage) covering the building.
    `bounds` = (xmin, ymin, xmax, ymax) of the outer walls."""

    boxes: np.ndarray
    colors: np.ndarray
    kind: np.ndarray
    floor: GridImage
    bounds: tuple[float, float, float, float]
    loop_min: tuple[float, float]
    loop_max: tuple[float, float]


def _wall(x0: float, y0: float, x1: float, y1: float) -> list[float]:
    """A wall along a horizontal or vertical centre line, WALL_THICKNESS_M thick."""
    h = WALL_THICKNESS_M / 2.0
    return [min(x0, x1) - h, min(y0, y1) - h, max(x0, x1) + h, max(y0, y1) + h, WALL_HEIGHT_M]


def _wall_with_doors(a: tuple[float, float], b: tuple[float, float], doors: list[tuple[float, float]]) -> list[list[float]]:
    """Wall segments from a to b (axis-aligned) leaving gaps at `doors` (intervals along it)."""
    horizontal = a[1] == b[1]
    lo, hi = (a[0], b[0]) if horizontal else (a[1], b[1])
    cuts = sorted(doors)
    out = []
    s = lo
    for d0, d1 in cuts + [(hi, hi)]:
        if d0 > s:
            if horizontal:
                out.append(_wall(s, a[1], d0, a[1]))
            else:
                out.append(_wall(a[0], s, a[0], d0))
        s = d1
    return out


def _overlaps(box: list[float], others: list[list[float]], margin: float) -> bool:
    for o in others:
        if box[0] < o[2] + margin and box[2] > o[0] - margin and box[1] < o[3] + margin and box[3] > o[1] - margin:
            return True
    return False


def build_world(seed: int, n_clutter: int = 22, texture_res_m: float = 0.02, scale: float = 1.0) -> World:
    """Build the seeded floor plan and floor texture.

    `n_clutter`: number of clutter boxes/pillars placed in rooms and along corridor walls;
    `texture_res_m`: floor texture resolution (m per pixel); `scale`: the building's size
    relative to the 17 x 13.5 m plan (>= 0.85; corridors, doors and clutter keep their size).
    """
    rng = np.random.default_rng([seed, 101])
    W, H = (v * scale for v in WORLD_SIZE_PLAN)
    (lx0, ly0), (lx1, ly1) = ((v * scale for v in LOOP_MIN), (v * scale for v in LOOP_MAX))
    hw = CORRIDOR_HALF_WIDTH_M
    walls: list[list[float]] = []
    # Outer walls of the building.
    walls += [_wall(0, 0, W, 0), _wall(W, 0, W, H), _wall(W, H, 0, H), _wall(0, H, 0, 0)]
    # Inner block (two rooms split at a seeded x), doors on its south and north walls.
    bx0, by0, bx1, by1 = lx0 + hw, ly0 + hw, lx1 - hw, ly1 - hw
    split = float(rng.uniform(bx0 + 2.0, bx1 - 2.0))
    d_s = float(rng.uniform(bx0 + 0.4, split - 1.3))
    d_n = float(rng.uniform(split + 0.4, bx1 - 1.3))
    walls += _wall_with_doors((bx0, by0), (bx1, by0), [(d_s, d_s + 0.9)])
    walls += _wall_with_doors((bx0, by1), (bx1, by1), [(d_n, d_n + 0.9)])
    walls += [_wall(bx0, by0, bx0, by1), _wall(bx1, by0, bx1, by1), _wall(split, by0, split, by1)]
    # Outer corridor wall with one door per side into the side rooms.
    ox0, oy0, ox1, oy1 = lx0 - hw, ly0 - hw, lx1 + hw, ly1 + hw

    def door(lo: float, hi: float, width: float) -> tuple[float, float]:
        s = float(rng.uniform(lo, hi - width))
        return (s, s + width)

    walls += _wall_with_doors((ox0, oy0), (ox1, oy0), [door(ox0 + 3.5, ox1 - 0.5, 1.1)])
    walls += _wall_with_doors((ox1, oy0), (ox1, oy1), [door(oy0 + 0.5, oy1 - 0.5, 1.3)])
    walls += _wall_with_doors((ox0, oy1), (ox1, oy1), [door(ox0 + 0.5, ox1 - 0.5, 1.1)])
    walls += _wall_with_doors((ox0, oy0), (ox0, oy1), [door(oy0 + 0.5, oy1 - 0.5, 1.0)])
    # Partitions in the band between the corridor and the outer walls (rooms).
    x_s = float(rng.uniform(ox0 + 1.5, lx0 + 2.5))
    walls.append(_wall(x_s, 0, x_s, oy0))
    y_e = float(rng.uniform(oy0 + 2.0, oy1 - 1.5))
    walls.append(_wall(ox1, y_e, W, y_e))
    x_n = float(rng.uniform(ox0 + 3.0, ox1 - 2.0))
    walls.append(_wall(x_n, oy1, x_n, H))
    y_w = float(rng.uniform(oy0 + 1.0, oy1 - 2.0))
    walls.append(_wall(0, y_w, ox0, y_w))

    # Clutter: boxes and pillars in the side rooms and against the corridor walls, never in
    # the middle 1.7 m of the corridor (the route) and never on top of each other or a wall.
    clutter: list[list[float]] = []
    kinds: list[int] = []
    attempts = 0
    while len(clutter) < n_clutter and attempts < 5000:
        attempts += 1
        pillar = rng.random() < 0.2
        if pillar:
            sx = sy = float(rng.uniform(0.2, 0.35))
            h = WALL_HEIGHT_M
        else:
            sx, sy = (float(v) for v in rng.uniform(0.25, 0.55, size=2))
            # Half the clutter is below the lidar plane (seen only with the head pitched down).
            h = float(rng.uniform(0.3, 0.9)) if rng.random() < 0.5 else float(rng.uniform(1.6, 2.2))
        x = float(rng.uniform(0.2, W - 0.2 - sx))
        y = float(rng.uniform(0.2, H - 0.2 - sy))
        box = [x, y, x + sx, y + sy, h]
        # Distance of the box from the route rectangle's centre line must exceed 0.85 m.
        in_ring = (ox0 < x + sx and x < ox1 and oy0 < y + sy and y < oy1) and not (
            bx0 < x and x + sx < bx1 and by0 < y and y + sy < by1
        )
        if in_ring:
            # nearest point of the route to the box (clamped to the rectangle boundary)
            dx = max(lx0 - (x + sx), 0.0, x - lx1)
            dy = max(ly0 - (y + sy), 0.0, y - ly1)
            inside_loop = lx0 < x and x + sx < lx1 and ly0 < y and y + sy < ly1
            if inside_loop:
                dist = min(x - lx0, lx1 - (x + sx), y - ly0, ly1 - (y + sy))
            else:
                dist = float(np.hypot(dx, dy))
            if dist < 0.85:
                continue
        if _overlaps(box, walls, 0.05) or _overlaps(box, clutter, 0.3):
            continue
        clutter.append(box)
        kinds.append(1 if pillar else 2)

    boxes = np.array(walls + clutter, dtype=np.float64)
    kind = np.array([0] * len(walls) + kinds, dtype=np.int8)
    # Plain colours: walls pale and varied (so texture bleeding is visible), clutter saturated.
    colors = np.empty((len(boxes), 3), dtype=np.uint8)
    colors[: len(walls)] = rng.integers(150, 235, size=(len(walls), 3))
    colors[len(walls) :] = rng.integers(20, 220, size=(len(clutter), 3))

    shift = np.array(START_PLAN) * scale
    boxes[:, [0, 2]] -= shift[0]
    boxes[:, [1, 3]] -= shift[1]
    floor = floor_texture(rng, W, H, texture_res_m, origin=(-shift[0], -shift[1]))
    return World(
        boxes=boxes,
        colors=colors,
        kind=kind,
        floor=floor,
        bounds=(-shift[0], -shift[1], W - shift[0], H - shift[1]),
        loop_min=(lx0 - shift[0], ly0 - shift[1]),
        loop_max=(lx1 - shift[0], ly1 - shift[1]),
    )


def floor_texture(rng: np.random.Generator, width_m: float, height_m: float, res_m: float, origin: tuple[float, float]) -> GridImage:
    """A distinct, non-repeating floor: 0.5 m tiles in random colours with dark grout,
    overlaid with coloured discs and stripes (so a misplaced texture pixel is measurable).
    Row 0 is the lowest y (GridImage convention)."""
    nx, ny = int(round(width_m / res_m)), int(round(height_m / res_m))
    xs = (np.arange(nx) + 0.5) * res_m
    ys = (np.arange(ny) + 0.5) * res_m
    X, Y = np.meshgrid(xs, ys)
    tile = 0.5
    ntx, nty = int(np.ceil(width_m / tile)), int(np.ceil(height_m / tile))
    palette = rng.integers(60, 230, size=(nty, ntx, 3)).astype(np.uint8)
    img = palette[(Y // tile).astype(int), (X // tile).astype(int)]
    grout = (np.mod(X, tile) < 0.02) | (np.mod(Y, tile) < 0.02)
    img[grout] = (40, 40, 40)
    for _ in range(40):  # discs
        cx, cy = rng.uniform(0, width_m), rng.uniform(0, height_m)
        r = rng.uniform(0.15, 0.6)
        img[(X - cx) ** 2 + (Y - cy) ** 2 < r * r] = rng.integers(0, 256, size=3)
    for _ in range(12):  # straight stripes at random angles
        a = rng.uniform(0, np.pi)
        c = rng.uniform(0, width_m) * np.cos(a) + rng.uniform(0, height_m) * np.sin(a)
        d = X * np.cos(a) + Y * np.sin(a) - c
        img[np.abs(d) < rng.uniform(0.03, 0.1)] = rng.integers(0, 256, size=3)
    return GridImage(data=np.ascontiguousarray(img, dtype=np.uint8), resolution_m=res_m, origin_xy=(float(origin[0]), float(origin[1])))


def occupancy_grid(world: World, resolution_m: float = 0.05, min_height_m: float = 1.2, margin_m: float = 0.5) -> GridImage:
    """Rasterise the boxes taller than `min_height_m` (what a head-level 2D lidar maps) into a
    bool grid (True = occupied). A cell is occupied if it overlaps a box at all, so thin walls
    are never lost between cell centres. The grid covers the building plus `margin_m`."""
    xmin, ymin, xmax, ymax = world.bounds
    ox, oy = xmin - margin_m, ymin - margin_m
    nx = int(np.ceil((xmax - xmin + 2 * margin_m) / resolution_m))
    ny = int(np.ceil((ymax - ymin + 2 * margin_m) / resolution_m))
    grid = np.zeros((ny, nx), dtype=bool)
    for b in world.boxes[world.boxes[:, 4] >= min_height_m]:
        c0 = int(np.floor((b[0] - ox) / resolution_m))
        c1 = int(np.ceil((b[2] - ox) / resolution_m))
        r0 = int(np.floor((b[1] - oy) / resolution_m))
        r1 = int(np.ceil((b[3] - oy) / resolution_m))
        grid[max(r0, 0) : max(r1, 0), max(c0, 0) : max(c1, 0)] = True
    return GridImage(data=grid, resolution_m=resolution_m, origin_xy=(float(ox), float(oy)))
