"""A dense likelihood field as the numba kernels read it, whichever way it is stored.

A grid's field (`grid.OccupancyGrid`) only ever holds values of its kernels: each cell is the
largest kernel value reaching it from a wall, or 0. So it is kept as codes, each value's rank
among the kernels' distinct values (`value_codes`: one byte a cell at the walls' centres, two
with walls at their hits), and read through the sorted table of those values: the same float32
values as the float32 field it replaced, in a quarter of the memory (the map of a building is
the run's largest array).

The readers take either form, and are compiled for each:
- a pair `(codes, lut)`: a cell's value is `lut[codes[r, c]]`. The grids' fields
  (`grid.field_cells`) and the finished submaps' one-byte fields (`submaps.FIELD_LUT`: code /
  255) are read this way, so a run compiles each reader once;
- a float32 array of values (tests, a caller with plain values): `field[r, c]`.
`cell` and `rows_cols` read both, so a reader is written once.
"""

from __future__ import annotations

import numpy as np
from numba.core import types
from numba.extending import overload

# A field as the kernels take it: (codes [H, W] uint8 or uint16, lut float32) or values [H, W] float32
FieldCells = tuple[np.ndarray, np.ndarray]


def value_codes(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Codes for an array of float32 field values: (codes like `values`, lut float32) with
    lut[codes] == values, lut sorted ascending (so codes compare as their values do) and
    lut[0] == 0 (a cell no wall reaches). One byte a code when at most 256 values are
    distinct, else two."""
    lut = np.unique(np.concatenate([np.zeros(1, np.float32), np.asarray(values, dtype=np.float32).ravel()]))
    if len(lut) > 1 << 16:
        raise ValueError(f"{len(lut)} distinct field values: more than two-byte codes hold")
    dtype = np.uint8 if len(lut) <= 256 else np.uint16
    return np.searchsorted(lut, values).astype(dtype), lut


def cell(field, r, c):  # type: ignore[no-untyped-def]
    """The field's value (float32) at row r, col c of a field in either form (in Python, and
    compiled by the overload below inside numba kernels)."""
    if isinstance(field, tuple):
        return field[1][field[0][r, c]]
    return field[r, c]


def rows_cols(field):  # type: ignore[no-untyped-def]
    """(H, W) of a field in either form."""
    return field[0].shape if isinstance(field, tuple) else field.shape


@overload(cell, inline="always")
def _cell(field, r, c):  # type: ignore[no-untyped-def]
    if isinstance(field, types.Array):
        return lambda field, r, c: field[r, c]
    if isinstance(field, types.BaseTuple):
        return lambda field, r, c: field[1][field[0][r, c]]
    return None


@overload(rows_cols, inline="always")
def _rows_cols(field):  # type: ignore[no-untyped-def]
    if isinstance(field, types.Array):
        return lambda field: field.shape
    if isinstance(field, types.BaseTuple):
        return lambda field: field[0].shape
    return None
