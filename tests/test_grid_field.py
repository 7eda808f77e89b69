"""The occupancy grid's likelihood field is kept up to date incrementally (`OccupancyGrid.insert`:
lowered around cells that turned free, raised around new walls) and drawn in one go for a whole
map (`insert_many`). Both must give the values of the plain algorithm: recompute the field over
the box of every changed cell after each scan (`raycast.update_field`)."""

from __future__ import annotations

import numpy as np
import pytest

from slamlab.config.slam import MapConfig
from slamlab.slam.grid import NO_FLIP, OccupancyGrid
from slamlab.slam.raycast import HIT_COUNT_CAP, HIT_UNITS, WALL_STEPS, raycast_many_bands, raycast_update, update_field


def _random_scan(rng: np.random.Generator, spread_m: float, reach_m: float) -> tuple[np.ndarray, np.ndarray]:
    n = int(rng.integers(1, 200))
    sensor = rng.uniform(-spread_m, spread_m, 2)
    ang, r = rng.uniform(0, 2 * np.pi, n), rng.uniform(0.5, reach_m, n)
    return sensor, np.column_stack([sensor[0] + r * np.cos(ang), sensor[1] + r * np.sin(ang)])


def _reference_insert(g: OccupancyGrid, lo: np.ndarray, field: np.ndarray, sensor: np.ndarray, pts: np.ndarray) -> None:
    """One scan into (lo, field) by the plain algorithm: the field recomputed over the changed box."""
    s = g.s
    rows, cols = g.cells(pts)
    sr, sc = g.cells(sensor.reshape(1, 2))
    flip = np.array(NO_FLIP, dtype=np.int64)
    raycast_update(lo, int(sr[0]), int(sc[0]), rows, cols, np.float32(s.log_odds_occupied), np.float32(s.log_odds_free),
                   np.float32(s.clamp_min), np.float32(s.clamp_max), np.float32(s.occupied_threshold), flip)
    if flip[1] >= 0:
        R = g.field_radius
        H, W = lo.shape
        update_field(lo, field, np.float32(s.occupied_threshold), g.bank, g.hit_dx, g.hit_dy,
                     max(flip[0] - R, 0), min(flip[1] + R + 1, H), max(flip[2] - R, 0), min(flip[3] + R + 1, W))


def test_incremental_field_equals_recomputing_the_changed_box():
    rng = np.random.default_rng(0)
    g = OccupancyGrid(MapConfig(initial_size_m=20.0), (0.0, 0.0), 0.1, 0.3)
    lo, field = g.log_odds.copy(), g.field.copy()
    changed = 0
    for i in range(300):
        sensor, pts = _random_scan(rng, 3.0, 6.0)  # stays inside the 20 m grid: no growth to mirror
        if i % 7 == 0:
            pts = np.round(pts, 1)  # the same wall cells hit again, and free cells crossed by later beams
        g.insert(sensor, pts)
        _reference_insert(g, lo, field, sensor, pts)
        assert g.shape == lo.shape
        assert np.array_equal(g.log_odds, lo), f"log-odds differ after scan {i}"
        assert np.array_equal(g.field, field), f"field differs after scan {i}"
        changed += int(np.count_nonzero(field))
    assert changed > 0  # the scans drew walls: the comparison saw a field


def _field_recomputed(g: OccupancyGrid) -> np.ndarray:
    """The grid's field recomputed over the whole grid from its log-odds (and hit offsets)."""
    ref = np.zeros(g.shape, dtype=g.field.dtype)
    update_field(g.log_odds, ref, np.float32(g.s.occupied_threshold), g.bank, g.hit_dx, g.hit_dy, 0, g.shape[0], 0, g.shape[1])
    return ref


def _common_box(a: OccupancyGrid, b: OccupancyGrid) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """(log-odds, field) of both grids cut to the world area both cover (same resolution, cell-aligned)."""
    o = np.maximum(a.origin, b.origin)
    hi = np.minimum(a.origin + np.array(a.shape[::-1]) * a.res, b.origin + np.array(b.shape[::-1]) * b.res)
    rows, cols = int(round((hi[1] - o[1]) / a.res)), int(round((hi[0] - o[0]) / a.res))

    def cut(g: OccupancyGrid) -> tuple[np.ndarray, np.ndarray]:
        dc, dr = int(round((o[0] - g.origin[0]) / g.res)), int(round((o[1] - g.origin[1]) / g.res))
        return g.log_odds[dr:dr + rows, dc:dc + cols], g.field[dr:dr + rows, dc:dc + cols]

    return cut(a), cut(b)


@pytest.mark.parametrize("at_hits", [False, True])
def test_insert_many_equals_inserting_one_scan_at_a_time(at_hits):
    """Scans reaching beyond the initial grid: one-by-one grows it several times, insert_many once."""
    rng = np.random.default_rng(1)
    s = MapConfig(initial_size_m=20.0)
    one, many = OccupancyGrid(s, (0.0, 0.0), 0.05, 0.3, at_hits), OccupancyGrid(s, (0.0, 0.0), 0.05, 0.3, at_hits)
    sensors, scans = [], []
    for _ in range(100):
        sensor, pts = _random_scan(rng, 8.0, 12.0)
        one.insert(sensor, pts)
        sensors.append(sensor)
        scans.append(pts)
    many.insert_many(np.array(sensors), scans)
    assert one.grow_count > 1 and many.grow_count == 1
    (lo_a, f_a), (lo_b, f_b) = _common_box(one, many)
    assert lo_a.shape == one.shape  # the one-by-one grid lies wholly inside the other
    assert np.array_equal(lo_a, lo_b) and np.array_equal(f_a, f_b)
    assert np.count_nonzero(many.log_odds) == np.count_nonzero(one.log_odds)  # nothing drawn outside it


def test_scans_ray_cast_in_row_bands_give_scan_by_scan_values_for_any_band_and_thread_count():
    """`raycast_many_bands` (a map drawn again, on all cores): whatever the band height and the
    number of threads, the log-odds are those of `raycast_update` scan after scan, bit for bit
    (clamping makes the order of a cell's additions matter: many short scans reach the clamps)."""
    import numba

    rng = np.random.default_rng(5)
    s = MapConfig(initial_size_m=40.0)
    g = OccupancyGrid(s, (0.0, 0.0), 0.1)
    views = [_random_scan(rng, 12.0, 8.0) for _ in range(10)]
    sensors, scans = [], []
    for i in range(150):  # ten views seen again and again, so that cells reach the clamps
        sensor, pts = views[i % 10]
        scans.append(pts if i % 37 else pts[:0])  # an empty scan now and then
        sensors.append(sensor)
    ref = np.zeros(g.shape, dtype=np.float32)
    for sensor, pts in zip(sensors, scans):
        rows, cols = g.cells(pts)
        sr, sc = g.cells(sensor.reshape(1, 2))
        raycast_update(ref, int(sr[0]), int(sc[0]), rows, cols, np.float32(s.log_odds_occupied), np.float32(s.log_odds_free),
                       np.float32(s.clamp_min), np.float32(s.clamp_max), np.float32(s.occupied_threshold), np.array(NO_FLIP, dtype=np.int64))
    assert (ref == s.clamp_max).any() and (ref == s.clamp_min).any()
    rows, cols = g.cells(np.concatenate(scans))
    sensor_rows, sensor_cols = g.cells(np.array(sensors))
    starts = np.concatenate([[0], np.cumsum([len(p) for p in scans])]).astype(np.int64)
    threads = numba.get_num_threads()
    for band_rows, n_threads in ((1, threads), (7, 1), (64, threads), (g.shape[0], threads)):
        lo = np.zeros(g.shape, dtype=np.float32)
        try:
            numba.set_num_threads(n_threads)
            raycast_many_bands(lo, sensor_rows, sensor_cols, rows, cols, starts, np.float32(s.log_odds_occupied), np.float32(s.log_odds_free),
                               np.float32(s.clamp_min), np.float32(s.clamp_max), band_rows)
        finally:
            numba.set_num_threads(threads)
        assert np.array_equal(lo, ref), band_rows


@pytest.mark.parametrize("at_hits", [False, True])
def test_a_field_started_late_equals_one_kept_from_the_start(at_hits):
    """`start_field` on a grid built without a field (a graph submap, whose field is only read
    once it is finished): the values `insert` would have kept scan by scan, and kept after."""
    rng = np.random.default_rng(2)
    s = MapConfig(initial_size_m=4.0)
    kept, late = OccupancyGrid(s, (0.0, 0.0), 0.1, 0.3, at_hits), OccupancyGrid(s, (0.0, 0.0), walls_at_hits=at_hits)
    grown_at_start = 0
    for i in range(60):
        sensor, pts = _random_scan(rng, 1.0 + i, 4.0 + i)  # ever farther: the grids grow before and after the start
        kept.insert(sensor, pts)
        late.insert(sensor, pts)
        if i == 20:
            late.start_field(0.1, 0.3)
            grown_at_start = late.grow_count
            assert np.array_equal(late.field, kept.field)
    assert late.grow_count > grown_at_start >= 1 and late.shape == kept.shape
    assert np.array_equal(late.log_odds, kept.log_odds) and np.array_equal(late.field, kept.field)


@pytest.mark.parametrize("at_hits", [False, True])
def test_growing_keeps_every_cell_where_it_was_and_the_new_margins_empty(at_hits):
    """`ensure` past two sides at once: the old cells (log-odds and field) sit at the same world
    place in the grown grid, and every new cell is 0, as np.pad's zero margins were."""
    rng = np.random.default_rng(3)
    g = OccupancyGrid(MapConfig(initial_size_m=10.0), (0.0, 0.0), 0.1, 0.3, at_hits)
    for _ in range(20):
        g.insert(*_random_scan(rng, 1.0, 1.8))  # inside the 10 m grid: no growth yet
    assert g.grow_count == 0
    lo, field, origin = g.log_odds.copy(), g.field.copy(), g.origin.copy()
    g.ensure(-7.0, -2.0, 1.0, 9.0)  # beyond the left and top edges
    assert g.grow_count == 1
    dc, dr = int(round((origin[0] - g.origin[0]) / g.res)), int(round((origin[1] - g.origin[1]) / g.res))
    assert dc > 0 and dr == 0 and g.shape[0] > lo.shape[0]
    assert np.array_equal(g.log_odds[:lo.shape[0], dc:dc + lo.shape[1]], lo)
    margin = np.ones(g.shape, dtype=bool)
    margin[:lo.shape[0], dc:dc + lo.shape[1]] = False
    assert not g.log_odds[margin].any()
    if at_hits:
        assert g.hit_n.shape == g.shape and not g.hit_n[margin].any() and g.hit_n.any()
    # the field: unchanged inside, and in the margins exactly what the walls near the old edges give
    ref = _field_recomputed(g)
    assert np.array_equal(g.field[:lo.shape[0], dc:dc + lo.shape[1]], field)
    assert np.array_equal(g.field, ref)


def test_a_large_grid_grows_as_np_pad_and_gives_the_old_memory_back_only_when_no_one_holds_it(monkeypatch):
    """A grid over 8 MB an array grows band by band, giving the old array's pages back as they
    are copied (`heap.release_pages`; Linux). The values are np.pad's; an array someone else
    still holds (a reader that kept `grid.field`) is copied whole and left as it was."""
    import slamlab.slam.grid as grid_module

    released = []
    real = grid_module.release_pages
    monkeypatch.setattr(grid_module, "release_pages", lambda a, start, stop: released.append(a.shape) or real(a, start, stop))
    rng = np.random.default_rng(5)
    g = OccupancyGrid(MapConfig(initial_size_m=100.0), (0.0, 0.0), 0.1, 0.3)  # 2,000 x 2,000 cells: 16 MB an array
    for _ in range(30):
        g.insert(*_random_scan(rng, 40.0, 8.0))
    lo, origin = g.log_odds.copy(), g.origin.copy()
    held = g.field  # kept by "a reader": must survive the growth
    held_copy = held.copy()
    g.ensure(-60.0, -10.0, 10.0, 10.0)  # past the left edge
    assert g.grow_count == 1
    dc = int(round((origin[0] - g.origin[0]) / g.res))
    assert np.array_equal(g.log_odds, np.pad(lo, ((0, 0), (dc, g.shape[1] - lo.shape[1] - dc))))
    assert np.array_equal(held, held_copy)  # not given back
    assert released and set(released) == {lo.shape}  # the log-odds (no one else held it) was
    ref = _field_recomputed(g)
    assert np.array_equal(g.field, ref)


def test_growing_an_array_no_one_reads_again_gives_its_pages_back():
    """`_copy_into(..., release_old=True)`: np.pad's values, and the old array's whole pages read as
    zeros after (given back to the system) but for its last partial page."""
    import sys

    from slamlab.slam.grid import _copy_into

    if not sys.platform.startswith("linux"):
        return  # madvise(MADV_DONTNEED) is Linux's; elsewhere the copy is a plain one (checked above)
    a = np.random.default_rng(6).random((3000, 1000)).astype(np.float32) + 1.0  # 12 MB, no zero
    ref = np.pad(a, ((2, 3), (4, 5)))
    out = np.zeros((3005, 1009), dtype=np.float32)
    _copy_into(a, out, 2, 4, release_old=True)
    assert np.array_equal(out, ref)
    import mmap

    end_in_partial_page = (a.ctypes.data + a.nbytes) % mmap.PAGESIZE != 0
    zero = (a.reshape(-1) == 0)
    assert zero.mean() > 0.99  # given back: all but the partial first and last pages
    assert zero[-1] != end_in_partial_page  # a last partial page is kept (its other bytes may be someone else's)


def _brute_force_field(g: OccupancyGrid, sigma_m: float, radius_m: float) -> np.ndarray:
    """The field from its definition: each cell's value is the largest exp(-d^2 / 2 sigma^2) over
    the walls within R cells in rows and columns (R = radius_m in cells) and within R + 1/2 cells
    of it, d the distance (m) from the cell's centre to the wall's place: its cell's centre moved
    by its mean hit offset, rounded to the nearest of WALL_STEPS places a side."""
    res, R = g.res, int(np.ceil(radius_m / g.res))
    walls = np.argwhere(g.log_odds > g.s.occupied_threshold)
    place = lambda o: ((np.floor((int(o) + HIT_UNITS / 2) / HIT_UNITS * WALL_STEPS) + 0.5) / WALL_STEPS - 0.5)
    out = np.zeros(g.shape)
    for r, c in walls:
        px, py = c + place(g.hit_dx[r, c]), r + place(g.hit_dy[r, c])  # the wall's place (cells)
        rr, cc = np.mgrid[max(r - R, 0):min(r + R + 1, g.shape[0]), max(c - R, 0):min(c + R + 1, g.shape[1])]
        d2 = ((cc - px) ** 2 + (rr - py) ** 2) * res**2
        v = np.where(d2 <= ((R + 0.5) * res) ** 2, np.exp(-d2 / (2 * sigma_m**2)), 0.0)
        out[rr, cc] = np.maximum(out[rr, cc], v)
    return out


def test_walls_at_hits_keep_the_mean_of_their_hits_and_the_field_peaks_there():
    """Hits scattered in one cell around (0.3, -0.2) cells from its centre: the cell keeps their
    mean (to 1/256 cell), and the field is highest on that side of it."""
    rng = np.random.default_rng(7)
    g = OccupancyGrid(MapConfig(initial_size_m=4.0), (0.0, 0.0), 0.05, 0.2, walls_at_hits=True)
    r, c = 40, 40
    centre = g.origin + (np.array([c, r]) + 0.5) * g.res
    offsets = np.array([0.3, -0.2]) + rng.uniform(-0.15, 0.15, (HIT_COUNT_CAP, 2))  # cells: up to the cap, a plain mean
    for o in offsets:
        g.insert(centre + np.array([-1.0, 0.3]), (centre + o * g.res).reshape(1, 2))
    assert g.hit_n[r, c] == HIT_COUNT_CAP
    mean = offsets.mean(axis=0) * HIT_UNITS
    assert abs(g.hit_dx[r, c] - mean[0]) <= 1.5 and abs(g.hit_dy[r, c] - mean[1]) <= 1.5
    f = g.field_values()
    assert f[r, c + 1] > f[r, c - 1] and f[r - 1, c] > f[r + 1, c]
    assert np.allclose(f, _brute_force_field(g, 0.05, 0.2), atol=1e-6)


def test_walls_at_hits_field_kept_scan_by_scan_equals_its_definition():
    """Random scans, some hitting the same cells again (their walls move within the cell) and
    some freeing walls: after each, the field kept incrementally is exactly the field recomputed
    over the whole grid, and (checked now and then, it is slow) its definition."""
    rng = np.random.default_rng(8)
    g = OccupancyGrid(MapConfig(initial_size_m=12.0), (0.0, 0.0), 0.1, 0.3, walls_at_hits=True)
    moved = 0
    place = lambda a: (a.astype(np.int64) + HIT_UNITS // 2) * WALL_STEPS // HIT_UNITS
    for i in range(150):
        sensor, pts = _random_scan(rng, 2.0, 4.0)
        if i % 3 == 0:
            pts = np.round(pts, 1) + rng.normal(0.0, 0.01, pts.shape)  # the same cells hit again, at other places within them
        before = place(g.hit_dx), place(g.hit_dy), g.log_odds > g.s.occupied_threshold
        g.insert(sensor, pts)
        moved += int(np.count_nonzero(((place(g.hit_dx) != before[0]) | (place(g.hit_dy) != before[1])) & before[2]))
        ref = _field_recomputed(g)
        assert np.array_equal(g.field, ref), f"field differs after scan {i}"
        if i % 50 == 49:
            assert np.allclose(g.field_values(), _brute_force_field(g, 0.1, 0.3), atol=1e-6)
    assert moved > 50  # walls did move within their cells


def test_a_wall_seen_long_follows_its_newest_hits_past_the_count_cap():
    """Past HIT_COUNT_CAP hits a cell's mean is a moving average: a wall hit many times at its
    centre, then many times 0.3 cells off, ends within the rounding's dead band (about half the
    cap, in 1/HIT_UNITS of a cell) of the new offset, not stuck near the old one."""
    g = OccupancyGrid(MapConfig(initial_size_m=4.0), (0.0, 0.0), 0.05, 0.2, walls_at_hits=True)
    r, c = 40, 40
    centre = g.origin + (np.array([c, r]) + 0.5) * g.res
    for offset in [0.0] * 3 * HIT_COUNT_CAP + [0.3] * 20 * HIT_COUNT_CAP:
        g.insert(centre + np.array([-1.0, 0.0]), (centre + np.array([offset, 0.0]) * g.res).reshape(1, 2))
    assert g.hit_n[r, c] == HIT_COUNT_CAP
    # within half a place of it (the place the field uses), where the dead band of a longer mean would leave it
    assert abs(int(g.hit_dx[r, c]) - 0.3 * HIT_UNITS) < HIT_UNITS / WALL_STEPS / 2 and g.hit_dy[r, c] == 0


@pytest.mark.parametrize("at_hits", [False, True])
def test_the_field_kept_as_codes_holds_exactly_the_float32_field(at_hits):
    """The grid keeps its field as codes of its kernels' values (one byte at cell centres, two
    with walls at their hits) and the values they decode to are, bit for bit, the float32 field
    the same kernels give computed on values; a matcher reads the same sums from either form."""
    from slamlab.slam.matcher import score_field

    rng = np.random.default_rng(9)
    g = OccupancyGrid(MapConfig(initial_size_m=12.0), (0.0, 0.0), 0.1, 0.3, walls_at_hits=at_hits)
    for _ in range(80):
        g.insert(*_random_scan(rng, 2.0, 4.0))
    assert g.field.dtype == (np.uint16 if at_hits else np.uint8)
    values = np.zeros(g.shape, dtype=np.float32)
    update_field(g.log_odds, values, np.float32(g.s.occupied_threshold), g.field_lut[g.bank], g.hit_dx, g.hit_dy, 0, g.shape[0], 0, g.shape[1])
    assert np.count_nonzero(values) > 1000
    assert np.array_equal(g.field_values(), values)
    scan = _random_scan(rng, 0.0, 4.0)[1]
    for x, y, th in rng.normal(0.0, [0.3, 0.3, 0.5], (20, 3)):
        assert score_field(g.field_cells, g.origin[0], g.origin[1], 1.0 / g.res, x, y, th, scan) == \
            score_field(values, g.origin[0], g.origin[1], 1.0 / g.res, x, y, th, scan)


@pytest.mark.parametrize("at_hits", [False, True])
def test_the_field_recomputed_in_row_bands_on_all_cores_is_the_field_recomputed_at_once(at_hits):
    """`update_field_bands` (a whole map's field after it is redrawn): each band takes its values
    from the walls within R rows of it, so any band height gives the one-pass field, also over
    a box that does not start at the grid's edge."""
    from slamlab.slam.raycast import update_field_bands

    rng = np.random.default_rng(10)
    g = OccupancyGrid(MapConfig(initial_size_m=12.0), (0.0, 0.0), 0.1, 0.3, walls_at_hits=at_hits)
    for _ in range(60):
        g.insert(*_random_scan(rng, 2.0, 4.0))
    thresh = np.float32(g.s.occupied_threshold)
    for r0, r1, c0, c1 in ((0, g.shape[0], 0, g.shape[1]), (17, 90, 5, 101)):
        ref, banded = g.field.copy(), g.field.copy()
        update_field(g.log_odds, ref, thresh, g.bank, g.hit_dx, g.hit_dy, r0, r1, c0, c1)
        for band_rows in (1, 7, 64, 1000):
            banded[r0:r1, c0:c1] = 0
            update_field_bands(g.log_odds, banded, thresh, g.bank, g.hit_dx, g.hit_dy, r0, r1, c0, c1, band_rows)
            assert np.array_equal(banded, ref), f"band of {band_rows} rows over {(r0, r1, c0, c1)}"
    assert np.count_nonzero(ref) > 1000
