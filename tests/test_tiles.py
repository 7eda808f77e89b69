"""Copy-on-write tiled maps (slamlab.slam.tiles): isolation between particles, sharing after
resampling, memory counted once, and the same cell values as the dense grid."""

import math
import sys

import numpy as np
import pytest

from slamlab.slam.grid import MapSettings, OccupancyGrid
from slamlab.slam.scan import points_to_world
from slamlab.slam.tiles import EMPTY, TILE, TiledMaps, _TilePool

RES = 0.05
# 12.8 m = 256 cells = 8 tiles: the dense grid and the tiles then share one origin
SETTINGS = MapSettings(resolution_m=RES, initial_size_m=12.8, growth_margin_m=0.0)


def _scan(rng: np.random.Generator, m: int = 90, max_r: float = 5.0) -> tuple[np.ndarray, np.ndarray]:
    """Random beams around a room-like shape: (M, 2) body-frame points and the lidar origin."""
    a = np.sort(rng.uniform(-np.pi, np.pi, m))
    r = rng.uniform(0.5, max_r, m)
    return np.stack([r * np.cos(a), r * np.sin(a)], axis=1), np.array([0.1, 0.0])


def _snapshot(maps: TiledMaps) -> list[tuple[np.ndarray, np.ndarray]]:
    return [(maps.dense(p).copy(), maps.dense(p, "field").copy()) for p in range(maps.n)]


def test_a_particle_update_never_changes_another_particles_map():
    rng = np.random.default_rng(0)
    maps = TiledMaps(SETTINGS, 3, field_sigma_m=0.1, field_radius_m=0.3)
    pts, origin = _scan(rng)
    poses = np.zeros((3, 3))
    maps.insert_scan(poses, pts, origin, which=np.array([0]))
    maps.share_all_from(0)
    before = _snapshot(maps)
    pts2, _ = _scan(rng)
    moved = np.array([[0.0, 0, 0], [0.4, -0.3, 0.5], [0, 0, 0]])
    maps.insert_scan(moved, pts2, origin, which=np.array([1]))
    after = _snapshot(maps)
    for p in (0, 2):
        assert np.array_equal(before[p][0], after[p][0]) and np.array_equal(before[p][1], after[p][1])
    assert not np.array_equal(before[1][0], after[1][0])
    assert not np.array_equal(before[1][1], after[1][1])


def test_resampled_children_share_tiles_until_one_writes():
    rng = np.random.default_rng(1)
    maps = TiledMaps(SETTINGS, 3, field_sigma_m=0.1, field_radius_m=0.3)
    pts, origin = _scan(rng)
    # two different parents: particle 0 and 1 map from different poses
    poses = np.array([[0.0, 0, 0], [0.3, 0.2, 0.4], [0.0, 0, 0]])
    maps.insert_scan(poses, pts, origin, which=np.array([0, 1]))
    parent = (maps.dense(0).copy(), maps.dense(0, "field").copy())
    other = (maps.dense(1).copy(), maps.dense(1, "field").copy())
    maps.resample(np.array([0, 0, 1]))  # children 0 and 1 of old 0, child 2 of old 1
    assert np.array_equal(maps.table[0], maps.table[1])  # shared, not copied
    shared = maps.table[0][maps.table[0] != EMPTY]
    assert (maps.ref[shared] == 2).all()
    copied = maps.tiles_taken
    pts2, _ = _scan(rng)
    maps.insert_scan(np.array([[0.2, 0.1, -0.3]] * 3), pts2, origin, which=np.array([1]))
    # the child's write copied tiles: its table now differs where it wrote ...
    assert maps.tiles_taken > copied
    assert (maps.table[1] != maps.table[0]).any()
    # ... and neither its sibling (child 0 = the parent's map) nor child 2 changed
    assert np.array_equal(maps.dense(0), parent[0]) and np.array_equal(maps.dense(0, "field"), parent[1])
    assert np.array_equal(maps.dense(2), other[0]) and np.array_equal(maps.dense(2, "field"), other[1])
    assert not np.array_equal(maps.dense(1), parent[0])
    # references are exact: every tile a table holds counts each holder once
    for t in np.unique(maps.table[maps.table != EMPTY]):
        assert maps.ref[t] == (maps.table == t).sum()


def test_updates_that_change_no_cell_keep_tiles_shared():
    """Copy on *change*: once the same scan from the same pose has driven its cells to the
    clamps (free space at clamp_min, walls at clamp_max), inserting it again into resampled
    children changes no value, so no tile is copied; a scan from another pose changes cells
    and copies only tiles, leaving the siblings' maps as they were."""
    maps = TiledMaps(SETTINGS, 3, field_sigma_m=0.1, field_radius_m=0.3)
    # a round room: no beam crosses another's end cell (a cell freed and hit in one scan is
    # written twice, and its tile copied, even when its value ends where it was)
    a = np.linspace(-np.pi, np.pi, 90, endpoint=False)
    pts, origin = 3.0 * np.stack([np.cos(a), np.sin(a)], axis=1), np.zeros(2)
    pose = np.zeros((3, 3))
    for _ in range(20):  # 20 x -0.4 and 20 x 0.85 reach the +-5 clamps
        maps.insert_scan(pose, pts, origin, which=np.array([0]))
    maps.share_all_from(0)
    held, taken = maps.tiles_in_use, maps.tiles_taken
    before = _snapshot(maps)
    maps.insert_scan(pose, pts, origin)
    assert (maps.tiles_in_use, maps.tiles_taken) == (held, taken)
    assert all(np.array_equal(b[0], a[0]) and np.array_equal(b[1], a[1]) for b, a in zip(before, _snapshot(maps)))
    maps.insert_scan(np.array([[0.3, 0.2, 0.4], [0, 0, 0], [0, 0, 0]]), pts, origin, which=np.array([0]))
    assert maps.tiles_taken > taken and not np.array_equal(maps.table[0], maps.table[1])
    assert np.array_equal(maps.dense(1), before[1][0]) and np.array_equal(maps.dense(2, "field"), before[2][1])


def test_shared_tiles_are_counted_once_in_memory():
    rng = np.random.default_rng(2)
    one = TiledMaps(SETTINGS, 1, field_sigma_m=0.1, field_radius_m=0.3)
    many = TiledMaps(SETTINGS, 50, field_sigma_m=0.1, field_radius_m=0.3)
    pts, origin = _scan(rng)
    one.insert_scan(np.zeros((1, 3)), pts, origin)
    many.insert_scan(np.zeros((50, 3)), pts, origin, which=np.array([0]))
    many.share_all_from(0)
    assert many.tiles_in_use == one.tiles_in_use > 0
    tile_bytes = TILE * TILE * (1 + 1)  # log-odds one-byte codes (units of 0.05) + field one-byte codes
    assert many.memory_mb() == pytest.approx((one.tiles_in_use * tile_bytes + many.table.nbytes) / 1e6)
    # 50 particles each writing their own scan hold about 50 maps' worth of changed tiles
    many.insert_scan(rng.normal(0, 0.3, (50, 3)), pts, origin)
    assert many.tiles_in_use > 10 * one.tiles_in_use


# log-odds updates whose float32 sums are exact (binary fractions), and the defaults (0.85,
# -0.4: the dense grid's float32 sums round, the tiles' integer codes of 0.05 do not)
EXACT = MapSettings(resolution_m=RES, initial_size_m=12.8, growth_margin_m=0.0, log_odds_occupied=0.75, log_odds_free=-0.375,
                    clamp_min=-4.0, clamp_max=4.0)


# updates with no common unit (the logits of 0.7 and 0.4): float32 cells, the grid's arithmetic
LOGIT = MapSettings(resolution_m=RES, initial_size_m=12.8, growth_margin_m=0.0, log_odds_occupied=float(np.log(7 / 3)),
                    log_odds_free=float(np.log(4 / 6)))


@pytest.mark.parametrize("settings", [EXACT, SETTINGS, LOGIT], ids=["binary", "default", "float32"])
@pytest.mark.parametrize("field", [False, True])
def test_tiles_hold_the_same_values_as_the_dense_grid(field, settings):
    """Three particles updated together (in parallel) from their own random poses, resampled
    now and then so children share tiles and then copy them, cells flipping both ways and a
    field radius of 20 cells: every particle's log-odds and incrementally kept field equal
    those of its own dense grid (full recomputation over the changed box): exactly where the
    grid's float32 sums are exact, else within their rounding with the same walls."""
    import copy

    SETTINGS = settings
    assert TiledMaps(SETTINGS, 1).lo_dtype == (np.float32 if settings is LOGIT else np.int8)

    rng = np.random.default_rng(3)
    sigma, radius = (0.3, 1.0) if field else (0.0, 0.0)
    dense = [OccupancyGrid(SETTINGS, (0.0, 0.0), sigma, radius)]
    maps = TiledMaps(SETTINGS, 3, (0.0, 0.0), sigma, radius)
    if field:
        assert maps.kernel.shape[0] // 2 == 20
    assert np.allclose(dense[0].origin, maps.origin)
    pts, origin = _scan(rng, m=60, max_r=3.5)
    maps.insert_scan(np.zeros((3, 3)), pts, origin, which=np.array([0]))
    maps.share_all_from(0)
    dense[0].insert(origin, pts)
    dense = [copy.deepcopy(dense[0]) for _ in range(3)]
    freed = 0
    for k in range(45):
        poses = np.stack([rng.uniform(-1.5, 1.5, 3), rng.uniform(-1.5, 1.5, 3), rng.uniform(-np.pi, np.pi, 3)], axis=1)
        pts, origin = _scan(rng, m=60, max_r=3.5)
        for p in range(3):
            before = dense[p].occupied()
            dense[p].insert(points_to_world(origin.reshape(1, 2), poses[p])[0], points_to_world(pts, poses[p]))
            freed += int((before & ~dense[p].occupied()).sum())
        maps.insert_scan(poses, pts, origin)
        if k % 10 == 9:
            idx = np.array([0, 0, 1])
            maps.resample(idx)
            dense = [copy.deepcopy(dense[i]) for i in idx]
    assert maps.grow_count == 0 and all(d.grow_count == 0 for d in dense)
    assert freed > 20  # the recomputation path for cells that stopped being walls ran
    H, W = dense[0].shape
    for p in range(3):
        if settings is not SETTINGS:
            assert np.array_equal(maps.dense(p)[:H, :W], dense[p].log_odds)
        else:
            assert np.abs(maps.dense(p)[:H, :W] - dense[p].log_odds).max() < 1e-5
        assert np.array_equal(maps.dense(p)[:H, :W] > 0, dense[p].occupied())
        if field:
            assert np.array_equal(maps.dense(p, "field")[:H, :W], dense[p].field_values())
    # references are exact after all that
    for t in np.unique(maps.table[maps.table != EMPTY]):
        assert maps.ref[t] == (maps.table == t).sum()


def test_growing_keeps_every_value_and_crops_the_image():
    rng = np.random.default_rng(4)
    maps = TiledMaps(SETTINGS, 1, field_sigma_m=0.1, field_radius_m=0.3)
    pts, origin = _scan(rng)
    maps.insert_scan(np.zeros((1, 3)), pts, origin)
    img0 = maps.to_image(0)
    field0 = maps.dense(0, "field").copy()
    table_shape0, origin0 = maps.shape, maps.origin.copy()
    # far away in both directions: the table grows on every side
    maps.insert_scan(np.array([[30.0, -25.0, 0.0]]), pts, origin)
    maps.insert_scan(np.array([[-30.0, 25.0, 0.0]]), pts, origin)
    assert maps.grow_count >= 2
    img = maps.to_image(0)
    # the first scan's cells are where they were, in world coordinates
    dx = int(round((img0.origin_xy[0] - img.origin_xy[0]) / RES))
    dy = int(round((img0.origin_xy[1] - img.origin_xy[1]) / RES))
    h, w = img0.data.shape
    assert np.array_equal(img.data[dy:dy + h, dx:dx + w], img0.data)
    # the image is cropped to the box of written tiles, not the whole table
    rr, cc = np.nonzero(maps.table[0] != EMPTY)
    assert img.data.shape == ((np.ptp(rr) + 1) * TILE, (np.ptp(cc) + 1) * TILE)
    assert img0.data.shape[0] < table_shape0[0] or img0.data.shape[1] < table_shape0[1]
    # the whole field of before the growth is where it was, unchanged
    oy = int(round((origin0[1] - maps.origin[1]) / RES))
    ox = int(round((origin0[0] - maps.origin[0]) / RES))
    H0, W0 = table_shape0
    assert field0.max() > 0
    assert np.array_equal(maps.dense(0, "field")[oy:oy + H0, ox:ox + W0], field0)


def _corridor_scan(half_width_m: float = 1.5, reach_m: float = 4.0, m: int = 120) -> tuple[np.ndarray, np.ndarray]:
    """Beams onto the two walls of a straight corridor along the body's x axis."""
    x = np.linspace(-reach_m, reach_m, m // 2)
    pts = np.concatenate([np.stack([x, np.full_like(x, half_width_m)], 1), np.stack([x, np.full_like(x, -half_width_m)], 1)])
    return pts, np.zeros(2)


@pytest.mark.slow
def test_memory_of_a_long_diagonal_walk_grows_with_the_distance_not_the_area():
    """A walk along a diagonal corridor: a dense grid would grow with the bounding box
    (distance squared), the tiles only where scans land (distance)."""
    pts, origin = _corridor_scan()
    settings = MapSettings(resolution_m=RES, initial_size_m=12.8, growth_margin_m=2.0)
    maps = TiledMaps(settings, 2, field_sigma_m=0.1, field_radius_m=0.3)
    heading = np.pi / 4
    tiles_at: dict[int, int] = {}
    for k in range(0, 801):  # 0.1 m steps: 80 m
        d = 0.1 * k
        pose = np.array([d * np.cos(heading), d * np.sin(heading), heading])
        maps.insert_scan(np.tile(pose, (2, 1)), pts, origin)
        if k in (200, 400, 800):
            tiles_at[k // 10] = maps.tiles_in_use
    # each 20 m of corridor adds the same band of tiles: linear in the distance (the ends of
    # the first scan add a constant), where the bounding box would grow 4x per doubling
    per_20m_a = tiles_at[40] - tiles_at[20]
    per_20m_b = (tiles_at[80] - tiles_at[40]) / 2
    assert 0.85 < per_20m_b / per_20m_a < 1.15
    # the table (tile slots of the bounding box) grew with the area, 4x per doubling; the MB
    # held stays with the tiles in use
    H, W = maps.shape
    box_tiles = (H // TILE) * (W // TILE)
    assert box_tiles > 8 * tiles_at[80] / 2  # per particle, the box dwarfs the band
    assert maps.memory_mb() < 2.0 * tiles_at[80] * maps.bytes_per_tile() / 1e6 + maps.table.nbytes / 1e6


def test_coarse_search_by_whole_cell_shifts_picks_what_placing_every_offset_picks():
    """The likelihood matcher's coarse grid on tiles reuses each yaw's point placement across
    its whole-cell x/y offsets (`cell_shifts`); it must choose the same offsets, hence the
    same poses and scores, as placing the points anew for every offset."""
    from slamlab.slam.matcher import LikelihoodFieldMatcher, cell_shifts
    from slamlab.slam.tiled_match import tiled_field_search

    rng = np.random.default_rng(3)
    n = 6
    maps = TiledMaps(SETTINGS, n, field_sigma_m=0.1, field_radius_m=0.3)
    for _ in range(4):  # different maps per particle; walls up to the table's edge (it grows to hold them)
        pts, origin = _scan(rng, m=120, max_r=7.0)
        maps.insert_scan(rng.normal(0.0, [0.2, 0.2, 0.1], (n, 3)), pts, origin)
    m = LikelihoodFieldMatcher(sigma_m=0.1, radius_m=0.3, xy_half_width_m=0.1, xy_step_m=RES, prior_sigma_xy_m=0.05, prior_sigma_yaw_rad=0.1)
    scan, _ = _scan(rng, m=120, max_r=9.0)  # some points beyond the map's edge: the kernels' edge paths
    poses = rng.normal(0.0, [0.15, 0.15, 0.05], (n, 3))
    far = maps.origin + np.array(maps.table.shape[:0:-1]) * 32 * RES  # the table's (x, y) upper corner
    assert np.any((scan < maps.origin) | (scan > far))
    shifts, by_yaw, yaws = cell_shifts(m.offsets, maps.res)
    assert len(shifts) == len(m.offsets) == 5 * 5 * 9 and by_yaw.shape == (9, 25)
    out = {}
    for name, (sh, _, ya) in {"cells": (shifts, by_yaw, yaws), "every": cell_shifts(m.offsets, 0.03)}.items():
        best, scores = np.empty((n, 3)), np.empty(n)
        coarse = np.ascontiguousarray(scan[::3])
        tiled_field_search(maps.pool_f, maps.field_lut, maps.table, np.arange(n), maps.origin[0], maps.origin[1], 1.0 / maps.res, poses,
                           coarse, np.tile([0, len(coarse)], (n, 1)), scan, np.tile([0, len(scan)], (n, 1)), m.offsets, sh, ya, 0.025, 0.0125, 4, m.kxy, m.kyaw, best, scores, np.empty(n, dtype=np.int64), np.zeros((0, 6)), np.zeros(0), 0.0)
        out[name] = (best, scores)
    assert len(cell_shifts(m.offsets, 0.03)[0]) == 0  # 0.05 m is not a whole number of 3 cm cells
    np.testing.assert_allclose(out["cells"][0], out["every"][0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(out["cells"][1], out["every"][1], rtol=1e-12)
    assert not np.allclose(out["cells"][0], poses)  # the search did move the particles


def test_coarse_sums_by_whole_cell_shifts_equal_scoring_every_offset_up_to_the_map_edge():
    """Every coarse offset's field sum from the whole-cell kernel equals `tiled_score_field`
    at that offset, on a real field and on a field of ones out to the table's edge (where
    the 2 x 2 cells of some shifts leave the map and must add nothing)."""
    from slamlab.slam.matcher import cell_shifts, offset_grid
    from slamlab.slam.tiled_match import coarse_scores_by_cells, tiled_score_field

    rng = np.random.default_rng(8)
    maps = TiledMaps(SETTINGS, 1, field_sigma_m=0.1, field_radius_m=0.3)
    maps.insert_scan(np.zeros((1, 3)), *_scan(rng, m=200, max_r=6.0))
    offsets = offset_grid(0.1, RES, 0.1, 0.025)
    shifts, _, yaws = cell_shifts(offsets, RES)
    pts, _ = _scan(rng, m=150, max_r=9.0)  # many points off the map
    half = maps.table.shape[1] * 32 * RES / 2
    for field in ("real", "ones"):
        # "ones": every cell holds the top code (the kernel's centre value, 1.0)
        pool = maps.pool_f.copy() if field == "real" else np.full_like(maps.pool_f, len(maps.field_lut) - 1)
        for pose in ([0.1, -0.2, 0.05], [half - 0.1, 0.0, 0.0]):  # centred; at the table's edge
            px, py = (float(v) for v in maps.origin + half + np.array(pose[:2]))
            pt = pose[2]
            sums = coarse_scores_by_cells(pool, maps.field_lut, maps.table[0], maps.origin[0], maps.origin[1], 1.0 / RES, px, py, pt, np.ascontiguousarray(pts.T), shifts, yaws)
            r_lo, c_lo = shifts[:, 0].min(), shifts[:, 1].min()
            # both of the kernel's row reads are checked: on-map windows within one tile column and across two
            u = (px + np.cos(pt) * pts[:, 0] - np.sin(pt) * pts[:, 1] - maps.origin[0]) / RES - 0.5
            v = (py + np.sin(pt) * pts[:, 0] + np.cos(pt) * pts[:, 1] - maps.origin[1]) / RES - 0.5
            c0, r0 = np.floor(u).astype(int) + c_lo, np.floor(v).astype(int) + r_lo
            nx, ny = shifts[:, 1].max() - c_lo + 1, shifts[:, 0].max() - r_lo + 1
            H, W = np.array(maps.table.shape[1:]) * 32
            inside = (r0 >= 0) & (c0 >= 0) & (r0 + ny + 1 <= H) & (c0 + nx + 1 <= W)
            across = (c0 & 31) + nx > 31
            assert (inside & across).any() and (inside & ~across).any()
            for k, (dx, dy, dyaw) in enumerate(offsets):
                want = tiled_score_field(pool, maps.field_lut, maps.table[0], maps.origin[0], maps.origin[1], 1.0 / RES, px + dx, py + dy, pt + dyaw, np.ascontiguousarray(pts.T), np.empty((4, len(pts))))
                got = sums[shifts[k, 2], shifts[k, 0] - r_lo, shifts[k, 1] - c_lo]
                assert got == pytest.approx(want, rel=1e-12, abs=1e-12), (field, pose, k)
    with pytest.raises(ValueError, match="pts_t"):  # (M, 2) rows, not the two rows x and y
        coarse_scores_by_cells(pool, maps.field_lut, maps.table[0], maps.origin[0], maps.origin[1], 1.0 / RES, px, py, pt, pts, shifts, yaws)


def test_the_two_pass_field_score_is_the_point_by_point_sum_to_the_bit():
    """`tiled_score_field` places every point first and reads the field after; its sum must
    be the one a point-by-point loop (`_field_at`: place, read, add) gives, bit for bit, on
    the map, across tile borders and off the map's edge, with scratch longer than the points."""
    from slamlab.slam.tiled_match import _field_at, tiled_score_field

    rng = np.random.default_rng(11)
    maps = TiledMaps(SETTINGS, 1, field_sigma_m=0.1, field_radius_m=0.3)
    maps.insert_scan(np.zeros((1, 3)), *_scan(rng, m=200, max_r=6.0))
    pts, _ = _scan(rng, m=300, max_r=9.0)  # some off the map
    tab = maps.table[0]
    H, W = tab.shape[0] * 32, tab.shape[1] * 32
    lut = maps.field_lut.astype(np.float64)
    inv = 1.0 / RES
    # spare scratch columns hold a cell of the field's peak: a kernel that read past the points would add it
    field = maps.dense(0, "field")
    peak_row, peak_col = np.argwhere(field == field.max())[0]
    work = np.empty((4, len(pts) + 7))
    work[:, len(pts):] = np.array([[peak_col], [peak_row], [0.0], [0.0]])
    half = tab.shape[0] * 32 * RES / 2
    for pose in rng.normal(0.0, [0.3, 0.3, 0.5], (20, 3)):
        x, y, th = maps.origin[0] + half + pose[0], maps.origin[1] + half + pose[1], pose[2]
        c, s_ = math.cos(th), math.sin(th)  # as the kernel computes them (libm)
        want, read = 0.0, 0
        for p in pts:
            u = (x + c * p[0] - s_ * p[1] - maps.origin[0]) * inv - 0.5
            v = (y + s_ * p[0] + c * p[1] - maps.origin[1]) * inv - 0.5
            want += _field_at(maps.pool_f, lut, tab, H, W, u, v)
            read += 0 <= u < W - 1 and 0 <= v < H - 1
        assert 0 < read < len(pts)  # both the map and off it
        got = tiled_score_field(maps.pool_f, lut, tab, maps.origin[0], maps.origin[1], inv, x, y, th, np.ascontiguousarray(pts.T), work)
        assert got == want and got > 0
    with pytest.raises(ValueError, match="work"):
        tiled_score_field(maps.pool_f, lut, tab, maps.origin[0], maps.origin[1], inv, x, y, th, np.ascontiguousarray(pts.T), work[:, : len(pts) - 1])
    with pytest.raises(ValueError, match="pts_t"):  # points as (M, 2) rows, not the two rows x and y
        tiled_score_field(maps.pool_f, lut, tab, maps.origin[0], maps.origin[1], inv, x, y, th, pts, work)


def test_reference_counts_after_inserts_equal_a_full_recount():
    """`insert_scan` updates the tile counts and the free list from the tiles each particle
    took and let go of; after any mix of inserts (all particles, some, one) and resamples
    they equal a recount of every table entry, and no tile is both free and in use."""
    rng = np.random.default_rng(5)
    n = 6
    maps = TiledMaps(SETTINGS, n, field_sigma_m=0.1, field_radius_m=0.3, initial_tiles=4)
    poses = np.zeros((n, 3))
    for k in range(12):
        pts, origin = _scan(rng)
        poses = poses + rng.normal(0, 0.05, poses.shape)
        which = [None, np.array([k % n]), np.array([0, 2, 4])][k % 3]
        maps.insert_scan(poses, pts, origin, which=which)
        want = np.bincount(maps.table.ravel(), minlength=len(maps.ref))
        want[EMPTY] = 0
        assert np.array_equal(maps.ref, want)
        assert sorted(maps.free.tolist()) == (np.flatnonzero(want[1:] == 0) + 1).tolist()
        if k % 4 == 3:  # children share their parents' tiles, then write into some of them
            maps.resample(rng.integers(0, n, n))
    assert maps.tiles_in_use == len(np.unique(maps.table[maps.table != EMPTY]))


@pytest.mark.parametrize("sigma_m, radius_m", [(0.0, 0.0), (0.1, 0.3), (0.3, 1.1)])
def test_the_fresh_tile_bound_covers_every_tile_an_insert_takes(sigma_m, radius_m):
    """`count_fresh_tiles` bounds the fresh tiles each particle's insert takes (the free list
    is handed out by these bounds), with no field, the preset's kernel radius (6 cells) and
    the largest radius the tiles allow (22 cells, the sparsest samples): long beams at every
    angle from sub-cell poses, just after resampling, when every tile is shared."""
    from slamlab.slam.tiles import count_fresh_tiles

    rng = np.random.default_rng(11)
    n = 8
    maps = TiledMaps(SETTINGS, n, field_sigma_m=sigma_m, field_radius_m=radius_m, initial_tiles=4)
    assert maps.kernel.shape[0] // 2 == round(radius_m / RES)
    poses = rng.uniform(-0.5, 0.5, (n, 3))
    total_taken = 0
    for _ in range(10):
        pts, origin = _scan(rng, m=120, max_r=12.0)
        poses = poses + rng.normal(0, [0.3, 0.3, 0.2], poses.shape)
        rmax = float(np.sqrt((np.vstack([pts, origin]) ** 2).sum(axis=1)).max())
        maps.ensure(poses[:, 0].min() - rmax, poses[:, 1].min() - rmax, poses[:, 0].max() + rmax, poses[:, 1].max() + rmax)
        need = np.zeros(n, dtype=np.int64)
        marks, listed = maps._marks(n)
        listed[:] = -1  # the tiles of the beams' samples come first; the rest stays -1
        count_fresh_tiles(maps.table, maps.ref, np.arange(n, dtype=np.int64), poses, pts, origin, float(maps.origin[0]),
                          float(maps.origin[1]), 1.0 / maps.res, maps.kernel.shape[0] // 2, need, marks, listed)
        before = maps.table.copy()
        maps.insert_scan(poses, pts, origin)
        assert maps.table.shape == before.shape  # the bound was taken on the table the insert used
        tw = maps.table.shape[2]
        for j in range(n):
            sampled = listed[j][listed[j] >= 0]
            counted = {(t // tw + a, t % tw + b) for t in sampled.tolist() for a in (-1, 0, 1) for b in (-1, 0, 1)}
            taken = {tuple(rc) for rc in np.argwhere(maps.table[j] != before[j]).tolist()}  # one entry per fresh tile
            total_taken += len(taken)
            assert taken <= counted, sorted(taken - counted)
            assert len(taken) <= need[j]
        maps.resample(rng.integers(0, n, n))
    assert total_taken > 10 * n  # the scans reached unshared space: the check had tiles to check


def test_tile_pool_grows_in_place_and_keeps_its_tiles():
    """The pool is a memory map resized in place (no second copy of the tiles while it
    grows); a view still held elsewhere makes it copy instead, and that view stays valid."""
    pool = _TilePool(4)
    pool.array[1] = 1.5
    pool.array[3, 2, 5] = -2.0
    pool.grow(64)
    assert pool.array.shape == (64, TILE, TILE)
    assert (pool.array[1] == 1.5).all() and pool.array[3, 2, 5] == -2.0
    assert not pool.array[0].any() and not pool.array[4:].any()  # new tiles read zero
    if sys.platform.startswith("linux"):
        assert pool.copies == 0
    held = pool.array[1]
    pool.grow(128)
    assert pool.copies == 1 and (held == 1.5).all() and (pool.array[1] == 1.5).all() and pool.array.shape[0] == 128
    # in a filter run no view outlives a step: every growth is in place
    maps = TiledMaps(SETTINGS, 8, field_sigma_m=0.1, field_radius_m=0.3, initial_tiles=2)
    rng = np.random.default_rng(3)
    for _ in range(4):
        pts, origin = _scan(rng)
        maps.insert_scan(rng.normal(0, 0.2, (8, 3)), pts, origin)
    assert maps.pool_lo.shape[0] > 2
    if sys.platform.startswith("linux"):
        assert maps._pools["lo"].copies == 0 and maps._pools["f"].copies == 0


def test_field_codes_decode_to_the_kernel_and_keep_its_order():
    """One-byte field cells: decoding a code gives the float32 kernel value bit for bit, 0 is
    code 0 (the empty tile), and codes order like values (the incremental max runs on codes)."""
    from slamlab.slam.raycast import gaussian_kernel
    from slamlab.slam.tiles import field_codes

    for sigma, radius in ((2.0, 6), (0.7, 3), (6.0, 22)):
        kernel = gaussian_kernel(sigma, radius)
        codes, lut = field_codes(kernel)
        assert codes.dtype == np.uint8 and lut[0] == 0.0 and np.all(np.diff(lut) > 0)
        assert np.array_equal(lut[codes], kernel)
        a, b = kernel.ravel()[:, None], kernel.ravel()[None, :]
        assert np.array_equal(a > b, codes.ravel()[:, None] > codes.ravel()[None, :])


def test_log_odds_codes_pick_the_smallest_exact_integer_type():
    from slamlab.slam.tiles import log_odds_codes

    assert log_odds_codes(SETTINGS) == (np.int8, pytest.approx(0.05))  # +0.85, -0.4, +-5: -100..100
    assert log_odds_codes(EXACT) == (np.int8, pytest.approx(0.125))  # 0.75, -0.375, +-4: -32..32
    assert log_odds_codes(MapSettings(log_odds_occupied=0.847)) == (np.int16, pytest.approx(0.001))
    assert log_odds_codes(MapSettings(clamp_max=50.0, clamp_min=-50.0)) == (np.int16, pytest.approx(0.05))
    assert log_odds_codes(LOGIT) == (np.float32, 1.0)


def test_the_code_image_decodes_to_the_log_odds_image():
    """The engine keeps the best map as one-byte codes while the particles' maps are held and
    decodes it afterwards: the same float32 image as decoding while cropping."""
    from slamlab.slam.replay import reduce_map
    from slamlab.slam.tiles import decode_image

    rng = np.random.default_rng(5)
    maps = TiledMaps(SETTINGS, 2)
    for _ in range(6):
        poses = np.stack([rng.uniform(-4, 4, 2), rng.uniform(-4, 4, 2), rng.uniform(-np.pi, np.pi, 2)], axis=1)
        maps.insert_scan(poses, *_scan(rng, m=80, max_r=9.0))
    codes = maps.to_image(1, decoded=False)
    assert codes.data.dtype == np.int8 and maps.lo_unit == pytest.approx(0.05)
    assert set(np.unique(codes.data)) >= {-8, 17}  # one free update and one hit, in units of 0.05
    image = maps.to_image(1)
    decoded = decode_image(codes, maps.lo_unit, band_rows=7)  # bands that do not divide the rows
    assert decoded.origin_xy == image.origin_xy and np.array_equal(decoded.data, image.data)
    assert image.data.dtype == np.float32 and np.array_equal(image.data, (codes.data * 0.05).astype(np.float32))
    # the replay's snapshot of the codes is the snapshot of the log-odds
    for a, b in zip(reduce_map(codes, 64, unit=maps.lo_unit), reduce_map(image, 64)):
        assert np.array_equal(a, b)


@pytest.mark.parametrize("settings", [SETTINGS, LOGIT], ids=["int8", "float32"])
@pytest.mark.parametrize("max_px", [1000, 64, 37])  # k = 1; k not dividing the crop; k across tiles
def test_snapshots_read_from_tiles_equal_those_of_the_gathered_map(settings, max_px):
    """The replay's snapshot straight from the tiles (`reduce_tiled_map`) is the snapshot of
    the gathered map (`reduce_map`), pixels and extent to the bit, also where empty tiles lie
    inside the map's box (two islands of scans far apart)."""
    from slamlab.slam.replay import reduce_map, reduce_tiled_map

    rng = np.random.default_rng(7)
    maps = TiledMaps(settings, 2)
    for centre in ((0.0, 0.0), (9.0, 5.0)):
        for _ in range(3):
            poses = np.array([[centre[0] + rng.uniform(-1, 1), centre[1] + rng.uniform(-1, 1), rng.uniform(-np.pi, np.pi)]] * 2)
            maps.insert_scan(poses, *_scan(rng, m=60, max_r=2.5))
    rr, cc = np.nonzero(maps.table[1] != EMPTY)
    assert (maps.table[1][rr.min():rr.max() + 1, cc.min():cc.max() + 1] == EMPTY).any()  # a gap inside the box
    want = reduce_map(maps.to_image(1, decoded=False), max_px, unit=maps.lo_unit)
    got = reduce_tiled_map(maps, 1, max_px)
    assert np.array_equal(got[0], want[0]) and got[1] == want[1]
    assert len(np.unique(want[0])) > 3  # free, occupied and unknown blocks all there

