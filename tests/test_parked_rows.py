"""A large map's far rows held compressed (`slam/parked_rows.py`): the grid reads and writes
the same cells to the bit whether its far rows are parked or not."""

from __future__ import annotations

import numpy as np
import pytest

from slamlab.slam.grid import MapSettings, OccupancyGrid
from slamlab.slam.parked_rows import BAND_ROWS, ParkedRows


def _room_scan(rng: np.random.Generator, pose: np.ndarray, n: int = 180, max_r: float = 12.0) -> np.ndarray:
    """World hit points of a scan from `pose` (x, y m) in a cluttered room: ranges 2-12 m."""
    a = np.linspace(-np.pi, np.pi, n, endpoint=False)
    r = rng.uniform(2.0, max_r, n)
    r[rng.random(n) < 0.3] = max_r  # a wall's stretch at the same range, so cells turn occupied
    return np.column_stack([pose[0] + r * np.cos(a), pose[1] + r * np.sin(a)])


def _wandering_path() -> np.ndarray:
    """Robot positions (m) that push each side of the grid out twice, far from where they pushed
    it the first time (the first time's rows then parked, with walls by the old edge)."""
    legs = [(0, 0), (-30, 20), (0, -20), (-45, -20), (0, 0), (30, 20), (0, -20), (45, -20), (0, 0),
            (-20, 30), (20, 0), (25, 45), (0, 0), (-20, -30), (20, 0), (25, -45), (0, 0)]
    pts = [np.linspace(legs[i], legs[i + 1], 12, endpoint=False) for i in range(len(legs) - 1)]
    return np.concatenate(pts + [np.array([legs[-1]], dtype=float)])


def _same(a: OccupancyGrid, b: OccupancyGrid) -> None:
    b.unpark_all()
    assert a.shape == b.shape and np.array_equal(a.origin, b.origin)
    assert a.log_odds.view(np.uint32).tobytes() == b.log_odds.view(np.uint32).tobytes()
    assert a.field.tobytes() == b.field.tobytes()


def test_a_grid_parked_behind_every_scan_holds_the_bits_of_one_never_parked():
    """Every scan inserted, then all rows but the robot's own band parked: the next scan puts back
    what it reaches, the grid grows on all four sides with walls parked near its edges, and at the
    end the log-odds and field are the unparked grid's, bit for bit."""
    rng = np.random.default_rng(3)
    # no growth margin: a scan's walls lie by the edge it pushed out, where the next growth's field reads them
    settings = MapSettings(resolution_m=0.05, initial_size_m=10.0, growth_margin_m=0.0)
    plain = OccupancyGrid(settings, (0.0, 0.0), 0.1, 0.3)
    parked = OccupancyGrid(settings, (0.0, 0.0), 0.1, 0.3)
    parked.start_parking()
    for pose in _wandering_path():
        pts = _room_scan(rng, pose)
        plain.insert(pose, pts)
        parked.insert(pose, pts)
        parked.park_beyond(pose[1] - 0.5, pose[1] + 0.5)
    assert parked.grow_count == plain.grow_count > 8
    assert parked.parked.parks > 20 and parked.parked.unparks > 10 and parked.parked.bands
    resident = parked.log_odds.view(np.uint32).any(axis=1).mean()
    assert resident < 0.5 * plain.log_odds.view(np.uint32).any(axis=1).mean()  # the parked rows read as zeros
    _same(plain, parked)


def test_a_map_drawn_a_group_of_rows_at_a_time_is_the_map_drawn_at_once():
    from slamlab.slam.graph.local import map_of_nodes
    from slamlab.slam.matcher import LikelihoodFieldMatcher
    from slamlab.slam.scan import ScanPoints

    rng = np.random.default_rng(5)
    path = _wandering_path()
    poses = np.column_stack([path, rng.uniform(-np.pi, np.pi, len(path))])
    scans = []
    for p in poses:  # the room's points seen from each pose, in its robot frame
        w = _room_scan(rng, p) - p[:2]
        c, s = np.cos(p[2]), np.sin(p[2])
        scans.append(ScanPoints(np.column_stack([c * w[:, 0] + s * w[:, 1], -s * w[:, 0] + c * w[:, 1]]), np.zeros(2)))
    matcher, ms = LikelihoodFieldMatcher(), MapSettings(resolution_m=0.05)
    at_once = map_of_nodes(scans, poses, matcher, ms)
    in_groups = map_of_nodes(scans, poses, matcher, ms, park=True)
    assert in_groups.shape[0] > 4 * BAND_ROWS * 3  # several groups of rows
    assert in_groups.parked.bands and in_groups.parked.parks >= len(in_groups.parked.bands)
    _same(at_once, in_groups)


def test_a_parked_band_comes_back_where_it_was_after_the_grid_grew_around_it():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(3 * BAND_ROWS, 700)).astype(np.float32)
    a[:, 100:200] = 0
    field = (rng.random((3 * BAND_ROWS, 700)) * 255).astype(np.uint8)
    keep = {"log_odds": a.copy(), "field": field.copy()}
    p = ParkedRows()
    p.park(1, {"log_odds": a, "field": field}, row_base=0, col_base=0)
    assert not a[BAND_ROWS:2 * BAND_ROWS].any() and not field[BAND_ROWS:2 * BAND_ROWS].any()
    assert a[:BAND_ROWS].tobytes() == keep["log_odds"][:BAND_ROWS].tobytes()
    assert p.nbytes < 2 * a[BAND_ROWS:2 * BAND_ROWS].nbytes
    # the grid grew 5 rows below and 7 columns left: the same global rows sit 5 rows, 7 columns further in
    grown = {k: np.zeros((v.shape[0] + 5, v.shape[1] + 7), dtype=v.dtype) for k, v in keep.items()}
    assert p.touching(BAND_ROWS + 3, BAND_ROWS + 4) == [1] and p.touching(0, BAND_ROWS) == []
    assert p.with_cells_in_columns("log_odds", 100, 200, np.dtype(np.float32)) == []
    assert p.with_cells_in_columns("log_odds", 99, 101, np.dtype(np.float32)) == [1]
    p.unpark(1, grown, row_base=-5, col_base=-7)
    for k, v in keep.items():
        assert grown[k][5 + BAND_ROWS:5 + 2 * BAND_ROWS, 7:].tobytes() == v[BAND_ROWS:2 * BAND_ROWS].tobytes()
    assert not p.bands and p.unparks == 1


@pytest.mark.parametrize("rows", [1, 3, 64])
def test_parking_gives_the_bands_pages_back_and_leaves_its_neighbours(rows):
    a = np.ones((4 * rows + 2, 1500), dtype=np.float32)  # rows of 6,000 bytes: bands end inside pages
    import slamlab.slam.parked_rows as pr

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(pr, "BAND_ROWS", rows)
        p = ParkedRows()
        p.park(2, {"log_odds": a}, row_base=0, col_base=0)
    assert not a[2 * rows:3 * rows].any()
    assert a[:2 * rows].all() and a[3 * rows:].all()


def test_the_rows_a_match_asks_for_grow_with_its_window_and_climb():
    """A match reads its scan's points moved by the coarse offsets and the hill climb: a matcher
    set to move farther asks for more rows than the 3 m the default needs."""
    from slamlab.slam.graph.local import REACH_MARGIN_M, match_margin_m
    from slamlab.slam.matcher import LikelihoodFieldMatcher

    assert match_margin_m(LikelihoodFieldMatcher()) == REACH_MARGIN_M
    wide = LikelihoodFieldMatcher(xy_half_width_m=1.0, xy_step_m=0.25)
    assert match_margin_m(LikelihoodFieldMatcher(), wide) >= 1.0 + 16 * 0.25
