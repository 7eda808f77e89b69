"""The occupancy map: a log-odds grid (float32) that grows as the robot explores.

Cell (row r, col c) covers x in [origin_x + c*res, +res), y in [origin_y + r*res, +res),
as `frames.GridImage`. When a scan would fall off the grid, the grid is enlarged on that
side by the scan's overshoot plus `growth_margin_m`, so no part of a long log is lost and
growth (a copy) happens rarely. Optionally the grid also keeps a likelihood field (a
Gaussian of the distance to the nearest occupied cell) for scan matching, recomputed only
where a scan changed which cells are occupied (or, with `walls_at_hits`, where a wall moved
within its cell: each wall's Gaussian is then centred where the scan hits in its cell fell on
average, not at the cell's centre; `raycast.note_hits`). The field is kept as codes of its
kernels' values (`field_cells.value_codes`: one byte a cell, two with walls at their hits),
which the field kernels raise and lower as they would the values (codes keep the values'
order) and the matchers read through the table (`field_cells.cell`).
"""

from __future__ import annotations

import sys

import numba
import numpy as np

from slamlab.frames import GridImage
from slamlab.geometry import FloatArray
from slamlab.config.slam import MapConfig
from slamlab.heap import release_pages
from slamlab.slam.field_cells import FieldCells, value_codes
from slamlab.slam.parked_rows import BAND_ROWS, ParkedRows
from slamlab.slam.raycast import (
    WALL_STEPS, copy_nonzero, field_radius_cells, kernel_bank, note_hits, raise_field, raycast_many_bands, raycast_update, raycast_update_noting,
    refresh_cells, update_field, update_field_bands,
)

# The `map/` config group's schema is the settings object the grid reads: resolution_m,
# log-odds (occupied > 0, free < 0, clamp bounds), occupied_threshold, ground_threshold_m,
# min/max_range_m, initial_size_m, growth_margin_m (see `slamlab.config.slam.MapConfig`,
# which also checks them).
MapSettings = MapConfig


NO_CELLS = np.empty((0, 2), dtype=np.int64)  # `note_hits` with nowhere to list moved walls (no field to keep)
NO_FLIP = (np.iinfo(np.int64).max, -1, np.iinfo(np.int64).max, -1)  # an empty box of changed cells (`raycast_update`)
RAY_BAND_ROWS_MIN = 64  # `insert_many` ray-casts in row bands of at least this many rows on all cores
PARALLEL_FIELD_CELLS = 1 << 20  # a field box of this many cells or more is recomputed in row bands on all cores
FIELD_BAND_ROWS = 64  # rows a band (each band also reads the R rows of walls either side of it)
DRAW_GROUP_BANDS = 4  # parked bands' worth of rows drawn at a time by `insert_joined` with parking (~2 M cells on the hospital's map)
RELEASE_BAND_BYTES = 4 << 20  # `_copy_into` gives an old array over twice this size back in bands of about this size


def _copy_into(a: np.ndarray, out: np.ndarray, r0: int, c0: int, release_old: bool = False) -> None:
    """`a` copied into the zeroed, larger `out` at rows r0.., cols c0..: np.pad's result when
    `out` comes zeroed from the allocator (fresh pages of a large array are mapped zero pages,
    resident only once written). Only `a`'s non-zero cells are written (`copy_nonzero`, on
    the bits: -0.0 too), where np.pad writes every cell: a building's map grows hundreds of
    times (on the Freiburg hospital log the writes took ~0.9 s), and the unmapped space around
    the building then never becomes resident.

    `release_old`: `a` owns its memory and nobody reads it again, so a large one is copied
    band by band and each band's pages go back to the system once copied
    (`heap.release_pages`): the old and the new array are not both resident at once. A grid
    grows its log-odds and then its field, so otherwise three full arrays were resident at its
    largest growth (hospital log: 485 MB)."""
    bits = f"u{a.dtype.itemsize}"  # the grid's cells (float32 log-odds, field codes), copied as their bits
    dst = out.view(bits)
    release = release_old and a.flags.c_contiguous and a.flags.owndata and a.base is None and a.nbytes > 2 * RELEASE_BAND_BYTES
    H = a.shape[0]
    rows = max(RELEASE_BAND_BYTES // a.strides[0], 1) if release else max(H, 1)
    released = 0
    for r in range(0, H, rows):
        copy_nonzero(a[r:r + rows].view(bits), dst, r0 + r, c0)
        if release:
            released = release_pages(a, released, min(r + rows, H) * a.strides[0])


def _sole_reference_count() -> int:
    """What `sys.getrefcount` says of an object only one local variable holds, on this Python
    (2 up to 3.13; 3.14 reads locals without a new reference, and says 1)."""
    only_here = object()
    return sys.getrefcount(only_here)


SOLE_REFERENCE = _sole_reference_count()


def growth_pads(origin: FloatArray, shape: tuple[int, int], res: float, margin_m: float,
                box: tuple[float, float, float, float]) -> tuple[int, int, int, int]:
    """(bottom, top, left, right) cells a grid of `shape` at `origin` (m) grows by so the box
    (xmin, ymin, xmax, ymax) m fits inside, with `margin_m` of room past it (0s: it fits)."""
    xmin, ymin, xmax, ymax = box
    H, W = shape
    m = int(np.ceil(margin_m / res)) + 1
    lo_c = int(np.floor((xmin - origin[0]) / res))
    lo_r = int(np.floor((ymin - origin[1]) / res))
    hi_c = int(np.floor((xmax - origin[0]) / res))
    hi_r = int(np.floor((ymax - origin[1]) / res))
    pad_l = m - lo_c if lo_c < 1 else 0
    pad_b = m - lo_r if lo_r < 1 else 0
    pad_r = hi_c - (W - 2) + m if hi_c > W - 2 else 0
    pad_t = hi_r - (H - 2) + m if hi_r > H - 2 else 0
    return pad_b, pad_t, pad_l, pad_r


def cells_at(xy: FloatArray, origin: FloatArray, res: float) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols) int64 of world points (M, 2) m on a grid of origin `origin` (m) and `res` m cells."""
    c = np.floor((xy[:, 0] - origin[0]) / res).astype(np.int64)
    r = np.floor((xy[:, 1] - origin[1]) / res).astype(np.int64)
    return r, c


def grown_origin(origin: FloatArray, pad_l: int, pad_b: int, res: float) -> FloatArray:
    """A grid's origin (m) after it grew by `pad_l` cells on the left and `pad_b` below."""
    return origin - np.array([pad_l, pad_b]) * res


class OccupancyGrid:
    """Log-odds grid centred at `center_xy` (m) at start, growing on demand.

    `field_sigma_m` > 0 also maintains the likelihood field, values in [0, 1] =
    exp(-d^2 / (2 sigma^2)) with d the distance (m) to the nearest occupied cell, cut off at
    `field_radius_m`: kept as `field` (codes, uint8 or uint16) and `field_lut` (float32, the
    value of each code); readers take `field_cells`. `walls_at_hits`: d is measured from the
    mean of the hits in that cell (to 1/9 of a cell), kept in three bytes a cell (`hit_dx`,
    `hit_dy`, `hit_n`), for a field started now or later (`start_field`).
    """

    def __init__(
        self,
        settings: MapSettings,
        center_xy: tuple[float, float] = (0.0, 0.0),
        field_sigma_m: float = 0.0,
        field_radius_m: float = 0.0,
        walls_at_hits: bool = False,
    ) -> None:
        self.s = settings
        self.res = settings.resolution_m
        n = max(int(np.ceil(settings.initial_size_m / self.res)), 8)
        self.origin = np.array([center_xy[0] - n * self.res / 2.0, center_xy[1] - n * self.res / 2.0])
        self.log_odds = np.zeros((n, n), dtype=np.float32)
        self.bank: np.ndarray | None = None  # the field's kernels as codes [S, S, 2R+1, 2R+1]: one, or one per place in a cell
        self.field_lut = np.zeros(1, dtype=np.float32)  # the value of each field code (ascending, 0 first)
        self.field: np.ndarray | None = None  # the field's codes
        self.walls_at_hits = walls_at_hits
        # each cell's mean hit offset from its centre (int8, 1/256 cell) and hit count; empty: walls at cell centres
        shape = (n, n) if walls_at_hits else (0, 0)
        self.hit_dx = np.zeros(shape, dtype=np.int8)
        self.hit_dy = np.zeros(shape, dtype=np.int8)
        self.hit_n = np.zeros(shape, dtype=np.uint8)
        if field_sigma_m > 0:
            self._start_bank(field_sigma_m, field_radius_m)
            self.field = np.zeros((n, n), dtype=self.bank.dtype)
        self.grow_count = 0
        self._flips = np.empty((0, 2), dtype=np.int64)  # scratch for `insert`: the cells a scan changed
        # `park_beyond`: bands of rows far from the robot held compressed (`parked_rows`); None: every row resident.
        # row_base / col_base: the global index (row / column 0 of the grid as made) of the arrays' first row / column
        self.parked: ParkedRows | None = None
        self.row_base = 0
        self.col_base = 0

    @property
    def shape(self) -> tuple[int, int]:
        return self.log_odds.shape  # type: ignore[return-value]

    def _updates(self) -> tuple[np.float32, np.float32, np.float32, np.float32]:
        """The settings' (occupied, free, clamp min, clamp max) log-odds as the ray casts take them."""
        s = self.s
        return np.float32(s.log_odds_occupied), np.float32(s.log_odds_free), np.float32(s.clamp_min), np.float32(s.clamp_max)

    @property
    def nbytes(self) -> int:
        """Bytes the grid's arrays hold: log-odds, field codes, hit offsets."""
        arrays = (self.log_odds, self.field, self.hit_dx, self.hit_dy, self.hit_n)
        return sum(a.nbytes for a in arrays if a is not None)

    def start_parking(self) -> None:
        """From now on `park_beyond` may hold far rows compressed (`parked_rows`). Every reader of
        the arrays must then ask for its rows first (`need_rows`); the grid's own methods do.
        Not for a grid that keeps hit offsets (`walls_at_hits`)."""
        assert not self.walls_at_hits, "parking keeps the log-odds and the field, not hit offsets"
        if self.parked is None:
            self.parked = ParkedRows()

    def _park_arrays(self) -> dict[str, np.ndarray]:
        return {"log_odds": self.log_odds} if self.field is None else {"log_odds": self.log_odds, "field": self.field}

    def need_rows(self, y_lo_m: float, y_hi_m: float) -> None:
        """Put back the parked rows (`park_beyond`) within the field's reach of y in [y_lo_m, y_hi_m] (m),
        before anything reads or writes cells there."""
        if self.parked is None or not self.parked.bands:
            return
        halo = 2 * (self.field_radius if self.bank is not None else 0) + 2  # a field update reads R beyond the R it writes
        lo = int(np.floor((y_lo_m - self.origin[1]) / self.res)) - halo
        hi = int(np.floor((y_hi_m - self.origin[1]) / self.res)) + halo + 1
        self._need_rows(lo, hi)

    def _need_rows(self, lo: int, hi: int) -> None:
        """The parked bands holding any of the grid's rows [lo, hi) (its own indices) put back."""
        if self.parked is not None:
            self._put_back(self.parked.touching(lo + self.row_base, hi + self.row_base))

    def unpark_all(self) -> None:
        """Every parked row back: for a reader of the whole grid."""
        if self.parked is not None:
            self._put_back(list(self.parked.bands))

    def _put_back(self, bands: list[int]) -> None:
        """These parked bands' rows back in the arrays."""
        assert self.parked is not None
        for i in bands:
            self.parked.unpark(i, self._park_arrays(), self.row_base, self.col_base)

    def park_beyond(self, y_lo_m: float, y_hi_m: float) -> None:
        """Hold compressed (`parked_rows`) every band of rows wholly outside y in [y_lo_m, y_hi_m] (m)."""
        if self.parked is None:
            return
        self._park_outside(int(np.floor((y_lo_m - self.origin[1]) / self.res)), int(np.floor((y_hi_m - self.origin[1]) / self.res)) + 1)

    def _park_outside(self, lo: int, hi: int) -> None:
        """Every band wholly outside the grid's rows [lo, hi) (its own indices) parked."""
        if self.parked is None:
            return
        B = BAND_ROWS
        keep_lo, keep_hi = lo + self.row_base, hi + self.row_base
        first, last = self.row_base // B, (self.row_base + self.shape[0] - 1) // B
        arrays = self._park_arrays()
        for i in range(first, last + 1):
            if ((i + 1) * B <= keep_lo or i * B >= keep_hi) and i not in self.parked.bands:
                self.parked.park(i, arrays, self.row_base, self.col_base)

    def _unpark_for_growth(self, pad_b: int, pad_t: int, pad_l: int, pad_r: int) -> None:
        """Before the grid grows: the parked bands whose cells the field of the new margins reads
        (`_refresh_field_margins`: R rows and columns in from the old edges) put back. A band with
        no wall near a growing side stays parked: the margin's field in its rows is then what the
        new empty cells give, whatever the band holds."""
        if self.parked is None or not self.parked.bands:
            return
        reach = (self.field_radius if self.bank is not None else 0) + 1
        H, W = self.shape
        wanted: set[int] = set()
        if pad_b:
            wanted.update(self.parked.touching(self.row_base, self.row_base + reach))
        if pad_t:
            wanted.update(self.parked.touching(self.row_base + H - reach, self.row_base + H))
        if pad_l:
            wanted.update(self.parked.with_cells_in_columns("log_odds", self.col_base, self.col_base + reach, self.log_odds.dtype))
        if pad_r:
            wanted.update(self.parked.with_cells_in_columns("log_odds", self.col_base + W - reach, self.col_base + W, self.log_odds.dtype))
        self._put_back(sorted(wanted))

    @property
    def field_radius(self) -> int:
        """The field kernel's radius R (cells): a wall reaches R cells."""
        assert self.bank is not None, "grid built without a likelihood field"
        return self.bank.shape[2] // 2

    @property
    def field_cells(self) -> FieldCells:
        """The field as its readers take it: (codes, lut), a cell's value lut[codes[r, c]]."""
        assert self.field is not None, "grid built without a likelihood field"
        return self.field, self.field_lut

    def field_values(self) -> np.ndarray:
        """The field's values, float32 [H, W] (a decoded copy)."""
        self.unpark_all()
        assert self.field is not None, "grid built without a likelihood field"
        return self.field_lut[self.field]

    def _start_bank(self, field_sigma_m: float, field_radius_m: float) -> None:
        steps = WALL_STEPS if self.walls_at_hits else 1
        values = kernel_bank(field_sigma_m / self.res, field_radius_cells(field_sigma_m, field_radius_m, self.res), steps)
        self.bank, self.field_lut = value_codes(values)

    def cells(self, xy: FloatArray) -> tuple[np.ndarray, np.ndarray]:
        """(rows, cols) int64 of world points (M, 2) m (may lie outside the grid)."""
        return cells_at(xy, self.origin, self.res)

    def ensure(self, xmin: float, ymin: float, xmax: float, ymax: float) -> None:
        """Grow the grid (by the overshoot + growth margin) so the box (m) fits inside."""
        pads = growth_pads(self.origin, self.shape, self.res, self.s.growth_margin_m, (xmin, ymin, xmax, ymax))
        if pads == (0, 0, 0, 0):
            return
        pad_b, pad_t, pad_l, pad_r = pads
        self._unpark_for_growth(pad_b, pad_t, pad_l, pad_r)
        H, W = self.shape
        self.log_odds = self._grown_array("log_odds", pad_b, pad_t, pad_l, pad_r)
        if self.walls_at_hits:
            for name in ("hit_dx", "hit_dy", "hit_n"):
                setattr(self, name, self._grown_array(name, pad_b, pad_t, pad_l, pad_r))
        if self.field is not None:
            self.field = self._grown_array("field", pad_b, pad_t, pad_l, pad_r)
            self._refresh_field_margins(pad_b, pad_l, H, W)
        self.origin = grown_origin(self.origin, pad_l, pad_b, self.res)
        self.row_base -= pad_b
        self.col_base -= pad_l
        self.grow_count += 1

    def insert_cells(self, sensor_rc: tuple[int, int], rows: np.ndarray, cols: np.ndarray) -> None:
        """Ray-cast one scan given in cells (sensor (row, col), hits' rows and cols, all inside
        the grid) into a grid without a field or hit offsets: what `insert` does after `cells`."""
        assert self.field is None and not self.walls_at_hits, "insert_cells keeps neither a field nor hit offsets"
        assert self.parked is None or not self.parked.bands, "insert_cells asks for no rows: not for a grid with parked rows"
        raycast_update(self.log_odds, int(sensor_rc[0]), int(sensor_rc[1]), rows, cols, *self._updates(),
                       np.float32(self.s.occupied_threshold), np.array(NO_FLIP, dtype=np.int64))

    def resize_empty(self, origin: FloatArray, shape: tuple[int, int]) -> None:
        """Make a grid that holds nothing yet (a fresh one, no field) `shape` cells at `origin` (m)."""
        assert self.field is None and not self.walls_at_hits and not self.log_odds.any(), "resize_empty is for an empty grid"
        assert self.parked is None or not self.parked.bands, "resize_empty is for an empty grid (its parked rows hold cells)"
        self.log_odds = np.zeros(shape, dtype=np.float32)
        self.origin = np.asarray(origin, dtype=np.float64).copy()

    def _grown_array(self, name: str, pad_b: int, pad_t: int, pad_l: int, pad_r: int) -> np.ndarray:
        """The grid's array `name` grown (copied into a larger zeroed one, `_copy_into`); its old
        memory given back as it is copied when the grid held the only reference (every reader
        takes the grid's arrays afresh at each call; one that kept an old array would keep it
        whole)."""
        old = getattr(self, name)
        # allocated first: if this fails (the run's largest allocation), the grid keeps its array
        out = np.zeros((old.shape[0] + pad_b + pad_t, old.shape[1] + pad_l + pad_r), dtype=old.dtype)
        setattr(self, name, None)
        # held by `old` alone? (asked on a line of its own: as an argument of the call below, the
        # call's own reference would be counted too)
        sole = sys.getrefcount(old) == SOLE_REFERENCE
        _copy_into(old, out, pad_b, pad_l, release_old=sole)
        return out

    def _refresh_field_margins(self, pad_b: int, pad_l: int, H: int, W: int) -> None:
        """After growing: walls near the old edge reach R cells into the new margin, which
        padding filled with zeros. Recompute the field in those bands (old grid: H x W,
        now at rows pad_b.., cols pad_l..)."""
        R = self.field_radius
        NH, NW = self.shape
        top, right = pad_b + H, pad_l + W
        for r0, r1, c0, c1 in (
            (0, NH, max(pad_l - R, 0), pad_l),  # left band
            (0, NH, right, min(right + R, NW)),  # right band
            (max(pad_b - R, 0), pad_b, 0, NW),  # bottom band
            (top, min(top + R, NH), 0, NW),  # top band
        ):
            if r1 > r0 and c1 > c0:
                self._refresh_field(self.field, r0, r1, c0, c1)

    def start_field(self, field_sigma_m: float, field_radius_m: float) -> None:
        """Compute the likelihood field of a grid built without one (the values `insert` would
        have kept up to date, scan by scan: tested) and keep it from now on."""
        assert self.field is None and field_sigma_m > 0, "the grid has a field already, or none is asked for"
        self.unpark_all()  # the field of every row, from its log-odds
        self._start_bank(field_sigma_m, field_radius_m)
        assert self.bank is not None
        self.field = np.zeros(self.shape, dtype=self.bank.dtype)
        self._refresh_field(self.field, 0, self.shape[0], 0, self.shape[1])

    def insert(self, sensor_xy: FloatArray, points_xy: FloatArray) -> None:
        """Ray-cast one scan: sensor position (2,) m, world hit points (M, 2) m."""
        if len(points_xy) == 0:
            return
        xs = np.append(points_xy[:, 0], sensor_xy[0])
        ys = np.append(points_xy[:, 1], sensor_xy[1])
        self.ensure(xs.min(), ys.min(), xs.max(), ys.max())
        self.need_rows(ys.min(), ys.max())
        rows, cols = self.cells(points_xy)
        sr, sc = self.cells(np.asarray(sensor_xy, dtype=np.float64).reshape(1, 2))
        args = (self.log_odds, int(sr[0]), int(sc[0]), rows, cols, *self._updates(), np.float32(self.s.occupied_threshold))
        if self.field is None:
            raycast_update(*args, np.array(NO_FLIP, dtype=np.int64))
            self._note_hits(points_xy, rows, cols, NO_CELLS)
            return
        moved_room = len(rows) if self.walls_at_hits else 0  # the last rows: the walls whose place in their cell moved
        need = 4 * len(rows) + 64 + moved_room
        flips = self._flips if len(self._flips) >= need else np.empty((need, 2), dtype=np.int64)
        self._flips = flips
        room = len(flips) - moved_room
        n_free, n_occ = raycast_update_noting(*args, flips[:room])
        n_moved = self._note_hits(points_xy, rows, cols, flips[room:])
        if n_free + n_occ > room:  # more changes than room: the field again over their box, as before
            self.unpark_all()
            self._refresh_field(self.field, 0, self.shape[0], 0, self.shape[1])
            return
        stale = flips[:n_free] if n_moved == 0 else np.concatenate([flips[:n_free], flips[room:room + n_moved]])
        self._update_field(stale, flips[n_free:n_free + n_occ])

    def insert_many(self, sensors_xy: FloatArray, points_xy: list[FloatArray]) -> None:
        """Ray-cast many scans (sensor positions (K, 2) m, world hit points, one (M, 2) array
        per scan) in order, as `insert` one by one would, but growing the grid once to fit them
        all and computing the field once at the end (where `insert` updates it scan by scan):
        the same log-odds and field (tested), for a map drawn again from scratch."""
        if not len(points_xy):
            return
        self.insert_joined(sensors_xy, np.concatenate(points_xy), np.concatenate([[0], np.cumsum([len(p) for p in points_xy])]).astype(np.int64))

    def insert_joined(self, sensors_xy: FloatArray, pts: FloatArray, starts: np.ndarray, park: bool = False) -> None:
        """`insert_many` of scans whose world hit points are joined in one array `pts` (N, 2) m,
        scan i's the rows starts[i]:starts[i + 1] ((K + 1,) int64, from 0): a caller that made
        them one scan at a time lets its list go before the ray-casting's own arrays are made.
        `park` with parking on (`start_parking`): drawn a group of rows at a time, and left with
        every row parked but the last (`_insert_joined_parked`)."""
        if len(starts) <= 1:
            return
        sensors_xy = np.asarray(sensors_xy, dtype=np.float64)
        lo, hi = sensors_xy.min(axis=0), sensors_xy.max(axis=0)
        if len(pts):
            lo, hi = np.minimum(lo, pts.min(axis=0)), np.maximum(hi, pts.max(axis=0))
        self.ensure(*lo, *hi)
        if park and self.parked is not None:
            self._insert_joined_parked(sensors_xy, pts, starts)
            return
        self.unpark_all()  # every row is cast and its field computed
        rows, cols = self.cells(pts)
        sensor_rows, sensor_cols = self.cells(sensors_xy)
        # the grid's rows in bands, a few for each core (the result does not depend on them)
        band_rows = max(RAY_BAND_ROWS_MIN, -(-self.shape[0] // (4 * numba.get_num_threads())))
        raycast_many_bands(self.log_odds, sensor_rows, sensor_cols, rows, cols, starts, *self._updates(), band_rows)
        # the hits' offsets read nothing of the log-odds (no moved walls to list): taken in the
        # scans' order after them, they are what scan-by-scan gave
        self._note_hits(pts, rows, cols, NO_CELLS)
        if self.field is not None:
            self._refresh_field(self.field, 0, self.shape[0], 0, self.shape[1])

    def _insert_joined_parked(self, sensors_xy: FloatArray, pts: FloatArray, starts: np.ndarray) -> None:
        """`insert_joined` for a large map that need not be resident all at once: drawn a group
        of rows at a time, top to bottom. Each group gets every beam that crosses it, in the
        scans' order (each cell the same additions in the same order as casting the whole grid:
        the same log-odds); the field of a group is computed once the next group is drawn (it
        reads R rows beyond its own: the whole field's values there), and the groups behind are
        then parked. Each band is compressed once. Drawing the Freiburg hospital's map again
        held all of it resident (~130 MB) at every loop closure late in the run."""
        assert not self.walls_at_hits, "parking keeps no hit offsets"
        self.unpark_all()  # a fresh grid holds nothing parked; a used one is drawn over as a whole
        rows, cols = self.cells(pts)
        sensor_rows, sensor_cols = self.cells(sensors_xy)
        H, W = self.shape
        G = DRAW_GROUP_BANDS * BAND_ROWS
        R = self.field_radius if self.field is not None else 0
        assert R <= G, "a group's field reads R rows of the next group only"
        updates = self._updates()
        # each beam's rows, from its scan's sensor to its end: a group casts only the beams that cross it
        beam_sensor = np.repeat(sensor_rows, np.diff(starts))
        beam_lo, beam_hi = np.minimum(beam_sensor, rows), np.maximum(beam_sensor, rows)
        del beam_sensor
        for top in range(0, H + G, G):
            if top < H:
                bottom = min(top + G, H)
                cross = (beam_hi >= top) & (beam_lo < bottom)
                group_starts = np.concatenate([[0], np.cumsum(cross)])[starts]  # each scan's beams that cross, in order
                # the group's rows as a grid of their own: the same lines, shifted by `top` rows
                raycast_many_bands(self.log_odds[top:bottom], sensor_rows - top, sensor_cols, rows[cross] - top, cols[cross], group_starts,
                                   *updates, max(RAY_BAND_ROWS_MIN, -(-(bottom - top) // (4 * numba.get_num_threads()))))
            if top >= G and self.field is not None:
                self._refresh_field(self.field, top - G, min(top, H), 0, W)
            self._park_outside(top - G - R, H)  # the groups behind, done; those ahead hold nothing yet

    def _note_hits(self, points_xy: FloatArray, rows: np.ndarray, cols: np.ndarray, moved: np.ndarray) -> int:
        """Take a scan's hits (world points (M, 2) m in cells rows, cols) into their cells' mean
        hit offsets (walls_at_hits; else nothing). Lists the walls whose place moved in `moved`
        (one row per hit: room for all; see `raycast.note_hits`) and returns how many."""
        if not self.walls_at_hits:
            return 0
        return int(note_hits(self.log_odds, np.float32(self.s.occupied_threshold), self.hit_dx, self.hit_dy, self.hit_n, points_xy,
                             float(self.origin[0]), float(self.origin[1]), 1.0 / self.res, rows, cols, WALL_STEPS, moved))

    def _update_field(self, stale: np.ndarray, occupied: np.ndarray) -> None:
        """The field after cells turned free or their wall moved within the cell (`stale`) and
        cells turned occupied (`occupied`), (K, 2) rows and cols: around stale cells it is
        recomputed (a wall value there may have gone), then it is raised around the new walls.
        The same values as recomputing the box of every changed cell, which is what this
        replaced (tested), in a fraction of the reads."""
        R = self.field_radius
        H, W = self.shape
        if len(stale):
            r0, c0 = stale.min(axis=0)
            r1, c1 = stale.max(axis=0)
            box = (r1 - r0 + 2 * R + 1) * (c1 - c0 + 2 * R + 1)
            if len(stale) * (2 * R + 1) ** 2 < box:  # a few cells far apart (long beams): each one's neighbourhood
                refresh_cells(self.log_odds, self.field, np.float32(self.s.occupied_threshold), self.bank, self.hit_dx, self.hit_dy, stale)
            else:
                self._refresh_field(self.field, max(r0 - R, 0), min(r1 + R + 1, H), max(c0 - R, 0), min(c1 + R + 1, W))
        if len(occupied):
            raise_field(self.field, self.bank, self.hit_dx, self.hit_dy, occupied)

    def _refresh_field(self, field: np.ndarray, r0: int, r1: int, c0: int, c1: int) -> None:
        args = (self.log_odds, field, np.float32(self.s.occupied_threshold), self.bank, self.hit_dx, self.hit_dy, r0, r1, c0, c1)
        if (r1 - r0) * (c1 - c0) >= PARALLEL_FIELD_CELLS:  # a whole map or a large part of it: row bands on all cores
            update_field_bands(*args, max(FIELD_BAND_ROWS, 4 * self.field_radius))
        else:
            update_field(*args)

    def occupied(self) -> np.ndarray:
        """bool [H, W]: cells whose log-odds exceed the occupied threshold."""
        self.unpark_all()
        return self.log_odds > self.s.occupied_threshold

    def to_image(self) -> GridImage:
        """The log-odds grid as a float32 GridImage (a copy)."""
        self.unpark_all()
        return GridImage(data=self.log_odds.copy(), resolution_m=self.res, origin_xy=(float(self.origin[0]), float(self.origin[1])))

    def take_image(self) -> GridImage:
        """The log-odds grid as a float32 GridImage without a copy, for a grid that is done:
        it gives its arrays away and cannot be used after (a building's map is ~160 MB, and
        the copy doubled it at the end of every pose-graph run)."""
        self.unpark_all()
        image = GridImage(data=self.log_odds, resolution_m=self.res, origin_xy=(float(self.origin[0]), float(self.origin[1])))
        self.log_odds = self.field = self.hit_dx = self.hit_dy = self.hit_n = None  # type: ignore[assignment]
        return image
