"""An outdoor simulated world: a campus of buildings, trees, parked cars, lamp posts and
hedges along streets (layout `campus`), for 2D lidar probes of the kind of log the indoor
worlds are not (Freiburg's campus, MIT's Killian Court): open space where much of a scan
returns nothing, walls seen from 6-30 m, and along a street often only the trees and cars
to hold the match along it.

Plan (metres, times `scale`; 100 x 80 m at scale 1, 200 x 160 m at 2): street centre lines
run CAMPUS_INSET (15 %) inside the campus edge as a ring, plus one north-south street
through the middle, so the route is the `loops` building's figure-eight (856 m at scale 2),
coming back to mapped places after a third and two thirds of it. Buildings (10-30 m, some
L-shaped; their sizes do not scale) stand in the blocks between the streets and in the bands
outside the ring, 6 m or more from any street centre line; nothing else stands within
STREET_CLEAR_M of one, so the route never collides. No outer wall: past the campus edge the
lidar sees nothing (a building in a band outside the ring may reach a few metres past it;
`World.bounds` holds every box). People (`--people`) pace sidewalks SIDEWALK_M to one side of
each street between its junctions (`World.lanes`), clear of the route and of everything
standing beside the street.

Every obstacle is a box [x0, y0, x1, y1, height] (`World.boxes`), kind 0 building, 1 tree or
lamp post, 2 car or hedge; all stand taller than a wheeled robot's lidar (0.35 m).
"""

from __future__ import annotations

import numpy as np

from slamlab.datasets.sim.world import World, _coloured_boxes, _overlaps, _segment_distance, floor_texture

CAMPUS_SIZE_PLAN = (100.0, 80.0)  # the campus at scale 1 (m)
CAMPUS_INSET = 0.15  # street centre lines this share of the size inside the campus edge
STREET_CLEAR_M = 3.0  # nothing stands within this of a street centre line (the route and people)
SETBACK_M = 6.0  # buildings keep at least this from every street centre line
BUILDING_GAP_M = 5.0  # between two buildings
SIDEWALK_M = 2.0  # people's lanes: this far to the side of a street centre line (they pace 0.65 m either side)


def _street_side_objects(rng: np.random.Generator, streets: list, buildings: list[list[float]]) -> tuple[list[list[float]], list[int]]:
    """Trees, parked cars, lamp posts and hedges along both sides of every street (boxes, kinds)."""
    objs: list[list[float]] = []
    kinds: list[int] = []

    def box_at(along_x: bool, s: float, c: float, length: float, depth: float, height: float) -> list[float]:
        """A box centred at `s` along the street and `c` across it (absolute coordinates)."""
        if along_x:
            return [s - length / 2, c - depth / 2, s + length / 2, c + depth / 2, height]
        return [c - depth / 2, s - length / 2, c + depth / 2, s + length / 2, height]

    def place(box: list[float], kind: int) -> None:
        clear = min(_segment_distance(box, seg) for seg in streets)
        if clear >= STREET_CLEAR_M and not _overlaps(box, buildings, 0.5) and not _overlaps(box, objs, 0.3):
            objs.append(box)
            kinds.append(kind)

    for (ax, ay), (bx, by) in streets:
        along_x = ay == by
        lo, hi = (ax, bx) if along_x else (ay, by)
        line = ay if along_x else ax
        for side in (-1.0, 1.0):
            s = lo + float(rng.uniform(0.0, 8.0))  # trees, with gaps of open space
            while s < hi:
                if rng.random() < 0.25:
                    s += float(rng.uniform(20.0, 40.0))
                    continue
                size = float(rng.uniform(0.3, 0.6))
                place(box_at(along_x, s, line + side * float(rng.uniform(4.0, 6.0)), size, size, 6.0), 1)
                s += float(rng.uniform(6.0, 14.0))
            s = lo + float(rng.uniform(0.0, 25.0))  # lamp posts
            while s < hi:
                place(box_at(along_x, s, line + side * 6.5, 0.2, 0.2, 4.0), 1)
                s += 25.0
            if rng.random() < 0.35:  # a row of parked cars, their inner sides 3.1 m from the centre line
                s = float(rng.uniform(lo, hi))
                for _ in range(int(rng.integers(2, 7))):
                    place(box_at(along_x, s, line + side * 4.0, 4.5, 1.8, 1.5), 2)
                    s += 4.5 + float(rng.uniform(1.0, 2.5))
            if rng.random() < 0.15:  # a hedge
                length = float(rng.uniform(10.0, 30.0))
                s = float(rng.uniform(lo, max(hi - length, lo)))
                place(box_at(along_x, s + length / 2, line + side * 7.5, length, 0.8, 1.0), 2)
    return objs, kinds


def _buildings(rng: np.random.Generator, regions: list[tuple[float, float, float, float]], streets: list) -> list[list[float]]:
    """Buildings (boxes, 12 m tall) in each region (x0, y0, x1, y1), a quarter to a third of its
    area built, some with a wing (L-shaped), SETBACK_M or more from every street centre line."""
    out: list[list[float]] = []
    for x0, y0, x1, y1 in regions:
        area = (x1 - x0) * (y1 - y0)
        target = float(rng.uniform(0.25, 0.35)) * area
        built = 0.0
        for _ in range(200):
            if built >= target:
                break
            w, h = (float(v) for v in rng.uniform(10.0, 30.0, size=2))
            if w > x1 - x0 or h > y1 - y0:
                continue
            bx, by = float(rng.uniform(x0, x1 - w)), float(rng.uniform(y0, y1 - h))
            parts = [[bx, by, bx + w, by + h, 12.0]]
            if rng.random() < 0.4:  # a wing off one side
                ww, wh = float(rng.uniform(6.0, 12.0)), float(rng.uniform(6.0, 12.0))
                wx = bx + (w if rng.random() < 0.5 else -ww)
                wy = by + float(rng.uniform(0.0, max(h - wh, 0.0)))
                parts.append([wx, wy, wx + ww, wy + wh, 12.0])
            if any(_overlaps(p, out, BUILDING_GAP_M) for p in parts):
                continue
            if min(_segment_distance(p, seg) for p in parts for seg in streets) < SETBACK_M:
                continue
            out.extend(parts)
            built += sum((p[2] - p[0]) * (p[3] - p[1]) for p in parts)
    return out


def build_campus(seed: int, scale: float = 2.0, texture_res_m: float = 0.25) -> World:
    """The seeded campus (module doc) at `scale` (>= 1.5: the streets' blocks must hold a
    building); the robot starts on the south street 6 m east of the south-west corner, facing +x."""
    if scale < 1.5:
        raise ValueError(f"campus scale must be 1.5 or more, got {scale}")
    rng = np.random.default_rng([seed, 222])
    W, H = (v * scale for v in CAMPUS_SIZE_PLAN)
    xw, xe, xm = CAMPUS_INSET * W, W - CAMPUS_INSET * W, W / 2.0
    ys, yn = CAMPUS_INSET * H, H - CAMPUS_INSET * H
    start = (xw + 6.0, ys)
    route = [start, (xm, ys), (xm, yn), (xw, yn), (xw, ys), (xe, ys), (xe, yn), (xm, yn), (xm, ys), start]
    streets = [((xw, ys), (xe, ys)), ((xw, yn), (xe, yn)), ((xw, ys), (xw, yn)), ((xe, ys), (xe, yn)), ((xm, ys), (xm, yn))]
    # the blocks inside the ring and the bands outside it
    regions = [(xw, ys, xm, yn), (xm, ys, xe, yn), (0.0, 0.0, W, ys), (0.0, yn, W, H), (0.0, ys, xw, yn), (xe, ys, W, yn)]
    buildings = _buildings(rng, regions, streets)
    objs, kinds = _street_side_objects(rng, streets, buildings)
    clear = min(_segment_distance(b, seg) for b in buildings + objs for seg in streets)
    if clear < STREET_CLEAR_M - 1e-9:
        raise AssertionError(f"campus layout: an obstacle stands {clear:.2f} m from the route")
    e = 6.0  # people's lanes: every street between junctions, this far short of them, SIDEWALK_M to its side
    lanes = [((xw + e, ys + SIDEWALK_M), (xm - e, ys + SIDEWALK_M)), ((xm + e, ys + SIDEWALK_M), (xe - e, ys + SIDEWALK_M)),
             ((xw + e, yn - SIDEWALK_M), (xm - e, yn - SIDEWALK_M)), ((xm + e, yn - SIDEWALK_M), (xe - e, yn - SIDEWALK_M)),
             ((xw + SIDEWALK_M, ys + e), (xw + SIDEWALK_M, yn - e)), ((xe - SIDEWALK_M, ys + e), (xe - SIDEWALK_M, yn - e)),
             ((xm + SIDEWALK_M, ys + e), (xm + SIDEWALK_M, yn - e))]  # fmt: skip
    shift = np.array(start)
    boxes, kind, colors = _coloured_boxes(rng, buildings, objs, kinds, shift)
    floor = floor_texture(rng, W, H, texture_res_m, origin=(-shift[0], -shift[1]), n_discs=0, n_stripes=0)
    sh = (float(shift[0]), float(shift[1]))
    # the campus area, grown to hold every box (a building's wing may reach past the edge)
    bounds = (min(-sh[0], float(boxes[:, 0].min())), min(-sh[1], float(boxes[:, 1].min())),
              max(W - sh[0], float(boxes[:, 2].max())), max(H - sh[1], float(boxes[:, 3].max())))
    return World(
        boxes=boxes,
        colors=colors,
        kind=kind,
        floor=floor,
        bounds=bounds,
        loop_min=(xw - sh[0], ys - sh[1]),
        loop_max=(xe - sh[0], yn - sh[1]),
        layout="campus",
        route=np.array(route, dtype=np.float64) - shift,
        lanes=tuple(((a[0] - sh[0], a[1] - sh[1]), (b[0] - sh[0], b[1] - sh[1])) for a, b in lanes),
    )
