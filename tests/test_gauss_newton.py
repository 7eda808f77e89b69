"""The likelihood matcher's Gauss-Newton refinement (`matcher.refine: gauss_newton`,
slamlab.slam.gauss_newton): its gradient is the score's, it finds the pose with fewer
scores than the hill climb, never ends below the coarse grid's best, and reads a dense
field (filter=course) and a particle's tiles (filter=rbpf) alike."""

import numpy as np

from slamlab.slam.gauss_newton import NO_LUT, NO_POOL, NO_TABLE, distance_table, field_gradient
from slamlab.slam.grid import MapSettings, OccupancyGrid
from slamlab.slam.matcher import LikelihoodFieldMatcher, score_field
from slamlab.slam.scan import ScanPoints
from slamlab.slam.tiles import TiledMaps


def _room_scan() -> np.ndarray:
    """A 4 x 3 m room with one corner pulled in, seen from (0.3, 0.2) (body frame, m). Each
    hit is moved to the centre of its 5 cm cell, so that the map built from the origin peaks
    exactly at the hits and the true pose is the origin."""
    a = np.linspace(-np.pi, np.pi, 240, endpoint=False)
    d = np.minimum(2.0 / np.maximum(np.abs(np.cos(a)), 1e-9), 1.5 / np.maximum(np.abs(np.sin(a)), 1e-9))
    pts = np.stack([d * np.cos(a), d * np.sin(a)], axis=1)
    pts[(pts[:, 0] > 1.0) & (pts[:, 1] > 0.5)] *= 0.8  # something that tells the room's corners apart
    return (np.floor((pts - np.array([0.3, 0.2])) / 0.05) + 0.5) * 0.05


def _maps(n: int = 1) -> tuple[OccupancyGrid, TiledMaps, ScanPoints]:
    """The room mapped three times from the origin, as a dense grid and as the tiles of `n`
    particles (both with their origin at (0, 0), so their cells coincide)."""
    settings = MapSettings(resolution_m=0.05)
    grid = OccupancyGrid(settings, (0.0, 0.0), field_sigma_m=0.1, field_radius_m=0.3)
    maps = TiledMaps(settings, n, (0.0, 0.0), field_sigma_m=0.1, field_radius_m=0.3)
    pts = _room_scan()
    for _ in range(3):
        grid.insert(np.zeros(2), pts)
        maps.insert_scan(np.zeros((n, 3)), pts, np.zeros(2))
    return grid, maps, ScanPoints(xy=pts[::2], origin=np.zeros(2))


def _bilinear(grid: OccupancyGrid, x: float, y: float, th: float, p: np.ndarray, sigma: float, cap: float) -> tuple[float, float]:
    """(f, d) bilinear at body point p with the body at (x, y, th), d in cells from each cell's f."""
    wx = x + np.cos(th) * p[0] - np.sin(th) * p[1]
    wy = y + np.sin(th) * p[0] + np.cos(th) * p[1]
    u = (wx - grid.origin[0]) / grid.res - 0.5
    v = (wy - grid.origin[1]) / grid.res - 0.5
    c0, r0 = int(np.floor(u)), int(np.floor(v))
    fu, fv = u - c0, v - r0
    cells = grid.field_values()[r0:r0 + 2, c0:c0 + 2].astype(np.float64)
    dist = np.where(cells > 0, sigma * np.sqrt(-2.0 * np.log(np.where(cells > 0, cells, 1.0))), cap)
    wts = np.array([[(1 - fv) * (1 - fu), (1 - fv) * fu], [fv * (1 - fu), fv * fu]])
    return float((wts * cells).sum()), float((wts * dist).sum())


def test_the_gradient_is_the_scores_derivative():
    """`field_gradient`'s sum is `score_field`'s, its gradient matches central differences of
    it in x, y and yaw, and its curvature is sum (f / sigma^2) J^T J with J the distance's
    gradient (bilinear f and d are smooth within a cell; steps of 1e-6 cross no cell border
    at these poses)."""
    grid, _, scan = _maps()
    sigma = 0.1 / grid.res
    cap = np.array([0.3 / grid.res + 1.0])
    pts = scan.xy
    rng = np.random.default_rng(4)
    for x, y, th in rng.normal(0.0, [0.06, 0.06, 0.03], (5, 3)):
        g, h = np.empty(3), np.empty(6)
        s = field_gradient(grid.field_cells, NO_POOL, NO_TABLE, NO_LUT, cap, sigma, grid.origin[0], grid.origin[1], 1.0 / grid.res, x, y, th, pts, 1 / sigma**2, g, h)

        def score(dx, dy, dt):
            return score_field(grid.field_cells, grid.origin[0], grid.origin[1], 1.0 / grid.res, x + dx, y + dy, th + dt, pts)

        assert s == score(0, 0, 0)  # the points are placed as score_field places them
        e = 1e-6
        fd = [(score(e, 0, 0) - score(-e, 0, 0)) / (2 * e), (score(0, e, 0) - score(0, -e, 0)) / (2 * e), (score(0, 0, e) - score(0, 0, -e)) / (2 * e)]
        np.testing.assert_allclose(g, fd, rtol=1e-4, atol=1e-3)
        # the curvature: sum over points of (f / sigma^2) J^T J, J the gradient of the point's
        # distance d (bilinear in the cells' d) in x, y and yaw, here by central differences
        ref = np.zeros((3, 3))
        for p in pts:
            def d_at(dx, dy, dt, p=p):
                return _bilinear(grid, x + dx, y + dy, th + dt, p, sigma, cap[0])[1]
            jac = np.array([(d_at(e, 0, 0) - d_at(-e, 0, 0)), (d_at(0, e, 0) - d_at(0, -e, 0)), (d_at(0, 0, e) - d_at(0, 0, -e))]) / (2 * e)
            f = _bilinear(grid, x, y, th, p, sigma, cap[0])[0]
            ref += f / sigma**2 * np.outer(jac, jac)
        hm = np.array([[h[0], h[1], h[2]], [h[1], h[3], h[4]], [h[2], h[4], h[5]]])
        np.testing.assert_allclose(hm, ref, rtol=1e-4, atol=1e-6 * np.abs(ref).max())


def test_distance_table_inverts_the_field():
    lut = np.array([0.0, np.exp(-0.5), np.exp(-2.0), 1.0], dtype=np.float32)
    np.testing.assert_allclose(distance_table(lut, 2.0, 7.0), [7.0, 2.0, 4.0, 0.0], atol=1e-6)


def test_gauss_newton_finds_the_pose_with_fewer_scores_than_the_climb():
    """From 7 cm and 3 degrees off, both refinements end within a centimetre of the truth;
    Gauss-Newton reads the map far less often."""
    grid, _, scan = _maps()
    kw = dict(sigma_m=0.1, radius_m=0.3, prior_sigma_xy_m=0.0, prior_sigma_yaw_rad=0.0)
    start = np.array([[0.07, -0.06, 0.05], [-0.04, 0.08, -0.04]])
    climb = LikelihoodFieldMatcher(**kw)
    newton = LikelihoodFieldMatcher(refine="gauss_newton", **kw)
    a, _ = climb.match(grid, start, scan)
    b, _ = newton.match(grid, start, scan)
    np.testing.assert_allclose(a, 0.0, atol=0.01)
    np.testing.assert_allclose(b[:, :2], 0.0, atol=0.005)
    np.testing.assert_allclose(b[:, 2], 0.0, atol=0.002)
    assert newton.map_reads < 0.75 * climb.map_reads


def test_gauss_newton_never_ends_below_the_coarse_grids_best():
    """It starts at the coarse grid's best offset and keeps only steps that raise the score,
    prior included: its score is at least the score there (a climb of no levels), on every
    particle, from poses up to 15 cm off."""
    _, maps, scan = _maps(20)
    rng = np.random.default_rng(9)
    poses = rng.normal(0.0, [0.15, 0.15, 0.05], (20, 3))
    kw = dict(sigma_m=0.1, radius_m=0.3)
    _, at_coarse = LikelihoodFieldMatcher(refine_levels=0, **kw).match_each(maps, poses, scan)
    moved, refined = LikelihoodFieldMatcher(refine="gauss_newton", **kw).match_each(maps, poses, scan)
    assert np.all(refined >= at_coarse)
    assert np.mean(refined > at_coarse) > 0.9  # and it did refine
    assert np.median(np.hypot(moved[:, 0], moved[:, 1])) < 0.01


def test_dense_and_tiled_maps_refine_alike():
    """The shared map's kernel (dense field, d computed from f) and the RBPF's (field codes,
    d from `distance_table`) take the same steps to the same pose and score."""
    grid, maps, scan = _maps()
    pred = np.array([[0.05, -0.03, 0.03]])
    m = LikelihoodFieldMatcher(sigma_m=0.1, radius_m=0.3, refine="gauss_newton")
    dense, ds = m.match(grid, pred, scan)
    tiled, ts = m.match_each(maps, pred, scan)
    np.testing.assert_allclose(dense, tiled, atol=1e-9)
    np.testing.assert_allclose(ds, ts, rtol=1e-9)
    assert np.hypot(*dense[0, :2]) < 0.01
