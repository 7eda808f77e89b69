"""Compiled ray casting against the simulated world: the floor plane z = 0, axis-aligned
boxes standing on the floor, and (optionally) vertical cylinders (walking people).

Hit ids: -1 nothing within range, -2 the floor, k >= 0 box k, -(3 + j) cylinder j.
Ray parameters are along the direction vector as given (unit vectors for the lidar, so t
is a range in metres; (x, y, 1) camera rays for the Kinect, so t is the z-depth).
"""

from __future__ import annotations

import numba as nb
import numpy as np

HIT_NONE = -1
HIT_FLOOR = -2


@nb.njit(cache=True, inline="always")
def _slab(o: float, d: float, lo: float, hi: float, tmin: float, tmax: float) -> tuple[float, float]:
    # One axis of the slab test; a ray parallel to the slab is inside it or misses entirely.
    if abs(d) < 1e-12:
        if o < lo or o > hi:
            return 1.0, -1.0
        return tmin, tmax
    inv = 1.0 / d
    t1 = (lo - o) * inv
    t2 = (hi - o) * inv
    if t1 > t2:
        t1, t2 = t2, t1
    return max(tmin, t1), min(tmax, t2)


@nb.njit(cache=True)
def cast_ray(ox: float, oy: float, oz: float, dx: float, dy: float, dz: float,
             boxes: np.ndarray, cyl: np.ndarray, t_max: float) -> tuple[float, int]:
    """First hit (t, id) of the ray o + t d with t in (1e-6, t_max]. `boxes` (K, 5)
    [x0, y0, x1, y1, height]; `cyl` (P, 4) [cx, cy, radius, height]."""
    best = t_max
    hit = HIT_NONE
    if dz < -1e-12:
        tf = -oz / dz
        if 1e-6 < tf <= best:
            best = tf
            hit = HIT_FLOOR
    for k in range(boxes.shape[0]):
        lo, hi = 1e-6, best
        lo, hi = _slab(ox, dx, boxes[k, 0], boxes[k, 2], lo, hi)
        if lo > hi:
            continue
        lo, hi = _slab(oy, dy, boxes[k, 1], boxes[k, 3], lo, hi)
        if lo > hi:
            continue
        lo, hi = _slab(oz, dz, 0.0, boxes[k, 4], lo, hi)
        if lo > hi:
            continue
        best = lo
        hit = k
    for j in range(cyl.shape[0]):
        # Vertical cylinder: solve |(o + t d - c)_xy| = r, then check the height.
        px, py = ox - cyl[j, 0], oy - cyl[j, 1]
        a = dx * dx + dy * dy
        if a < 1e-18:
            continue
        b = px * dx + py * dy
        c = px * px + py * py - cyl[j, 2] * cyl[j, 2]
        disc = b * b - a * c
        if disc < 0.0:
            continue
        t = (-b - np.sqrt(disc)) / a
        if 1e-6 < t < best:
            z = oz + t * dz
            if 0.0 <= z <= cyl[j, 3]:
                best = t
                hit = -(3 + j)
    return best, hit


@nb.njit(cache=True, parallel=True)
def cast_scans(lidar_to_world: np.ndarray, beam_angles: np.ndarray, boxes: np.ndarray,
               cylinders: np.ndarray, t_max: float) -> tuple[np.ndarray, np.ndarray]:
    """Ranges (N, B) in metres (t_max where nothing is hit) and hit ids (N, B) for N lidar
    poses (N, 4, 4) and B beams in the lidar x-y plane. `cylinders` is (N, P, 4): the people
    at each scan's time (P may be 0)."""
    n, nb_ = lidar_to_world.shape[0], beam_angles.shape[0]
    ranges = np.empty((n, nb_), dtype=np.float64)
    ids = np.empty((n, nb_), dtype=np.int32)
    ca = np.cos(beam_angles)
    sa = np.sin(beam_angles)
    for i in nb.prange(n):  # scans are independent: parallel and still deterministic
        T = lidar_to_world[i]
        cyl = cylinders[i]
        for b in range(nb_):
            # lidar-frame direction (cos a, sin a, 0) rotated into the world
            dx = T[0, 0] * ca[b] + T[0, 1] * sa[b]
            dy = T[1, 0] * ca[b] + T[1, 1] * sa[b]
            dz = T[2, 0] * ca[b] + T[2, 1] * sa[b]
            t, h = cast_ray(T[0, 3], T[1, 3], T[2, 3], dx, dy, dz, boxes, cyl, t_max)
            ranges[i, b] = t
            ids[i, b] = h
    return ranges, ids


@nb.njit(cache=True, parallel=True)
def cast_camera(cam_to_world: np.ndarray, rays_cam: np.ndarray, boxes: np.ndarray,
                cylinders: np.ndarray, t_max: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cast camera rays (P, 3) given in the optical frame from one camera pose (4, 4).
    Returns t (P,) along each ray (z-depth for rays with unit z), hit ids (P,) and the world
    hit points (P, 3)."""
    p = rays_cam.shape[0]
    ts = np.empty(p, dtype=np.float64)
    ids = np.empty(p, dtype=np.int32)
    pts = np.empty((p, 3), dtype=np.float64)
    T = cam_to_world
    for i in nb.prange(p):  # pixels are independent: parallel and still deterministic
        rx, ry, rz = rays_cam[i, 0], rays_cam[i, 1], rays_cam[i, 2]
        dx = T[0, 0] * rx + T[0, 1] * ry + T[0, 2] * rz
        dy = T[1, 0] * rx + T[1, 1] * ry + T[1, 2] * rz
        dz = T[2, 0] * rx + T[2, 1] * ry + T[2, 2] * rz
        t, h = cast_ray(T[0, 3], T[1, 3], T[2, 3], dx, dy, dz, boxes, cylinders, t_max)
        ts[i] = t
        ids[i] = h
        pts[i, 0] = T[0, 3] + t * dx
        pts[i, 1] = T[1, 3] + t * dy
        pts[i, 2] = T[2, 3] + t * dz
    return ts, ids, pts


@nb.njit(cache=True, parallel=True)
def colour_hits(ids: np.ndarray, pts: np.ndarray, boxes: np.ndarray, colors: np.ndarray, tex: np.ndarray,
                tex_x0: float, tex_y0: float, tex_res: float, person_rgb: np.ndarray, sky_rgb: np.ndarray) -> np.ndarray:
    """Colour (P, 3) uint8 of each camera hit: floor texel at the hit point (nearest), box
    colour shaded by face orientation (x faces 0.8, y faces 1.0, top 1.15) so edges and
    corners stay visible, a fixed colour for people, `sky_rgb` for nothing hit (ceiling)."""
    p = ids.shape[0]
    out = np.empty((p, 3), dtype=np.uint8)
    for i in nb.prange(p):
        h = ids[i]
        if h == HIT_FLOOR:
            c = int(np.floor((pts[i, 0] - tex_x0) / tex_res))
            r = int(np.floor((pts[i, 1] - tex_y0) / tex_res))
            if 0 <= r < tex.shape[0] and 0 <= c < tex.shape[1]:
                for ch in range(3):
                    out[i, ch] = tex[r, c, ch]
            else:
                for ch in range(3):
                    out[i, ch] = 90
        elif h >= 0:
            x, y, z = pts[i, 0], pts[i, 1], pts[i, 2]
            d = abs(x - boxes[h, 0])
            shade = 0.8
            e = abs(x - boxes[h, 2])
            if e < d:
                d = e
            e = abs(y - boxes[h, 1])
            if e < d:
                d, shade = e, 1.0
            e = abs(y - boxes[h, 3])
            if e < d:
                d, shade = e, 1.0
            e = abs(z - boxes[h, 4])
            if e < d:
                d, shade = e, 1.15
            for ch in range(3):
                out[i, ch] = np.uint8(min(255.0, np.floor(colors[h, ch] * shade + 0.5)))
        elif h == HIT_NONE:
            for ch in range(3):
                out[i, ch] = sky_rgb[ch]
        else:
            for ch in range(3):
                out[i, ch] = person_rgb[ch]
    return out


def cast_ray_reference(origin: np.ndarray, direction: np.ndarray, boxes: np.ndarray, t_max: float) -> tuple[float, int]:
    """Plain-Python reference of `cast_ray` (boxes and floor only), for tests."""
    best, hit = t_max, HIT_NONE
    o, d = np.asarray(origin, float), np.asarray(direction, float)
    if d[2] < -1e-12 and 1e-6 < -o[2] / d[2] <= best:
        best, hit = -o[2] / d[2], HIT_FLOOR
    for k, (x0, y0, x1, y1, h) in enumerate(boxes):
        lo, hi = 1e-6, best
        for oo, dd, a, b in ((o[0], d[0], x0, x1), (o[1], d[1], y0, y1), (o[2], d[2], 0.0, h)):
            if abs(dd) < 1e-12:
                if oo < a or oo > b:
                    lo, hi = 1.0, -1.0
                continue
            t1, t2 = sorted(((a - oo) / dd, (b - oo) / dd))
            lo, hi = max(lo, t1), min(hi, t2)
        if lo <= hi:
            best, hit = lo, k
    return best, hit
