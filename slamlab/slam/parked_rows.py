"""Rows of a large map held compressed while the robot is far from them (issue 44).

A building's online map (`filter=graph`, `local_map=map`) is one dense grid of everything
mapped so far: on the Freiburg hospital log 5,233 x 9,280 cells, ~126 MB resident at its end
(float32 log-odds and one-byte field codes), while every scan reads and writes only the cells
within its lidar's range of the robot. `ParkedRows` keeps the grid's rows in bands of
`BAND_ROWS`; a band farther than a scan can reach is LZ4-compressed (~10 % of its bytes on
the hospital's map: most cells are unknown or clamped to the same few values; zlib's level 1
packs it to 6 % but took 7 ms a band against LZ4's ~1 ms, and a run parks thousands), its
pages given back (`heap.release_pages`); it is put back, the same bytes, before anything reads or writes
its cells (`OccupancyGrid.need_rows`). Bands are whole rows of the grid at a global row index
(row 0 of the grid when it was made), so they stay put when the grid grows; a parked band
remembers the column where its block starts.

Nothing reads a parked band: its cells are zeros, which is what the grid's growth copy
skips. Results cannot depend on it when every reader asks for its rows first (tested: the
same trajectories and maps to the bit with and without parking).
"""

from __future__ import annotations

import mmap
from dataclasses import dataclass

import lz4.block
import numpy as np

from slamlab.heap import release_pages

BAND_ROWS = 64  # rows a band (3.2 m at 5 cm cells: ~0.6 MB of log-odds and field on the hospital's widest map)


@dataclass(slots=True)
class ParkedBand:
    """A band's cells as they were when parked: rows [row_lo, row_hi) and columns from
    `col0` (global grid indices), `width` columns; each array's block LZ4-compressed
    (None: all zeros)."""

    row_lo: int
    row_hi: int
    col0: int
    width: int
    blocks: dict[str, bytes | None]


class ParkedRows:
    """The parked bands of one grid (see the module doc), by band index (global row // BAND_ROWS)."""

    def __init__(self) -> None:
        self.bands: dict[int, ParkedBand] = {}
        self.parks = 0  # bands parked and put back so far (counts the tests read)
        self.unparks = 0

    @property
    def nbytes(self) -> int:
        return sum(len(b) for band in self.bands.values() for b in band.blocks.values() if b is not None)

    def park(self, index: int, arrays: dict[str, np.ndarray], row_base: int, col_base: int) -> None:
        """Compress band `index` of the grid's `arrays` (row r of each is global row r + row_base,
        column c global column c + col_base), zero it and give its pages back."""
        H, W = next(iter(arrays.values())).shape
        lo = max(index * BAND_ROWS - row_base, 0)
        hi = min((index + 1) * BAND_ROWS - row_base, H)
        if hi <= lo or index in self.bands:
            return
        blocks: dict[str, bytes | None] = {}
        for name, a in arrays.items():
            rows = a[lo:hi]
            if not rows.view(f"u{a.dtype.itemsize}").any():
                blocks[name] = None  # nothing written there (or zeros): nothing to keep or give back
                continue
            blocks[name] = lz4.block.compress(memoryview(rows).cast("B"), store_size=True)
            _zero_rows(a, lo, hi)
        self.bands[index] = ParkedBand(lo + row_base, hi + row_base, col_base, W, blocks)
        self.parks += 1

    def unpark(self, index: int, arrays: dict[str, np.ndarray], row_base: int, col_base: int) -> None:
        """Put band `index` back into the grid's arrays (which may have grown since it was parked)."""
        band = self.bands[index]  # dropped once its rows are back (a failure leaves it parked, not lost)
        lo, hi = band.row_lo - row_base, band.row_hi - row_base
        c0 = band.col0 - col_base
        for name, a in arrays.items():
            block = band.blocks[name]
            if block is not None:
                a[lo:hi, c0:c0 + band.width] = np.frombuffer(lz4.block.decompress(block), dtype=a.dtype).reshape(hi - lo, band.width)
        del self.bands[index]
        self.unparks += 1

    def touching(self, row_lo: int, row_hi: int) -> list[int]:
        """The parked bands holding any of the global rows [row_lo, row_hi)."""
        return [i for i, b in self.bands.items() if b.row_lo < row_hi and row_lo < b.row_hi]

    def with_cells_in_columns(self, name: str, col_lo: int, col_hi: int, dtype: np.dtype) -> list[int]:
        """The parked bands whose array `name` holds a non-zero cell in the global columns [col_lo, col_hi)."""
        out = []
        for i, b in self.bands.items():
            block = b.blocks[name]
            lo, hi = max(col_lo - b.col0, 0), min(col_hi - b.col0, b.width)
            if block is None or hi <= lo:
                continue
            rows = np.frombuffer(lz4.block.decompress(block), dtype=dtype).reshape(b.row_hi - b.row_lo, b.width)
            if rows[:, lo:hi].view(f"u{rows.dtype.itemsize}").any():
                out.append(i)
        return out


def _zero_rows(a: np.ndarray, lo: int, hi: int) -> None:
    """Rows [lo, hi) of the C-contiguous `a` made zeros: their whole pages given back (they
    read as zeros after), the partial pages at either end written."""
    start, stop = lo * a.strides[0], hi * a.strides[0]
    done = release_pages(a, start, stop)
    flat = a.reshape(-1).view(np.uint8)
    if done == start:  # no whole page inside: write them all
        flat[start:stop] = 0
        return
    first = -(-(a.ctypes.data + start) // mmap.PAGESIZE) * mmap.PAGESIZE - a.ctypes.data  # where the first whole page begins
    flat[start:first] = 0
    flat[done:stop] = 0
