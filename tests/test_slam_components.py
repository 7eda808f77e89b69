"""Unit tests of the SLAM components on small cases with known answers."""

import warnings

import numpy as np
import pytest

from slamlab.config.slam import CourseMotionConfig
from slamlab.errors import ConfigError
from slamlab.frames import ScanFrame
from slamlab.geometry import rot_y, rot_z, trans
from slamlab.slam.grid import MapSettings, OccupancyGrid
from slamlab.slam.matcher import GridMatcher, LikelihoodFieldMatcher, offset_grid
from slamlab.slam.motion import CourseMotion, Odometry4Motion
from slamlab.slam.raycast import bresenham, raycast_update, update_field
from slamlab.slam.resample import MultinomialResampler, ResidualResampler, StratifiedResampler, SystematicResampler
from slamlab.slam.scan import ScanBatch, ScanPoints, scan_to_points, scans_to_points
from slamlab.slam.steps import fill_between_steps, select_steps
from slamlab.slam.weighting import LinearWeighting, LogSumExpWeighting, WeightUnderflowWarning, effective_sample_size, logsumexp

# ---------------------------------------------------------------- ray casting


def test_bresenham_reference_cells():
    assert bresenham(0, 0, 0, 3) == [(0, 0), (0, 1), (0, 2), (0, 3)]
    assert bresenham(0, 0, 2, 2) == [(0, 0), (1, 1), (2, 2)]
    assert bresenham(3, 1, 0, 1) == [(3, 1), (2, 1), (1, 1), (0, 1)]


def _cast(r0, c0, ends, shape=(12, 12)):
    lo = np.zeros(shape, np.float32)
    flip = np.array([10**9, -1, 10**9, -1], np.int64)
    rows = np.array([e[0] for e in ends], np.int64)
    cols = np.array([e[1] for e in ends], np.int64)
    raycast_update(lo, r0, c0, rows, cols, np.float32(1.0), np.float32(-0.5), np.float32(-2.0), np.float32(2.0), np.float32(0.0), flip)
    return lo, flip


def test_raycast_walks_the_reference_cells_in_every_direction():
    """The kernels compute Bresenham's minor-axis steps instead of branching on them: every
    beam from the centre to each cell of a 41 x 41 square (all octants, steep and shallow,
    axis-aligned and diagonal) updates exactly the reference line's cells."""
    for r1 in range(0, 41):
        for c1 in range(0, 41):
            if (r1, c1) == (20, 20):
                continue
            lo, _ = _cast(20, 20, [(r1, c1)], shape=(41, 41))
            cells = bresenham(20, 20, r1, c1)
            free = {(int(r), int(c)) for r, c in zip(*np.nonzero(lo < 0))}
            assert free == set(cells[:-1]) and lo[r1, c1] > 0


def test_raycast_matches_reference_and_clamps():
    lo, flip = _cast(1, 1, [(7, 4)])
    cells = bresenham(1, 1, 7, 4)
    for r, c in cells[:-1]:
        assert lo[r, c] == pytest.approx(-0.5)
    assert lo[7, 4] == pytest.approx(1.0)
    assert np.count_nonzero(lo) == len(cells)
    assert list(flip) == [7, 7, 4, 4]  # only the hit cell became occupied
    # ten beams through the same cells clamp at the bounds
    lo, _ = _cast(0, 0, [(0, 5)] * 10)
    assert lo[0, 5] == pytest.approx(2.0) and lo[0, 2] == pytest.approx(-2.0)


def test_raycast_hits_not_erased_by_neighbour_beams():
    # the second beam passes through the first beam's end cell: hits are applied last
    lo, _ = _cast(0, 0, [(0, 3), (0, 6)])
    assert lo[0, 3] == pytest.approx(0.5)  # -0.5 (crossed) + 1.0 (hit)


def test_grid_grows_and_keeps_content():
    g = OccupancyGrid(MapSettings(resolution_m=0.1, initial_size_m=2.0, growth_margin_m=1.0))
    g.insert(np.zeros(2), np.array([[0.55, 0.0]]))
    assert g.occupied().sum() == 1
    g.insert(np.zeros(2), np.array([[5.0, -4.0]]))  # far outside the 2 m grid
    assert g.grow_count >= 1
    r, c = g.cells(np.array([[0.55, 0.0], [5.0, -4.0]]))
    assert g.occupied()[r[0], c[0]] and g.occupied()[r[1], c[1]]


def test_likelihood_field_is_right_after_the_grid_grows():
    # a wall cell right next to the left edge: growing to the left must extend its field
    # into the new margin exactly as a full recomputation would
    g = OccupancyGrid(MapSettings(resolution_m=0.1, initial_size_m=2.0, growth_margin_m=1.0),
                      field_sigma_m=0.1, field_radius_m=0.3)
    g.insert(np.array([0.0, 0.0]), np.array([[-0.85, 0.0]]))  # hit lands in column 1
    assert g.grow_count == 0
    g.insert(np.array([0.0, 0.0]), np.array([[-3.0, 0.5]]))  # forces growth to the left
    assert g.grow_count >= 1
    full = np.zeros_like(g.field)
    H, W = g.shape
    update_field(g.log_odds, full, np.float32(g.s.occupied_threshold), g.bank, g.hit_dx, g.hit_dy, 0, H, 0, W)
    np.testing.assert_array_equal(g.field, full)
    r, c = g.cells(np.array([[-0.95, 0.0]]))  # a new cell one step left of the old wall
    assert g.field_values()[r[0], c[0]] > 0.5


# ---------------------------------------------------------------- scan to points


def _frame(ranges, angles, l2b=None, pitch=0.0):
    r = np.asarray(ranges, np.float32)
    return ScanFrame(index=0, t=0.0, odom=np.zeros(3), ranges=r, angles=np.asarray(angles, np.float32),
                     valid=np.ones(len(r), bool), lidar_to_body=np.eye(4) if l2b is None else l2b, pitch=pitch)


def test_scan_to_points_ranges_and_mount():
    f = _frame([1.0, 0.05, 50.0, 2.0], [0.0, 0.0, 0.0, np.pi / 2], l2b=trans(x=0.1))
    p = scan_to_points(f, None, min_range_m=0.1, max_range_m=30.0, ground_threshold_m=0.1)
    np.testing.assert_allclose(p.xy, [[1.1, 0.0], [0.1, 2.0]], atol=1e-6)
    np.testing.assert_allclose(p.origin, [0.1, 0.0])


def test_scan_to_points_drops_ground_hits():
    # lidar 1.41 m above the floor, body pitched down 30 deg: a 1 m beam stays high, a 5 m
    # beam reaches the floor (z = 1.41 - 5 sin 30 < 0) and is dropped
    f = _frame([1.0, 5.0], [0.0, 0.0], l2b=trans(z=0.48), pitch=np.radians(30))
    p = scan_to_points(f, 0.93, 0.1, 30.0, ground_threshold_m=0.1)
    assert len(p.xy) == 1
    np.testing.assert_allclose(p.xy[0], (rot_y(np.radians(30)) @ [1.0, 0, 0, 1])[:2] + 0.48 * np.sin(np.radians(30)) * np.array([1, 0]), atol=1e-9)


def _random_frames(rng, n, l2b, pitch=0.0, zero_range=False):
    """Frames of varying beam counts and angle sets, with invalid, NaN, short and long beams."""
    frames = []
    for i in range(n):
        m = int(rng.integers(0, 40))
        r = rng.uniform(0.0, 40.0, m)
        r[rng.random(m) < 0.1] = np.nan
        if zero_range and m:
            r[0] = 0.0
        angles = np.linspace(-np.pi / 2, np.pi / 2, m) if i % 2 else rng.uniform(-np.pi, np.pi, m)
        f = _frame(r, angles, l2b=l2b, pitch=pitch)
        f.valid[rng.random(m) < 0.1] = False
        frames.append(f)
    return frames


@pytest.mark.parametrize("case", ["unrotated", "rotated", "pitched", "body_height", "zero_range"])
def test_scans_to_points_is_scan_to_points(case):
    # the batched projection (an unrotated planar mount: offsets added in one pass) and its
    # fallbacks (anything else goes scan by scan) give scan_to_points' arrays to the bit
    rng = np.random.default_rng(7)
    l2b = rot_z(0.3) @ trans(x=0.2, y=-0.1) if case == "rotated" else trans(x=0.137, y=-0.021)
    frames = _random_frames(rng, 60, l2b, pitch=0.1 if case == "pitched" else 0.0, zero_range=case == "zero_range")
    height, lo = (0.9 if case == "body_height" else None), (0.0 if case == "zero_range" else 0.1)
    got = scans_to_points(frames, height, lo, 30.0, 0.1)
    batched = got[0].xy.base is not None and all(g.xy.base is got[0].xy.base for g in got)  # views of one array
    assert batched == (case == "unrotated")
    for g, f in zip(got, frames, strict=True):
        want = scan_to_points(f, height, lo, 30.0, 0.1)
        assert g.xy.shape == want.xy.shape and g.xy.flags.c_contiguous
        assert g.xy.tobytes() == want.xy.tobytes() and g.origin.tobytes() == want.origin.tobytes()


# ---------------------------------------------------------------- weighting, N_eff


def test_neff_known_values():
    assert effective_sample_size(np.full(10, 0.1)) == pytest.approx(10.0)
    assert effective_sample_size(np.array([1.0, 0, 0, 0])) == pytest.approx(1.0)
    assert effective_sample_size(np.array([0.5, 0.5, 0, 0])) == pytest.approx(2.0)


def test_logsumexp_extreme_values():
    assert logsumexp(np.array([1000.0, 1000.0])) == pytest.approx(1000.0 + np.log(2))
    assert logsumexp(np.array([-1000.0, -1000.0])) == pytest.approx(-1000.0 + np.log(2))
    assert logsumexp(np.array([0.0, -np.inf])) == 0.0
    w = LogSumExpWeighting(temperature=1.0)
    lw = w.update(np.log(np.full(3, 1 / 3)), np.array([5000.0, 4000.0, -1e6]))
    assert np.all(np.isfinite(lw[:2])) and lw[0] == pytest.approx(0.0) and np.exp(lw).sum() == pytest.approx(1.0)


def test_logsumexp_temperature():
    lw = LogSumExpWeighting(temperature=2.0).update(np.log([0.5, 0.5]), np.array([2.0, 0.0]))
    np.testing.assert_allclose(np.exp(lw), [np.e / (np.e + 1), 1 / (np.e + 1)])


def test_linear_weighting_known_and_underflow_fallback():
    lin = LinearWeighting()
    lw = lin.update(np.log([0.5, 0.5]), np.array([3.0, 1.0]))
    np.testing.assert_allclose(np.exp(lw), [0.75, 0.25])
    # tiny weights times tiny correlations underflow float64 to exactly 0 for everyone
    with pytest.warns(WeightUnderflowWarning, match="underflowed.*uniform.*logsumexp"):
        lw = lin.update(np.log([1e-200, 1e-200]), np.array([1e-200, 1e-200]))
    np.testing.assert_allclose(np.exp(lw), [0.5, 0.5])
    assert lin.underflows == 1
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # warned once; later occurrences only counted + logged
        lin.update(np.log([0.5, 0.5]), np.zeros(2))
    assert lin.underflows == 2


# ---------------------------------------------------------------- resampling


@pytest.mark.parametrize("cls", [MultinomialResampler, SystematicResampler, StratifiedResampler, ResidualResampler])
def test_resamplers_are_unbiased(cls):
    w = np.array([0.5, 0.25, 0.125, 0.125, 0.0])
    rng = np.random.Generator(np.random.PCG64(3))
    r = cls(threshold=0.5)
    counts = np.zeros(5)
    reps = 2000
    for _ in range(reps):
        idx = r.indices(w, rng)
        assert idx.shape == (5,) and idx.min() >= 0 and idx.max() <= 4
        counts += np.bincount(idx, minlength=5)
    np.testing.assert_allclose(counts / (reps * 5), w, atol=0.02)
    assert counts[4] == 0  # a zero-weight particle is never drawn


@pytest.mark.parametrize("cls", [SystematicResampler, StratifiedResampler, ResidualResampler])
def test_low_variance_resamplers_copy_exact_multiples(cls):
    # N w_i are integers: these schemes reproduce them exactly, every time
    w = np.array([0.5, 0.25, 0.25, 0.0])
    idx = cls().indices(w, np.random.Generator(np.random.PCG64(0)))
    np.testing.assert_array_equal(np.bincount(idx, minlength=4), [2, 1, 1, 0])


def test_resample_trigger():
    r = SystematicResampler(threshold=0.5)
    assert not r.should_resample(np.full(4, 0.25))
    assert r.should_resample(np.array([0.97, 0.01, 0.01, 0.01]))


# ---------------------------------------------------------------- motion


def test_motion_models_no_noise_when_standing_still():
    poses = np.array([[1.0, 2.0, 0.3]] * 5)
    rng = np.random.Generator(np.random.PCG64(0))
    for m in (CourseMotion(), Odometry4Motion()):
        np.testing.assert_allclose(m.sample(poses, np.zeros(3), rng), poses, atol=1e-12)


def _forward_step_spread(model, step_m: float, n: int = 20000) -> tuple[np.ndarray, np.ndarray]:
    """Mean and spread (std of world x, y, theta) of `n` particles facing +y after one
    forward odometry step of `step_m` metres: world y is along track, world x across."""
    rng = np.random.Generator(np.random.PCG64(0))
    poses = np.zeros((n, 3))
    poses[:, 2] = np.pi / 2
    out = model.sample(poses, np.array([step_m, 0.0, 0.0]), rng)
    return out.mean(axis=0), out.std(axis=0)


@pytest.mark.parametrize("step_m", [0.5, 1.0])
def test_course_motion_spread_per_metre_is_the_configured_sigma(step_m):
    # linear growth: sigma per `per_distance_m` of travel, i.e. sigma * step / per_distance_m
    m = CourseMotion(sigma_xy_m=0.01, sigma_theta_rad=0.02, per_distance_m=0.1, per_angle_rad=0.1)
    mean, spread = _forward_step_spread(m, step_m)
    k = step_m / 0.1
    np.testing.assert_allclose(mean, [0.0, step_m, np.pi / 2], atol=3 * 0.02 * k / np.sqrt(20000) + 1e-3)
    # 20000 samples: the std of a std is ~0.5 %; 3 % leaves room and catches a wrong scale
    np.testing.assert_allclose(spread, [0.01 * k, 0.01 * k, 0.02 * k], rtol=0.03)


@pytest.mark.parametrize("step_m", [0.5, 1.0])
def test_odometry4_spread_per_metre_follows_the_alphas(step_m):
    # a straight step: rot1 = rot2 = 0, so trans varies with sqrt(alpha3) per metre and each
    # turn with sqrt(alpha2) per metre; across track the position moves by trans * rot1
    a1, a2, a3, a4 = 0.05, 0.001, 0.01, 0.02
    mean, spread = _forward_step_spread(Odometry4Motion(a1, a2, a3, a4), step_m)
    np.testing.assert_allclose(mean, [0.0, step_m, np.pi / 2], atol=2e-3)
    s_trans, s_rot = np.sqrt(a3) * step_m, np.sqrt(a2) * step_m
    want = [step_m * s_rot, s_trans, np.hypot(s_rot, s_rot)]  # across (x), along (y), heading
    np.testing.assert_allclose(spread, want, rtol=0.03)


# ---------------------------------------------------------------- correlation on a known map


def _box_map():
    """A 4 x 4 m room (walls at x, y = +-2 m) mapped from the centre."""
    g = OccupancyGrid(MapSettings(resolution_m=0.05, initial_size_m=6.0), field_sigma_m=0.05, field_radius_m=0.2)
    a = np.linspace(-np.pi, np.pi, 360, endpoint=False)
    d = 2.0 / np.maximum(np.abs(np.cos(a)), np.abs(np.sin(a)))  # distance to the square's wall
    pts = np.stack([d * np.cos(a), d * np.sin(a)], 1) * 0.999
    for _ in range(3):
        g.insert(np.zeros(2), pts)
    return g, ScanPoints(xy=pts[::3], origin=np.zeros(2))


def test_grid_matcher_finds_known_offset():
    g, scan = _box_map()
    m = GridMatcher(xy_half_width_m=0.2, xy_step_m=0.05, beam_step=1)  # every point (the config's default is 4)
    start = np.array([[0.10, -0.15, 0.0], [0.0, 0.0, 0.0]])
    best, score = m.match(g, start, scan)
    np.testing.assert_allclose(best, 0.0, atol=1e-9)
    assert score[0] == score[1] == len(scan.xy)  # every point on a wall


def test_likelihood_matcher_recovers_pose_subcell():
    g, scan = _box_map()
    m = LikelihoodFieldMatcher(sigma_m=0.05, radius_m=0.2, xy_half_width_m=0.1, xy_step_m=0.05, yaw_half_width_rad=0.1,
                               yaw_step_rad=0.025, refine_levels=5, prior_sigma_xy_m=0.0, prior_sigma_yaw_rad=0.0)
    start = np.array([[0.07, -0.06, 0.05]])
    best, _ = m.match(g, start, scan)
    np.testing.assert_allclose(best[0], 0.0, atol=0.015)


def test_matchers_count_the_map_cells_they_read():
    """`map_reads` (metrics.json's matcher_map_reads): a hit test reads one cell per point and
    offset; a bilinear field value reads four. A climb that starts at the optimum scores its
    start and six neighbours per level and stops; one from off the optimum scores more."""
    g, scan = _box_map()
    m = len(scan.xy)
    grid = GridMatcher(xy_half_width_m=0.2, xy_step_m=0.05, beam_step=1)
    grid.match(g, np.zeros((2, 3)), scan)
    assert grid.map_reads == 2 * 81 * m
    lf = LikelihoodFieldMatcher(xy_half_width_m=0.0, yaw_half_width_rad=0.0, refine_levels=0, beam_step=1)
    lf.match(g, np.zeros((3, 3)), scan)
    assert lf.map_reads == 3 * 4 * m  # no coarse grid, no climb: one field value per point
    climb = LikelihoodFieldMatcher(xy_half_width_m=0.1, xy_step_m=0.05, yaw_half_width_rad=0.0, refine_levels=3, coarse_beam_step=3, beam_step=1)
    climb.match(g, np.array([[0.06, -0.04, 0.02]]), scan)
    coarse = 25 * len(scan.xy[::3])
    fine = climb.map_reads / 4 - coarse
    # the start, then at least one round of six moves per level, each over every point
    assert fine % m == 0 and fine / m >= 1 + 6 * 3


def test_tiled_coarse_grid_counts_each_yaws_window_once():
    """On tiled maps a coarse grid of whole-cell shifts reads, for each yaw and coarse point,
    the window of cells its shifts touch once (5 x 5 shifts: 6 x 6 cells), not four cells
    per shift; the climb's scores still read four per point."""
    from slamlab.slam.tiles import TiledMaps

    maps = TiledMaps(MapSettings(resolution_m=0.05), 2, (0.0, 0.0), field_sigma_m=0.1, field_radius_m=0.3)
    scan = ScanPoints(xy=_corridor_scan(), origin=np.zeros(2))
    maps.insert_scan(np.zeros((2, 3)), scan.xy, scan.origin)
    m = LikelihoodFieldMatcher(xy_half_width_m=0.1, xy_step_m=0.05, yaw_half_width_rad=0.025, yaw_step_rad=0.025, refine_levels=0, coarse_beam_step=3, beam_step=1)
    m.match_each(maps, np.zeros((2, 3)), scan)
    coarse, fine, _ = m._points(scan)
    assert m.map_reads == 2 * 3 * len(coarse) * 36 + 2 * 4 * len(fine)  # 3 yaws; a climb of 0 levels scores once
    # off whole cells the kernel places every offset: four cells per offset and point
    half = LikelihoodFieldMatcher(xy_half_width_m=0.05, xy_step_m=0.025, yaw_half_width_rad=0.0, refine_levels=0, coarse_beam_step=3, beam_step=1)
    half.match_each(maps, np.zeros((2, 3)), scan)
    assert half.map_reads == 2 * 25 * len(coarse) * 4 + 2 * 4 * len(fine)


@pytest.mark.parametrize("kind", ["likelihood", "stretch", "grid"])
def test_match_scans_gives_each_scan_what_matching_it_alone_gives(kind):
    """`match_scans` (the scans between two filter steps against one particle's map; one
    kernel call for the likelihood matcher) gives every scan the pose, to the bit, and counts
    the map reads that matching it alone against that particle's map gives; with
    `isolated=stretch` also when some scans of the batch have stretches and some none. (The
    grid matcher has no batched kernel: its loop is the reference, checked for the map.)"""
    from slamlab.slam.tiles import TiledMaps

    rng = np.random.default_rng(5)
    maps = TiledMaps(MapSettings(resolution_m=0.05), 3, (0.0, 0.0), field_sigma_m=0.1, field_radius_m=0.3)
    base = _corridor_scan()
    for _ in range(3):  # three different maps
        maps.insert_scan(rng.normal(0.0, [0.05, 0.05, 0.02], (3, 3)), base, np.zeros(2))
    scans = [ScanPoints(xy=base[i::2] + rng.normal(0.0, 0.01, base[i::2].shape), origin=np.zeros(2)) for i in range(2)]
    scans.append(ScanPoints(xy=base[::3], origin=np.zeros(2)))
    scans.append(ScanPoints(xy=np.column_stack([np.linspace(1.0, 3.0, 41), np.full(41, 1.0)]), origin=np.zeros(2)))  # a wall: no lone hit
    poses = rng.normal(0.0, [0.06, 0.06, 0.03], (4, 3))
    make = {"likelihood": lambda: LikelihoodFieldMatcher(max_gap_m=0.6),
            "stretch": lambda: LikelihoodFieldMatcher(max_gap_m=0.6, isolated="stretch"),
            "grid": lambda: GridMatcher(beam_step=2)}[kind]
    if kind == "stretch":  # the batch mixes scans with stretches and one without
        has = [len(make()._points(scan)[2]) > 0 for scan in scans]
        assert any(has) and not all(has)
    batch, alone = make(), make()
    got = batch.match_scans(maps, 1, poses, ScanBatch.of(scans))
    want = np.vstack([alone.match_each(maps, poses[i:i + 1], scan, tables=maps.table[1:2])[0] for i, scan in enumerate(scans)])
    assert got.tobytes() == want.tobytes() and batch.map_reads == alone.map_reads > 0
    assert not np.allclose(got, poses)
    # particle 1's map is what was matched: another particle's map moves the poses elsewhere
    assert not np.array_equal(make().match_scans(maps, 2, poses, ScanBatch.of(scans)), got)
    assert make().match_scans(maps, 1, poses[:0], ScanBatch.of([])).shape == (0, 3)


@pytest.mark.parametrize("max_gap_m, coarse_step, beam_step", [(0.6, 3, 1), (0.6, 2, 3), (0.0, 3, 2)])
def test_prepared_scans_pick_what_points_picks_scan_by_scan(max_gap_m, coarse_step, beam_step):
    # the scans between two steps have their points picked for all of them at once in NumPy:
    # the same rows `_points` picks in each scan alone, including a scan whose points all lie
    # far apart (all kept), a one-point scan and scans of widely spaced hits among close ones
    rng = np.random.default_rng(11)
    xys = [np.cumsum(rng.normal(0.0, 0.3, (n, 2)), axis=0) for n in (40, 1, 25, 60)]
    xys.insert(2, np.arange(10.0).repeat(2).reshape(10, 2) * 2.0)  # every gap 2.8 m: no close neighbour
    xys = [np.empty((0, 2))] + xys[:3] + [np.empty((0, 2))] + xys[3:] + [np.empty((0, 2))]  # scans without points
    m = LikelihoodFieldMatcher(max_gap_m=max_gap_m, coarse_beam_step=coarse_step, beam_step=beam_step)
    got = m.prepare_scans(ScanBatch.of([ScanPoints(xy=xy, origin=np.zeros(2)) for xy in xys]))
    parts = [m._points(ScanPoints(xy=xy, origin=np.zeros(2))) for xy in xys]
    assert len(got.ext) == 0 and got.coarse.flags.c_contiguous and got.fine.flags.c_contiguous
    for i, (c, f, _) in enumerate(parts):
        assert got.coarse[got.coarse_ends[i]:got.coarse_ends[i + 1]].tobytes() == c.tobytes()
        assert got.fine[got.fine_ends[i]:got.fine_ends[i + 1]].tobytes() == f.tobytes()
    assert got.samples.tolist() == [len(f) for _, f, _ in parts]
    # a slice of the prepared scans is what preparing those scans alone gives
    part = got.scans(3, 7)
    alone = m.prepare_scans(ScanBatch.of([ScanPoints(xy=xy, origin=np.zeros(2)) for xy in xys[3:7]]))
    assert all(getattr(part, k).tobytes() == getattr(alone, k).tobytes() for k in ("coarse", "fine", "coarse_ends", "fine_ends", "samples"))
    if max_gap_m > 0:  # the isolated-point filter did drop points somewhere, and kept the far-apart scan whole
        assert sum(len(f) for _, f, _ in parts) < sum(len(xy[::beam_step]) for xy in xys)
        assert len(parts[3][1]) == len(xys[3][::beam_step])


def test_offset_grid_sizes_and_order():
    o = offset_grid(0.2, 0.05, 0.0, 0.01)
    assert o.shape == (81, 3)
    np.testing.assert_array_equal(o[0], 0.0)  # ties favour not moving


# ---------------------------------------------------------------- step selection and filling


def test_select_steps_every_and_distance():
    odom = np.zeros((10, 3))
    odom[3:, 0] = np.arange(7) * 0.1  # static for scans 0..3, then 0.1 m per scan
    assert list(select_steps(odom, every=1)) == list(range(3, 10))
    assert list(select_steps(odom, every=3)) == [3, 6, 9]
    assert list(select_steps(odom, min_distance_m=0.25)) == [3, 6, 9]
    assert list(select_steps(odom, every=1, skip_static_start=False))[0] == 0


def test_fill_between_steps_composes_odometry():
    odom = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]], float)
    est = np.array([[0, 0, np.pi / 2], [0, 2, np.pi / 2]], float)  # estimate turned by 90 deg
    full = fill_between_steps(np.array([0, 2]), est, odom)
    np.testing.assert_allclose(full[:, :2], [[0, 0], [0, 1], [0, 2], [0, 3]], atol=1e-12)


def test_fill_between_steps_takes_a_scans_matched_motion_where_it_has_one():
    """`motion` rows (a scan's matched motion from its step, `steps.between=match`) replace
    the odometry since the step; NaN rows keep it."""
    odom = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]], float)
    est = np.array([[0, 0, np.pi / 2], [0, 2, np.pi / 2]], float)
    motion = np.full((4, 3), np.nan)
    motion[1] = [0.9, 0.1, 0.0]  # scan 1 matched 0.9 m ahead, 0.1 m left of step 0
    full = fill_between_steps(np.array([0, 2]), est, odom, motion)
    np.testing.assert_allclose(full[:, :2], [[0, 0], [-0.1, 0.9], [0, 2], [0, 3]], atol=1e-12)


def _spread_after(model: CourseMotion, step_m: float, total_m: float = 1.0, n: int = 20000) -> float:
    rng = np.random.default_rng(0)
    poses = np.zeros((n, 3))
    for _ in range(int(round(total_m / step_m))):
        poses = model.sample(poses, np.array([step_m, 0.0, 0.0]), rng)
    return float(poses[:, 1].std())  # sideways spread (m)


def test_course_motion_sqrt_growth_spreads_the_same_per_metre_whatever_the_step():
    lin = CourseMotion(sigma_xy_m=0.02, sigma_theta_rad=0.0, per_distance_m=0.2)
    sq = CourseMotion(sigma_xy_m=0.02, sigma_theta_rad=0.0, per_distance_m=0.2, growth="sqrt")
    # one reference step: both give the configured sigma
    assert _spread_after(sq, 0.2, 0.2) == pytest.approx(0.02, rel=0.03)
    assert _spread_after(lin, 0.2, 0.2) == pytest.approx(0.02, rel=0.03)
    # over 1 m: sqrt gives sigma * sqrt(1 / 0.2) at any step; linear shrinks with the step
    want = 0.02 * np.sqrt(5.0)
    assert _spread_after(sq, 0.1) == pytest.approx(want, rel=0.03)
    assert _spread_after(sq, 0.05) == pytest.approx(want, rel=0.03)
    assert _spread_after(lin, 0.1) == pytest.approx(want / np.sqrt(2), rel=0.03)
    with pytest.raises(ConfigError, match="motion.growth"):  # the schema checks, the model trusts it
        CourseMotionConfig(growth="cubic")


@pytest.mark.parametrize("yaw_half_width", [0.0, 0.02])
def test_grid_matcher_by_whole_cell_shifts_counts_what_every_offset_counts(yaw_half_width):
    """The course grid matcher places each yaw's points once and shifts them by whole cells
    (`grid_search_shifts`); it must pick the same offsets with the same counts as placing the
    points for every offset (`grid_search_hits`), including points lying exactly on cell
    borders, where rounding could otherwise move them to a neighbouring cell, and points whose
    shifts reach off the map."""
    from slamlab.slam.matcher import cell_shifts, grid_search_hits, grid_search_shifts

    rng = np.random.default_rng(5)
    res, ox, oy = 0.05, -6.4, -6.4
    lo = rng.choice([-1.0, 2.0], size=(256, 256), p=[0.8, 0.2]).astype(np.float32)
    offsets = offset_grid(0.2, res, yaw_half_width, 0.01)
    pts = rng.uniform(-4.0, 4.0, (200, 2))
    pts[:60] = np.round(pts[:60] / res) * res  # on cell borders (with the poses below)
    pts[60:80, 0] = rng.uniform(6.2, 6.6, 20)  # near the map's right and lower edges: from the
    pts[80:100, 1] = rng.uniform(-6.6, -6.2, 20)  # first pose (0, 0, 0) their shifts cross them
    pts[100] = [0.013, np.nan]  # a NaN scores nothing (numba checks no bounds: no read off the map)
    poses = np.vstack([np.zeros((1, 3)), np.column_stack([np.round(rng.uniform(-1, 1, (7, 2)) / res) * res, np.zeros(7)]),
                       rng.uniform(-1.0, 1.0, (8, 3)), [[np.nan, 0.0, 0.0]]])
    shifts, by_yaw, yaws = cell_shifts(offsets, res)
    assert len(shifts) == len(offsets)
    a_p, a_s = np.empty_like(poses), np.empty(len(poses))
    b_p, b_s = np.empty_like(poses), np.empty(len(poses))
    grid_search_hits(lo, np.float32(0.0), ox, oy, 1.0 / res, poses, pts, offsets, a_p, a_s)
    grid_search_shifts(lo, np.float32(0.0), ox, oy, 1.0 / res, poses, pts, offsets, shifts, by_yaw, yaws, b_p, b_s)
    np.testing.assert_array_equal(b_p, a_p)  # NaN where the reference has NaN (the NaN pose)
    np.testing.assert_array_equal(b_s, a_s)
    assert a_s[-1] == 0.0
    assert len(np.unique(a_s)) > 3  # the scores differ between particles: a real search
    # particles run on all cores: one thread gives the same bytes
    import numba

    c_p, c_s = np.empty_like(poses), np.empty(len(poses))
    before = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        grid_search_shifts(lo, np.float32(0.0), ox, oy, 1.0 / res, poses, pts, offsets, shifts, by_yaw, yaws, c_p, c_s)
    finally:
        numba.set_num_threads(before)
    assert np.array_equal(c_p, b_p, equal_nan=True) and np.array_equal(c_s, b_s)


@pytest.mark.parametrize("yaw_half_width", [0.0, 0.02])
def test_tiled_grid_matcher_by_whole_cell_shifts_counts_what_every_offset_counts(yaw_half_width):
    """The same for a map per particle in tiles (filter=rbpf, matcher=grid): block rows that
    cross a tile border, shared and empty tiles, points off the map."""
    from slamlab.slam.matcher import cell_shifts
    from slamlab.slam.shift_search import tiled_grid_search_shifts
    from slamlab.slam.tiled_match import tiled_grid_search
    from slamlab.slam.tiles import TILE

    rng = np.random.default_rng(7)
    res, ox, oy = 0.05, -6.4, -6.4
    side = 256 // TILE
    pool = rng.choice(np.array([-3, 4], np.int8), size=(12, TILE, TILE), p=[0.8, 0.2])
    pool[0] = 0  # the shared empty tile
    table = rng.integers(0, 12, size=(16, side, side)).astype(np.int32)  # particles share tiles
    offsets = offset_grid(0.2, res, yaw_half_width, 0.01)
    pts = rng.uniform(-4.0, 4.0, (200, 2))
    pts[:60] = np.round(pts[:60] / res) * res
    pts[60:80, 0] = rng.uniform(6.2, 6.6, 20)
    pts[80:100, 1] = rng.uniform(-6.6, -6.2, 20)
    pts[100] = [0.013, np.nan]
    poses = np.vstack([np.zeros((1, 3)), np.column_stack([np.round(rng.uniform(-1, 1, (7, 2)) / res) * res, np.zeros(7)]),
                       rng.uniform(-1.0, 1.0, (8, 3)), [[np.nan, 0.0, 0.0]]])
    shifts, by_yaw, yaws = cell_shifts(offsets, res)
    a_p, a_s = np.empty_like(poses), np.empty(len(poses))
    b_p, b_s = np.empty_like(poses), np.empty(len(poses))
    tiled_grid_search(pool, table, np.int8(0), ox, oy, 1.0 / res, poses, pts, offsets, a_p, a_s)
    tiled_grid_search_shifts(pool, table, np.int8(0), ox, oy, 1.0 / res, poses, pts, offsets, shifts, by_yaw, yaws, b_p, b_s)
    np.testing.assert_array_equal(b_p, a_p)
    np.testing.assert_array_equal(b_s, a_s)
    assert a_s[-1] == 0.0
    assert len(np.unique(a_s)) > 3


def test_likelihood_matcher_gives_the_same_bytes_on_one_thread():
    """The dense likelihood-field search runs particles on all cores; one thread must give the
    same poses, scores and evaluation counts."""
    import numba

    g, scan = _box_map()
    rng = np.random.default_rng(2)
    poses = rng.normal(0.0, [0.08, 0.08, 0.04], (9, 3))
    m = LikelihoodFieldMatcher(xy_half_width_m=0.1, xy_step_m=0.05, yaw_half_width_rad=0.1, yaw_step_rad=0.025)
    a_p, a_s = m.match(g, poses, scan)
    reads = m.map_reads
    before = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        b_p, b_s = m.match(g, poses, scan)
    finally:
        numba.set_num_threads(before)
    assert np.array_equal(a_p, b_p) and np.array_equal(a_s, b_s) and m.map_reads == 2 * reads
    assert not np.allclose(a_p, poses)


def test_voxel_filter_keeps_one_point_per_square_in_scan_order():
    from slamlab.slam.matcher import voxel_filter

    # a person 0.5 m away covers many beams; a wall 5 m away is sampled sparsely
    a = np.radians(np.arange(-20.0, 20.0, 0.25))
    blob = np.stack([0.5 * np.cos(a), 0.5 * np.sin(a)], axis=1)  # 160 points, 0.35 m of surface
    wall = np.stack([np.full(40, 5.0), np.linspace(-2.0, 2.0, 40)], axis=1)  # 10 cm apart
    xy = np.vstack([blob, wall])
    kept = voxel_filter(xy, 0.1)
    assert len(voxel_filter(blob, 0.1)) <= 10  # the blob weighs by its size now
    assert len(voxel_filter(wall, 0.1)) >= 38  # the sparse wall keeps (nearly) every point
    # the first point of each square, in scan order, and nothing invented
    keys = np.floor(kept / 0.1).astype(int)
    assert len({tuple(k) for k in keys}) == len(kept)
    idx = [int(np.flatnonzero((xy == p).all(axis=1))[0]) for p in kept]
    assert idx == sorted(idx)
    assert voxel_filter(xy, 0.0) is xy


def test_isolated_filter_keeps_points_with_a_close_scan_neighbour_in_order():
    from slamlab.slam.matcher import isolated_filter

    near = np.stack([np.full(20, 1.0), np.linspace(0.0, 0.95, 20)], axis=1)  # 5 cm apart
    far = np.array([[10.0, 1.4], [14.0, 1.4], [20.0, 1.4]])  # metres apart: each one alone
    pair = np.array([[25.0, -3.0], [25.0, -2.6]])  # 0.4 m apart: each has a neighbour
    xy = np.vstack([near, far, pair])
    kept = isolated_filter(xy, 0.6)
    assert np.array_equal(kept, np.vstack([near, pair]))
    assert isolated_filter(xy, 0.0) is xy  # off: every point
    assert isolated_filter(far, 0.6) is far  # no point has a neighbour: matched as it is, never empty
    assert len(isolated_filter(far[:1], 0.6)) == 1


def _corridor_scan() -> np.ndarray:
    """A 180-beam, 1-degree scan (-90..+89 deg, 30 m range) from the centre line of a bare
    corridor 2.8 m wide, facing along it (body frame, m): far along each wall the hits lie
    metres apart."""
    a = np.radians(np.arange(180) - 90.0)
    s = np.sin(a)
    hit = np.abs(s) > 1e-9
    t = np.where(hit, 1.4 / np.where(hit, np.abs(s), 1.0), np.inf)
    keep = t <= 30.0
    return np.stack([t[keep] * np.cos(a[keep]), t[keep] * np.sin(a[keep])], axis=1)


def test_isolated_far_hits_no_longer_hold_the_match_where_the_robot_was():
    """Down a bare corridor the only along-track 'evidence' is the comb of isolated far hits
    mapped from the last pose; matched against it the next scan is pulled back to where the
    robot was. Without them the match keeps the odometry's 0.2 m."""
    g = OccupancyGrid(MapSettings(resolution_m=0.05, initial_size_m=8.0), field_sigma_m=0.1, field_radius_m=0.3)
    g.insert(np.zeros(2), _corridor_scan())  # seen from x = 0
    scan = ScanPoints(xy=_corridor_scan(), origin=np.zeros(2))  # seen from x = 0.2 (the prediction)
    pred = np.array([[0.2, 0.0, 0.0]])
    held, _ = LikelihoodFieldMatcher(max_gap_m=0.0).match(g, pred, scan)
    free, _ = LikelihoodFieldMatcher(max_gap_m=0.6).match(g, pred, scan)
    assert held[0, 0] < 0.1  # the comb pulls the match back towards x = 0
    assert abs(free[0, 0] - 0.2) < 0.05
    # the RBPF's per-particle path (tiled maps) filters the same points
    from slamlab.slam.tiles import TiledMaps

    maps = TiledMaps(MapSettings(resolution_m=0.05), 1, (0.0, 0.0), field_sigma_m=0.1, field_radius_m=0.3)
    maps.insert_scan(np.zeros((1, 3)), _corridor_scan(), np.zeros(2))
    held_t, _ = LikelihoodFieldMatcher(max_gap_m=0.0).match_each(maps, pred, scan)
    free_t, _ = LikelihoodFieldMatcher(max_gap_m=0.6).match_each(maps, pred, scan)
    assert held_t[0, 0] < 0.1 and abs(free_t[0, 0] - 0.2) < 0.05


def test_surface_stretches_cover_the_gaps_around_lone_hits_on_a_line():
    from slamlab.slam.matcher import STRETCH_MAX_SAMPLES, surface_stretches

    dense = np.stack([np.linspace(0.0, 0.95, 20), np.full(20, 1.4)], axis=1)  # 5 cm apart
    sparse = np.stack([np.array([2.0, 3.0, 4.0, 5.0, 9.0, 10.0]), np.full(6, 1.4)], axis=1)  # 1 m apart, then 4 m
    off = np.array([[10.0, -3.0]])  # the line ends: the scan turns away
    xy = np.vstack([dense, sparse, off])
    ext = surface_stretches(xy, 0.6, 0.1)
    assert ext.shape == (len(xy), 6)
    assert not ext[:20].any()  # points with a close neighbour are points
    # 2 m (after the dense run, 1.05 m away), 3 m and 4 m: lone hits on the line, halfway to each neighbour
    for k, (before, after) in zip(range(20, 23), [(1.05, 1.0), (1.0, 1.0), (1.0, 1.0)]):
        assert abs(ext[k, 0] - 1.0) < 1e-9 and abs(ext[k, 1]) < 1e-9  # along the wall, towards the next point (+x)
        n_b, n_a = np.ceil(before / 2 / 0.1), np.ceil(after / 2 / 0.1)
        np.testing.assert_allclose(ext[k, 2:], [n_b, n_a, before / 2 / n_b, after / 2 / n_a])
        assert ext[k, 4] <= 0.1 and ext[k, 5] <= 0.1
    # 5 m -> 9 m: 4 m to cover in at most STRETCH_MAX_SAMPLES samples, so wider steps
    assert ext[23, 3] == STRETCH_MAX_SAMPLES and abs(ext[23, 5] - 2.0 / STRETCH_MAX_SAMPLES) < 1e-12
    assert not ext[25].any() and not ext[26].any()  # 10 m turns a corner; the last point has one neighbour
    assert not surface_stretches(xy, 0.0, 0.1).any()  # max_gap 0: no lone points
    bent = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [2.0 + np.cos(0.2), np.sin(0.2)], [4.0, 1.0]])
    assert surface_stretches(bent, 0.6, 0.1)[1, 2] > 0 and surface_stretches(bent, 0.6, 0.1)[2, 2] == 0  # 11 deg off: no line


def test_a_stretch_scores_its_wall_across_but_not_along():
    """A lone hit between blobs of a sparse wall: as a point it scores the comb (high on a blob,
    nothing between), as a stretch the same wherever along the wall it lands, and less when
    it moves off the wall."""
    from slamlab.slam.matcher import score_field, score_stretches, surface_stretches

    g = OccupancyGrid(MapSettings(resolution_m=0.05, initial_size_m=20.0), field_sigma_m=0.1, field_radius_m=0.3)
    g.insert(np.zeros(2), np.array([[2.0, 1.4], [4.0, 1.4], [6.0, 1.4], [8.0, 1.4]]))  # blobs 2 m apart
    scan = np.array([[1.0, 1.4], [3.0, 1.4], [5.0, 1.4], [7.0, 1.4], [9.0, 1.4]])  # lone hits, 2 m apart
    ext = surface_stretches(scan, 0.6, 0.1)
    assert (ext[1:4, 2:4] > 0).all()
    pts, e = np.ascontiguousarray(scan[2:3]), np.ascontiguousarray(ext[2:3])  # the hit at x = 5
    args = (g.field_cells, g.origin[0], g.origin[1], 1.0 / g.res)
    point = [score_field(*args, dx, 0.0, 0.0, pts) for dx in (0.0, 1.0)]
    along = [score_stretches(*args, dx, 0.0, 0.0, pts, e) for dx in (0.0, 0.3, 0.6, 1.0)]
    assert point[0] < 0.05 < 0.8 < point[1]  # as a point: the comb
    assert min(along) > 0.8 and max(along) - min(along) < 0.1  # as a stretch: flat along the wall
    assert score_stretches(*args, 0.0, 0.2, 0.0, pts, e) < 0.5 * min(along)  # and peaked across it
    assert score_stretches(*args, 0.0, 0.0, 0.0, pts, np.zeros((1, 6))) == point[0]  # no stretch: a point
    # between samples (0.05 m off them) the largest sample is a little lower: a 12 % ripple, not a comb
    assert score_stretches(*args, 0.05, 0.0, 0.0, pts, e) > 0.85 * min(along)
    # the same scan seen from a body turned by 0.5 rad: points and stretches turn with it
    c, s_ = np.cos(-0.5), np.sin(-0.5)
    turn = np.array([[c, -s_], [s_, c]])
    e_turned = e.copy()
    e_turned[:, :2] = e[:, :2] @ turn.T
    for dx in (0.0, 0.3):
        x, y = dx * np.cos(0.0), 0.0
        np.testing.assert_allclose(score_stretches(*args, x, y, 0.5, pts @ turn.T, e_turned),
                                   score_stretches(*args, x, y, 0.0, pts, e), rtol=1e-9)


def test_a_stretch_reaches_each_neighbour_on_its_own_side():
    """Uneven gaps: the hit at x = 4 has neighbours at 2 (2 m before) and 8 (4 m after); a
    blob at x = 5.5 is within the half-gap after it, not before it."""
    from slamlab.slam.matcher import score_stretches, surface_stretches

    g = OccupancyGrid(MapSettings(resolution_m=0.05, initial_size_m=20.0), field_sigma_m=0.1, field_radius_m=0.3)
    g.insert(np.zeros(2), np.array([[5.5, 1.4]]))
    scan = np.array([[2.0, 1.4], [4.0, 1.4], [8.0, 1.4]])
    ext = surface_stretches(scan, 0.6, 0.1)
    args = (g.field_cells, g.origin[0], g.origin[1], 1.0 / g.res)
    pts, e = np.ascontiguousarray(scan[1:2]), np.ascontiguousarray(ext[1:2])
    assert score_stretches(*args, 0.0, 0.0, 0.0, pts, e) > 0.5  # 1.5 m after: inside the 2 m half-gap (0.2 m samples)
    flipped = e.copy()
    flipped[:, [2, 3, 4, 5]] = e[:, [3, 2, 5, 4]]  # the two sides swapped: 1 m after, 2 m before
    assert score_stretches(*args, 0.0, 0.0, 0.0, pts, flipped) < 0.05


def test_lone_hits_matched_as_stretches_no_longer_hold_the_match_either():
    from slamlab.slam.matcher import surface_stretches

    g = OccupancyGrid(MapSettings(resolution_m=0.05, initial_size_m=8.0), field_sigma_m=0.1, field_radius_m=0.3)
    g.insert(np.zeros(2), _corridor_scan())
    scan = ScanPoints(xy=_corridor_scan(), origin=np.zeros(2))
    pred = np.array([[0.2, 0.0, 0.0]])
    m = LikelihoodFieldMatcher(max_gap_m=0.6, isolated="stretch")
    coarse, fine, ext = m._points(scan)
    # the climb's points: `drop`'s, and the lone hits on a line, in scan order
    _, dropped, none = LikelihoodFieldMatcher(max_gap_m=0.6)._points(scan)
    lone = scan.xy[surface_stretches(scan.xy, 0.6, 0.1)[:, 2] > 0]
    assert len(none) == 0 and len(lone) > 10 and len(ext) == len(fine) == len(dropped) + len(lone)
    order = np.argsort([int(np.flatnonzero((scan.xy == p).all(axis=1))[0]) for p in fine])
    assert np.array_equal(order, np.arange(len(fine)))
    assert {tuple(p) for p in fine} == {tuple(p) for p in np.vstack([dropped, lone])}
    assert (ext[:, 2] > 0).sum() == len(lone)
    # one score, no coarse grid: a stretch reads the field at each of its samples
    one = LikelihoodFieldMatcher(max_gap_m=0.6, isolated="stretch", xy_half_width_m=0.0, yaw_half_width_rad=0.0, refine_levels=0)
    one.match(g, pred, scan)
    assert one.map_reads == 4 * (len(fine) + int(ext[:, 2:4].sum()))
    dense, _ = m.match(g, pred, scan)
    from slamlab.slam.tiles import TiledMaps

    maps = TiledMaps(MapSettings(resolution_m=0.05), 1, (0.0, 0.0), field_sigma_m=0.1, field_radius_m=0.3)
    maps.insert_scan(np.zeros((1, 3)), _corridor_scan(), np.zeros(2))
    tiled, _ = m.match_each(maps, pred, scan)
    assert abs(dense[0, 0] - 0.2) < 0.05 and abs(tiled[0, 0] - 0.2) < 0.05
    np.testing.assert_allclose(dense, tiled, atol=1e-9)  # the two kernels score stretches alike


def test_the_grid_matcher_matches_only_the_points_with_a_close_neighbour():
    from slamlab.slam.matcher import isolated_filter

    g = OccupancyGrid(MapSettings(resolution_m=0.05, initial_size_m=8.0))
    for _ in range(3):
        g.insert(np.zeros(2), _corridor_scan())
    xy = _corridor_scan()
    pose = np.zeros((1, 3))
    m = GridMatcher(xy_half_width_m=0.0, beam_step=1, max_gap_m=0.6)
    _, with_gap = m.match(g, pose, ScanPoints(xy=xy, origin=np.zeros(2)))
    _, kept_only = GridMatcher(xy_half_width_m=0.0, beam_step=1).match(g, pose, ScanPoints(xy=isolated_filter(xy, 0.6), origin=np.zeros(2)))
    _, every = GridMatcher(xy_half_width_m=0.0, beam_step=1).match(g, pose, ScanPoints(xy=xy, origin=np.zeros(2)))
    assert with_gap[0] == kept_only[0] < every[0]  # the lone far hits no longer count


def test_the_prior_weighs_per_beam_spacing_so_a_denser_lidar_lands_where_a_sparser_one_does():
    """matcher.prior_beam_deg: a lidar with beams 4x closer scores 4x more points off the same
    walls. With the prior as given it outweighs the prior 4x and lands nearer the map's optimum;
    with the prior weighed for its beam spacing it lands where the sparse lidar does."""
    def room_scan(n: int) -> ScanPoints:  # the 4 x 4 m room seen from its centre by n beams
        a = np.linspace(-np.pi, np.pi, n, endpoint=False)
        d = 2.0 / np.maximum(np.abs(np.cos(a)), np.abs(np.sin(a))) * 0.999
        return ScanPoints(xy=np.stack([d * np.cos(a), d * np.sin(a)], 1), origin=np.zeros(2))

    g = OccupancyGrid(MapSettings(resolution_m=0.05, initial_size_m=6.0), field_sigma_m=0.1, field_radius_m=0.3)
    for _ in range(3):
        g.insert(np.zeros(2), room_scan(360).xy)
    kw = dict(sigma_m=0.1, radius_m=0.3, xy_half_width_m=0.1, xy_step_m=0.05, yaw_half_width_rad=0.1, yaw_step_rad=0.025,
              refine_levels=5, prior_sigma_xy_m=0.01, prior_sigma_yaw_rad=0.05)
    sparse, dense = room_scan(90), room_scan(360)  # 4 and 1 degree(s) apart
    start = np.array([[0.08, 0.0, 0.0]])  # the prediction 8 cm off the room's centre, where the map puts the scans
    plain = LikelihoodFieldMatcher(**kw)
    weighed = LikelihoodFieldMatcher(**kw, prior_beam_deg=4.0)
    assert plain.for_beam_spacing(np.radians(1.0)) is plain  # prior_beam_deg 0: any lidar, the prior as given
    assert weighed.for_beam_spacing(np.radians(4.0)) is weighed  # the lidar the prior is for: itself
    x_sparse = weighed.match(g, start, sparse)[0][0, 0]
    x_dense_plain = plain.match(g, start, dense)[0][0, 0]
    dense_matcher = weighed.for_beam_spacing(np.radians(1.0))
    x_dense = dense_matcher.match(g, start, dense)[0][0, 0]
    assert 0.04 < x_sparse < 0.075  # the prior holds the match off the map's optimum (x = 0) ...
    assert x_dense_plain < x_sparse - 0.02  # ... 4x the points pull it much nearer
    assert abs(x_dense - x_sparse) < 0.005  # weighed 4x: where the sparse lidar lands
    assert (dense_matcher.kxy, dense_matcher.kyaw) == (4 * weighed.kxy, 4 * weighed.kyaw)
    assert weighed.kxy == 0.5 / 0.01**2  # the original is untouched


def test_a_sequence_beam_spacing_is_its_first_scan_angle_step():
    from slamlab.frames import Sequence
    from slamlab.slam.scan import beam_spacing_rad

    frame = _frame(np.ones(667), np.radians(-120.0 + 0.36 * np.arange(667)))  # a URG-04LX's 240 degrees
    assert np.isclose(np.degrees(beam_spacing_rad(Sequence(name="urg", scans=[frame], body_height_m=None, sources=[]))), 0.36, atol=1e-4)
    assert beam_spacing_rad(Sequence(name="empty", scans=[], body_height_m=None, sources=[])) == 0.0
