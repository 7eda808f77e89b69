"""PNG row filtering as Pillow's encoder does it (libImaging/ZipEncode.c without `optimize`),
compiled: a building's map.png is ~50 million pixels, and NumPy's whole-band passes (every
filter in full, then the costs) took twice as long as the deflate after them."""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, inline="always")
def _signed_abs(v: np.uint8) -> int:
    return v if v < 128 else 256 - v


@numba.njit(cache=True, nogil=True)  # nogil: write_map writes the npz and PGM in another thread meanwhile
def filter_rows(raw: np.ndarray, previous: np.ndarray, out: np.ndarray) -> None:
    """Scanlines of pixel rows `raw` (n, m) uint8, RGBA, below the row `previous` (m,) into
    `out` (n, m + 1): each row's filter byte then its filtered bytes. Per row the filter is
    the first of none (0), up (2), sub (1) and Paeth (4) whose cost (the sum of |byte| with
    each byte read as signed) is strictly lower than the best so far; once the best costs 0
    no further filter is tried. Bytes left of the first pixel count as 0."""
    n, m = raw.shape
    bpp = 4
    for r in range(n):
        row = raw[r]
        above = previous if r == 0 else raw[r - 1]
        best_kind = 0
        best = 0
        for i in range(m):
            best += _signed_abs(row[i])
        if best > 0:  # up
            s = 0
            for i in range(m):
                s += _signed_abs(np.uint8(row[i] - above[i]))
            if s < best:
                best_kind, best = 2, s
        if best > 0:  # sub
            s = 0
            for i in range(m):
                left = row[i - bpp] if i >= bpp else np.uint8(0)
                s += _signed_abs(np.uint8(row[i] - left))
            if s < best:
                best_kind, best = 1, s
        if best > 0:  # Paeth
            s = 0
            for i in range(m):
                s += _signed_abs(np.uint8(row[i] - _paeth(row, above, i, bpp)))
            if s < best:
                best_kind, best = 4, s
        o = out[r]
        o[0] = best_kind
        for i in range(m):
            if best_kind == 0:
                o[i + 1] = row[i]
            elif best_kind == 2:
                o[i + 1] = np.uint8(row[i] - above[i])
            elif best_kind == 1:
                o[i + 1] = np.uint8(row[i] - (row[i - bpp] if i >= bpp else np.uint8(0)))
            else:
                o[i + 1] = np.uint8(row[i] - _paeth(row, above, i, bpp))


@numba.njit(cache=True, inline="always")
def _paeth(row: np.ndarray, above: np.ndarray, i: int, bpp: int) -> np.uint8:
    """The Paeth predictor of byte i: of left a, above b and upper-left c, the one nearest
    a + b - c (ties to a, then b)."""
    a = np.int32(row[i - bpp]) if i >= bpp else np.int32(0)
    b = np.int32(above[i])
    c = np.int32(above[i - bpp]) if i >= bpp else np.int32(0)
    pa, pb, pc = abs(b - c), abs(a - c), abs(a + b - 2 * c)
    if pa <= pb and pa <= pc:
        return np.uint8(a)
    return np.uint8(b) if pb <= pc else np.uint8(c)
