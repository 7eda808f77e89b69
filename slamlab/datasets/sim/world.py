"""The simulated building: a floor plan of axis-aligned 3D boxes on the floor z = 0, and a
floor texture. Two layouts (`dataset.layout`):

`ring` (default; plan coordinates, metres, shifted so the robot starts at the origin facing
+x): a 2.8 m wide corridor ring around a central block of two rooms, with side rooms in the
band between the corridor and the outer walls, 17 x 13.5 m. The robot walks the ring, so
every lap closes a loop. Door positions, partitions, clutter and floor colours vary with the
seed; the corridor itself is always clear so the route never collides.

`loops` (the hard one, 40 x 30 m): a corridor network shaped like the letter theta -- an
outer corridor ring 4 m inside the outer walls plus a middle corridor joining its south and
north sides -- around two blocks of rooms, with side rooms between the ring and the outer
walls. The south corridor is 32 m long and straight and nearly featureless (plain walls, two
doors, one junction); the other corridors have doors, pillars, cabinets and benches against
their walls. The route (`World.route`) is a figure-eight of 176 m: up the middle corridor
and round the west ring, back through the start and the whole south corridor, round the east
ring, down the middle corridor again and back to the start -- so it comes back to mapped
places after 76 m and 146 m of walking. Clutter and people keep out of the middle 2 m of
every corridor (people walk 0.65 m to either side of the centre line), so the route never
collides with anything.

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
LAYOUTS = ("ring", "loops")
# The `loops` layout (plan coordinates, metres): outer walls enclose [0, 40] x [0, 30] (times
# `scale`); corridor centre lines run LOOPS_INSET_M inside the outer walls (2.6 m of side rooms
# beyond the 2.8 m corridor) plus one north-south corridor through the middle; the robot
# starts on the south corridor LOOPS_START_EAST_M east of its west end, facing +x (east).
LOOPS_SIZE_PLAN = (40.0, 30.0)
LOOPS_INSET_M = 4.0
LOOPS_START_EAST_M = 4.0
LOOPS_CLEAR_M = 1.0  # nothing stands within this of a corridor centre line (the route and people)


@dataclass(frozen=True, slots=True)
class World:
    """Boxes (K, 5) [x0, y0, x1, y1, height] in metres, world frame (robot start = origin);
    `colors` (K, 3) uint8 plain colour per box; `kind` (K,) 0 wall, 1 pillar, 2 clutter.
    `floor` is the floor texture (uint8 RGB GridImage) covering the building.
    `bounds` = (xmin, ymin, xmax, ymax) of the outer walls.
    `layout` "ring": the route is the rectangle `loop_min`..`loop_max` walked counter-clockwise.
    `layout` "loops": the route is the polyline `route` (K, 2) from the origin (its first leg
    points along +x); `lanes` are the corridor centre lines between junctions, stopping short
    of them, ((x0, y0), (x1, y1)): people pace along them 0.65 m to either side, so they never
    cross the route; `loop_min`, `loop_max` bound the route."""

    boxes: np.ndarray
    colors: np.ndarray
    kind: np.ndarray
    floor: GridImage
    bounds: tuple[float, float, float, float]
    loop_min: tuple[float, float]
    loop_max: tuple[float, float]
    layout: str = "ring"
    route: np.ndarray | None = None
    lanes: tuple[tuple[tuple[float, float], tuple[float, float]], ...] = ()


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


def _random_clutter(rng: np.random.Generator, W: float, H: float) -> tuple[list[float], float, float, bool]:
    """A random clutter box [x0, y0, x1, y1, height] (m) inside [0, W] x [0, H], its sizes
    sx, sy (m), and whether it is a pillar (20 %). Half the other boxes are lower than the lidar plane (seen only with
    the head pitched down)."""
    pillar = rng.random() < 0.2
    if pillar:
        sx = sy = float(rng.uniform(0.2, 0.35))
        h = WALL_HEIGHT_M
    else:
        sx, sy = (float(v) for v in rng.uniform(0.25, 0.55, size=2))
        h = float(rng.uniform(0.3, 0.9)) if rng.random() < 0.5 else float(rng.uniform(1.6, 2.2))
    x = float(rng.uniform(0.2, W - 0.2 - sx))
    y = float(rng.uniform(0.2, H - 0.2 - sy))
    return [x, y, x + sx, y + sy, h], sx, sy, pillar


def _overlaps(box: list[float], others: list[list[float]], margin: float) -> bool:
    for o in others:
        if box[0] < o[2] + margin and box[2] > o[0] - margin and box[1] < o[3] + margin and box[3] > o[1] - margin:
            return True
    return False


def build_world(seed: int, n_clutter: int = 22, texture_res_m: float = 0.02, scale: float = 1.0, layout: str = "ring") -> World:
    """Build the seeded floor plan and floor texture.

    `n_clutter`: number of clutter boxes/pillars placed in rooms and along corridor walls;
    `texture_res_m`: floor texture resolution (m per pixel); `scale`: the building's size
    relative to the plan (ring: 17 x 13.5 m, >= 0.85; loops: 40 x 30 m, >= 0.7; corridors,
    doors and clutter keep their size); `layout`: "ring" or "loops" (see the module doc).
    """
    if layout == "loops":
        return _build_loops(seed, n_clutter, texture_res_m, scale)
    if layout != "ring":
        raise ValueError(f"unknown layout {layout!r} (known: {', '.join(LAYOUTS)})")
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
        box, sx, sy, pillar = _random_clutter(rng, W, H)
        x, y = box[0], box[1]
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

    shift = np.array(START_PLAN) * scale
    boxes, kind, colors = _coloured_boxes(rng, walls, clutter, kinds, shift)
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


def _coloured_boxes(rng: np.random.Generator, walls: list[list[float]], clutter: list[list[float]], kinds: list[int],
                    shift: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The world's boxes (walls then clutter, moved by -`shift` so the robot starts at the
    origin), their kinds (0 wall, then `kinds`) and plain colours: walls pale and varied (so
    texture bleeding is visible), clutter saturated."""
    boxes = np.array(walls + clutter, dtype=np.float64)
    kind = np.array([0] * len(walls) + kinds, dtype=np.int8)
    colors = np.empty((len(boxes), 3), dtype=np.uint8)
    colors[: len(walls)] = rng.integers(150, 235, size=(len(walls), 3))
    colors[len(walls) :] = rng.integers(20, 220, size=(len(clutter), 3))
    boxes[:, [0, 2]] -= shift[0]
    boxes[:, [1, 3]] -= shift[1]
    return boxes, kind, colors


def _segment_distance(box: list[float], seg: tuple[tuple[float, float], tuple[float, float]]) -> float:
    """Distance from an axis-aligned box [x0, y0, x1, y1, ...] to an axis-aligned segment."""
    (ax, ay), (bx, by) = seg
    sx0, sx1, sy0, sy1 = min(ax, bx), max(ax, bx), min(ay, by), max(ay, by)
    dx = max(sx0 - box[2], 0.0, box[0] - sx1)
    dy = max(sy0 - box[3], 0.0, box[1] - sy1)
    return float(np.hypot(dx, dy))


def _partitions(rng: np.random.Generator, lo: float, hi: float, gap: tuple[float, float]) -> list[float]:
    """Seeded cut positions between lo and hi, `gap` (min, max) apart and from the ends."""
    cuts: list[float] = []
    s = lo + float(rng.uniform(*gap))
    while s < hi - gap[0]:
        cuts.append(s)
        s += float(rng.uniform(*gap))
    return cuts


def _room_doors(rng: np.random.Generator, cuts: list[float], lo: float, hi: float, prob: float,
                width: tuple[float, float] = (0.9, 1.3), at_most: int | None = None) -> list[tuple[float, float]]:
    """Doors (intervals) along a wall from lo to hi: one per room between consecutive `cuts`
    with probability `prob` (at most `at_most` doors), each 0.4 m clear of the room's ends."""
    edges = [lo] + [c for c in cuts if lo < c < hi] + [hi]
    rooms = list(zip(edges[:-1], edges[1:]))
    order = rng.permutation(len(rooms))
    doors: list[tuple[float, float]] = []
    for i in order:
        a, b = rooms[int(i)]
        wd = float(rng.uniform(*width))
        go = rng.random() < prob
        if go and b - a - 0.8 >= wd and (at_most is None or len(doors) < at_most):
            s = float(rng.uniform(a + 0.4, b - 0.4 - wd))
            doors.append((s, s + wd))
    return sorted(doors)


def _build_loops(seed: int, n_clutter: int, texture_res_m: float, scale: float) -> World:
    """The `loops` layout (module doc): two corridor rings sharing the middle corridor."""
    rng = np.random.default_rng([seed, 111])
    W, H = (v * scale for v in LOOPS_SIZE_PLAN)
    hw = CORRIDOR_HALF_WIDTH_M
    xw, xe, xm = LOOPS_INSET_M, W - LOOPS_INSET_M, W / 2.0
    ys, yn = LOOPS_INSET_M, H - LOOPS_INSET_M
    start = (xw + LOOPS_START_EAST_M, ys)
    # Figure-eight: west ring counter-clockwise (north up the middle), back through the start
    # along the whole south corridor, east ring counter-clockwise, south down the middle again.
    route = [start, (xm, ys), (xm, yn), (xw, yn), (xw, ys), (xe, ys), (xe, yn), (xm, yn), (xm, ys), start]
    corridors = [((xw, ys), (xe, ys)), ((xw, yn), (xe, yn)), ((xw, ys), (xw, yn)), ((xe, ys), (xe, yn)), ((xm, ys), (xm, yn))]
    # people's lanes: the seven corridor stretches between junctions, 1.75 m short of them
    e = hw + 0.35
    lanes = [((xw + e, ys), (xm - e, ys)), ((xm + e, ys), (xe - e, ys)), ((xw + e, yn), (xm - e, yn)), ((xm + e, yn), (xe - e, yn)),
             ((xw, ys + e), (xw, yn - e)), ((xe, ys + e), (xe, yn - e)), ((xm, ys + e), (xm, yn - e))]
    ox0, oy0, ox1, oy1 = xw - hw, ys - hw, xe + hw, yn + hw  # the corridor ring's outer walls

    walls: list[list[float]] = [_wall(0, 0, W, 0), _wall(W, 0, W, H), _wall(0, H, W, H), _wall(0, 0, 0, H)]
    # Side rooms between the corridor ring and the outer walls. The south band (beside the
    # long corridor) gets a single door; the corner rooms are closed off.
    cuts_s = _partitions(rng, 0.0, W, (4.0, 8.0))
    cuts_n = _partitions(rng, 0.0, W, (3.5, 7.0))
    cuts_w = _partitions(rng, oy0, oy1, (3.5, 7.0))
    cuts_e = _partitions(rng, oy0, oy1, (3.5, 7.0))
    walls += [_wall(x, 0, x, oy0) for x in cuts_s] + [_wall(x, oy1, x, H) for x in cuts_n]
    walls += [_wall(0, y, ox0, y) for y in cuts_w] + [_wall(ox1, y, W, y) for y in cuts_e]
    walls += [_wall(0, oy0, ox0, oy0), _wall(ox1, oy0, W, oy0), _wall(0, oy1, ox0, oy1), _wall(ox1, oy1, W, oy1)]
    walls += _wall_with_doors((ox0, oy0), (ox1, oy0), _room_doors(rng, cuts_s, ox0, xm - hw, 1.0, at_most=1))
    walls += _wall_with_doors((ox0, oy1), (ox1, oy1), _room_doors(rng, cuts_n, ox0, ox1, 0.6))
    walls += _wall_with_doors((ox0, oy0), (ox0, oy1), _room_doors(rng, cuts_w, oy0, oy1, 0.6))
    walls += _wall_with_doors((ox1, oy0), (ox1, oy1), _room_doors(rng, cuts_e, oy0, oy1, 0.6))

    # Two blocks of rooms inside the rings: 2 columns x 3 rows, doors onto the side corridors
    # and the north corridor, one door onto the long south corridor (east block only).
    def block(bx0: float, by0: float, bx1: float, by1: float, south_doors: int) -> None:
        sx = bx0 + float(rng.uniform(0.4, 0.6)) * (bx1 - bx0)
        sy = [by0 + float(rng.uniform(0.28, 0.38)) * (by1 - by0), by0 + float(rng.uniform(0.62, 0.72)) * (by1 - by0)]
        walls.extend(_wall_with_doors((bx0, by0), (bx1, by0), _room_doors(rng, [sx], bx0, bx1, 1.0, at_most=south_doors)))
        walls.extend(_wall_with_doors((bx0, by1), (bx1, by1), _room_doors(rng, [sx], bx0, bx1, 0.8)))
        walls.extend(_wall_with_doors((bx0, by0), (bx0, by1), _room_doors(rng, sy, by0, by1, 0.75)))
        walls.extend(_wall_with_doors((bx1, by0), (bx1, by1), _room_doors(rng, sy, by0, by1, 0.75)))
        walls.extend(_wall_with_doors((sx, by0), (sx, by1), _room_doors(rng, sy, by0, by1, 0.5)))
        for y in sy:
            walls.extend(_wall_with_doors((bx0, y), (bx1, y), _room_doors(rng, [sx], bx0, bx1, 0.5, at_most=1)))

    block(xw + hw, ys + hw, xm - hw, yn - hw, south_doors=0)
    block(xm + hw, ys + hw, xe - hw, yn - hw, south_doors=1)

    clutter: list[list[float]] = []
    kinds: list[int] = []
    # Against the walls of every corridor but the south one: pillars, cabinets and benches,
    # 0.3 m deep, every 3.5-7 m on either side, never within LOOPS_CLEAR_M of a centre line.
    face = hw - WALL_THICKNESS_M / 2.0 - 0.02
    for (ax, ay), (bx, by) in corridors[1:]:
        along_x = ay == by
        lo, hi = (ax, bx) if along_x else (ay, by)
        s = lo + hw + float(rng.uniform(0.5, 3.0))
        while s < hi - hw - 0.5:
            pick = rng.random()
            length, height = (0.3, WALL_HEIGHT_M) if pick < 0.4 else ((float(rng.uniform(0.8, 1.2)), float(rng.uniform(1.7, 2.0))) if pick < 0.7 else (float(rng.uniform(1.0, 1.6)), 0.45))
            side = 1.0 if rng.random() < 0.5 else -1.0
            c = (ay if along_x else ax) + side * (face - 0.15)  # centre of the 0.3 m depth
            if along_x:
                box = [s - length / 2, c - 0.15, s + length / 2, c + 0.15, height]
            else:
                box = [c - 0.15, s - length / 2, c + 0.15, s + length / 2, height]
            if min(_segment_distance(box, seg) for seg in corridors) >= LOOPS_CLEAR_M and not _overlaps(box, walls, 0.0) and not _overlaps(box, clutter, 0.1):
                clutter.append(box)
                kinds.append(1 if pick < 0.4 else 2)
            s += float(rng.uniform(3.5, 7.0))
    # Room clutter: as in the ring, but only in rooms (clear of every corridor).
    placed = 0
    attempts = 0
    while placed < n_clutter and attempts < 20000:
        attempts += 1
        box, _sx, _sy, pillar = _random_clutter(rng, W, H)
        if min(_segment_distance(box, seg) for seg in corridors) < hw + 0.1:
            continue
        if _overlaps(box, walls, 0.05) or _overlaps(box, clutter, 0.3):
            continue
        clutter.append(box)
        kinds.append(1 if pillar else 2)
        placed += 1

    # The route (every corridor centre line) keeps LOOPS_CLEAR_M from everything, by construction.
    clear = min(_segment_distance(b, seg) for b in walls + clutter for seg in corridors)
    if clear < LOOPS_CLEAR_M - 1e-9:
        raise AssertionError(f"loops layout: an obstacle stands {clear:.2f} m from the route")
    shift = np.array(start)
    boxes, kind, colors = _coloured_boxes(rng, walls, clutter, kinds, shift)
    area = W * H / (WORLD_SIZE_PLAN[0] * WORLD_SIZE_PLAN[1])  # discs and stripes as dense as in the ring
    floor = floor_texture(rng, W, H, texture_res_m, origin=(-shift[0], -shift[1]), n_discs=int(round(40 * area)), n_stripes=int(round(12 * np.sqrt(area))))
    sh = (float(shift[0]), float(shift[1]))
    return World(
        boxes=boxes,
        colors=colors,
        kind=kind,
        floor=floor,
        bounds=(-sh[0], -sh[1], W - sh[0], H - sh[1]),
        loop_min=(xw - sh[0], ys - sh[1]),
        loop_max=(xe - sh[0], yn - sh[1]),
        layout="loops",
        route=np.array(route, dtype=np.float64) - shift,
        lanes=tuple(((a[0] - sh[0], a[1] - sh[1]), (b[0] - sh[0], b[1] - sh[1])) for a, b in lanes),
    )


def floor_texture(rng: np.random.Generator, width_m: float, height_m: float, res_m: float, origin: tuple[float, float],
                  n_discs: int = 40, n_stripes: int = 12) -> GridImage:
    """A distinct, non-repeating floor: 0.5 m tiles in random colours with dark grout,
    overlaid with `n_discs` coloured discs and `n_stripes` stripes (so a misplaced texture
    pixel is measurable). Row 0 is the lowest y (GridImage convention)."""
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
    for _ in range(n_discs):
        cx, cy = rng.uniform(0, width_m), rng.uniform(0, height_m)
        r = rng.uniform(0.15, 0.6)
        # only the pixels whose centres can lie within r (the same test on the same values)
        c0, c1 = max(int(np.floor((cx - r) / res_m - 0.5)), 0), min(int(np.ceil((cx + r) / res_m - 0.5)) + 1, nx)
        r0, r1 = max(int(np.floor((cy - r) / res_m - 0.5)), 0), min(int(np.ceil((cy + r) / res_m - 0.5)) + 1, ny)
        win = img[r0:r1, c0:c1]
        win[(X[r0:r1, c0:c1] - cx) ** 2 + (Y[r0:r1, c0:c1] - cy) ** 2 < r * r] = rng.integers(0, 256, size=3)
    for _ in range(n_stripes):  # straight stripes at random angles
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
