"""The report's map view (`figures.prepare_map`) crops a log-odds grid to its observed cells and
reduces it by blocks. A building's map is 160 MB of float32, so the observed rows and columns are
found band by band: the crop must be the one a whole-grid mask gives, also when the observed
cells sit across band edges."""

from __future__ import annotations

import numpy as np
import pytest

from slamlab.report import figures
from slamlab.report.rundir import LogOddsMap


def _whole_grid_crop(data: np.ndarray) -> tuple[int, int, int, int]:
    known = np.abs(data) > 1e-6
    rows, cols = np.flatnonzero(known.any(axis=1)), np.flatnonzero(known.any(axis=0))
    return int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1


def test_the_observed_rows_and_columns_found_band_by_band_are_the_whole_masks():
    rng = np.random.default_rng(2)
    band = figures.KNOWN_BAND_ROWS
    data = np.zeros((3 * band + 17, 300), dtype=np.float32)
    data[band - 3:2 * band + 5, 40:260] = rng.normal(0.0, 2.0, (band + 8, 220)).astype(np.float32)
    data[band - 3, 40] = np.float32(1e-6)  # not observed: |v| must exceed 1e-6
    data[3 * band + 10, 290] = -0.4  # one lone observed cell in the last, partial band
    rows, cols = figures._known_rows_cols(LogOddsMap(data=data, resolution_m=0.05, origin_xy=(-2.0, 3.0)))
    known = np.abs(data) > 1e-6
    assert np.array_equal(rows, np.flatnonzero(known.any(axis=1)))
    assert np.array_equal(cols, np.flatnonzero(known.any(axis=0)))
    # and the view: the crop (plus the 1 m margin) reduced by blocks, as from the whole mask
    view = figures.prepare_map(LogOddsMap(data=data, resolution_m=0.05, origin_xy=(-2.0, 3.0)), max_px=100)
    r0, r1, c0, c1 = _whole_grid_crop(data)
    pad = 20  # 1 m at 0.05 m
    r0, c0, r1, c1 = max(r0 - pad, 0), max(c0 - pad, 0), min(r1 + pad, data.shape[0]), min(c1 + pad, data.shape[1])
    assert view.extent[0] == -2.0 + c0 * 0.05 and view.extent[2] == 3.0 + r0 * 0.05
    k = int(np.ceil(max(r1 - r0, c1 - c0) / 100))
    assert view.image.shape == (-(-(r1 - r0) // k), -(-(c1 - c0) // k))


def test_the_view_computed_in_place_a_band_at_a_time_is_the_formula_on_the_whole_crop():
    """The grey levels are 1 - P(occupied) of each block's most occupied cell, computed in place a
    band at a time: bit for bit the formula's value on the whole reduced crop at once."""
    rng = np.random.default_rng(7)
    band = figures.KNOWN_BAND_ROWS
    data = rng.normal(0.0, 12.0, (3 * band + 29, 211)).astype(np.float32)  # beyond the +-30 clip too
    m = LogOddsMap(data=data, resolution_m=0.05, origin_xy=(0.0, 0.0))
    for max_px, k in ((5000, 1), (300, 3)):
        view = figures.prepare_map(m, max_px)
        crop = figures.block_max(data, k)
        expected = 1.0 - 1.0 / (1.0 + np.exp(-np.clip(crop.astype(np.float64), -30, 30)))
        assert view.image.dtype == np.float64 and np.array_equal(view.image, expected)


def _written_map(tmp_path, data: np.ndarray, **kw):
    from slamlab.io.atomic import write_npz_fast

    path = tmp_path / "map_logodds.npz"
    write_npz_fast(path, data=data, resolution_m=np.float64(0.05), origin_xy=np.array([-2.0, 3.0]), **kw)
    return path


def test_a_runs_map_read_band_by_band_gives_the_views_of_the_whole_array(tmp_path):
    """The report reads a run's map from its file a band of rows at a time (a building's map is
    ~200 MB whole): every view is the one the whole array gives, pixel for pixel."""
    from slamlab.io.rundir import LogOddsRows
    from slamlab.report.rundir import Trajectory, read_logodds

    rng = np.random.default_rng(4)
    band = figures.KNOWN_BAND_ROWS
    data = np.zeros((2 * band + 71, 530), dtype=np.float32)
    data[40:2 * band + 30, 25:500] = rng.normal(0.0, 3.0, (2 * band - 10, 475)).astype(np.float32)
    m = read_logodds(_written_map(tmp_path, data))
    assert isinstance(m.data, LogOddsRows) and m.shape == data.shape
    whole = LogOddsMap(data=data, resolution_m=0.05, origin_xy=(-2.0, 3.0))
    outside = Trajectory(t=np.arange(2.0), xy=np.array([[-2.0, 3.0], [30.0, 40.0]]), yaw=np.zeros(2))
    for max_px, trs in ((1000, []), (100, []), (37, [outside]), (7, [])):
        a, b = figures.prepare_map(whole, max_px, trs), figures.prepare_map(m, max_px, trs)
        assert a.extent == b.extent
        assert a.image.shape == b.image.shape and np.array_equal(a.image, b.image)


def test_a_map_file_the_band_reader_cannot_read_is_read_whole(tmp_path):
    from slamlab.report.rundir import read_logodds

    data = np.asfortranarray(np.random.default_rng(1).normal(0.0, 1.0, (30, 40)).astype(np.float32))
    m = read_logodds(_written_map(tmp_path, data))
    assert isinstance(m.data, np.ndarray) and np.array_equal(m.data, data)


def test_a_map_file_saved_by_numpy_as_float64_is_read_band_by_band_too(tmp_path):
    from slamlab.io.rundir import LogOddsRows
    from slamlab.report.rundir import read_logodds

    data = np.random.default_rng(3).normal(0.0, 2.0, (40, 33))
    path = tmp_path / "map_logodds.npz"
    np.savez(path, data=data, resolution_m=np.float64(0.05), origin_xy=np.array([-2.0, 3.0]))  # uncompressed, float64
    m = read_logodds(path)
    assert isinstance(m.data, LogOddsRows)
    whole = LogOddsMap(data=data.astype(np.float32), resolution_m=0.05, origin_xy=(-2.0, 3.0))
    a, b = figures.prepare_map(whole, 10), figures.prepare_map(m, 10)
    assert a.extent == b.extent and np.array_equal(a.image, b.image)


def test_a_damaged_truncated_or_replaced_map_file_is_a_data_error_naming_it(tmp_path):
    """A map_logodds.npz cut short or with a damaged byte: a DataError naming the file (the
    report says so, no stack trace), whether found when it is opened or when a figure reads
    its rows; also when a run replaced it after it was opened."""
    from slamlab.errors import DataError
    from slamlab.report.rundir import read_logodds

    data = np.random.default_rng(5).normal(0.0, 2.0, (300, 200)).astype(np.float32)
    path = _written_map(tmp_path, data)
    whole = path.read_bytes()
    path.write_bytes(whole[: len(whole) // 2])
    with pytest.raises(DataError, match="map_logodds.npz"):
        figures.prepare_map(read_logodds(path), 50)
    damaged = bytearray(whole)
    damaged[len(whole) // 3] ^= 0xFF  # inside data.npy's deflate stream
    path.write_bytes(bytes(damaged))
    with pytest.raises(DataError, match="map_logodds.npz"):
        figures.prepare_map(read_logodds(path), 50)
    path.write_bytes(whole)
    m = read_logodds(path)
    _written_map(tmp_path, data[:, :150])  # a run writes its map again
    with pytest.raises(DataError, match="changed while it was read"):
        figures.prepare_map(m, 50)


def test_an_empty_crop_is_an_empty_view():
    view = figures.prepare_map(LogOddsMap(data=np.zeros((0, 5), dtype=np.float32), resolution_m=0.05, origin_xy=(0.0, 0.0)), 10)
    assert view.image.shape[0] == 0
