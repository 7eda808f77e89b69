"""A light table of named NumPy columns, for the small tables a run writes itself.

A run writes three tables (steps.csv, consistency.csv, relations.csv) of a few thousand rows.
Building them as pandas DataFrames made every run import pandas, and with it pyarrow when it
is installed: about 80 MB resident and 0.3 s of CPU, more than the Intel filter's maps at their
peak. So the run keeps its tables as columns and writes the CSV text here; the reports read
them back with `read_csv` (`RunDirectory.read_columns`), and `Table.to_pandas` converts one
where a DataFrame is wanted.

The CSV text is what `DataFrame.to_csv(index=False, float_format=...)` writes for the same
columns: booleans as True / False, integers in full, floats through `float_format` with NaN
as an empty field. `read_csv` reads such a file back as a Table with the columns pandas
would read, so that a run with its report loads no pandas either (0.2 s of CPU, 30 MB).
"""

from __future__ import annotations

import csv
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

if TYPE_CHECKING:
    import pandas as pd


class Table:
    """Named 1-D columns of equal length, in insertion order (read-only views)."""

    __slots__ = ("_cols", "_rows")

    def __init__(self, columns: Mapping[str, ArrayLike]) -> None:
        cols: dict[str, np.ndarray] = {}
        for name, values in columns.items():
            a = np.asarray(values)
            if a.ndim != 1:
                raise ValueError(f"table column {name!r} must be 1-D, got shape {a.shape}")
            a = a.view()
            a.flags.writeable = False
            cols[str(name)] = a
        lengths = {len(a) for a in cols.values()}
        if len(lengths) > 1:
            raise ValueError(f"table columns differ in length: { {k: len(a) for k, a in cols.items()} }")
        self._cols = cols
        self._rows = lengths.pop() if lengths else 0

    @property
    def columns(self) -> list[str]:
        return list(self._cols)

    def __len__(self) -> int:
        return self._rows

    def __getitem__(self, name: str) -> np.ndarray:
        return self._cols[name]

    def __contains__(self, name: object) -> bool:
        return name in self._cols

    def __iter__(self) -> Iterator[str]:
        return iter(self._cols)

    def __repr__(self) -> str:
        return f"Table({self._rows} rows: {', '.join(self._cols)})"

    def to_pandas(self) -> pd.DataFrame:
        import pandas as pd

        return pd.DataFrame(dict(self._cols))

    def to_csv(self, float_format: str = "%.9g", formats: Mapping[str, str] | None = None) -> str:
        """CSV text with a header row. `float_format` (%-style) formats float columns; `formats`
        maps a column to a str.format spec applied to every value (e.g. {"t": ".6f"} keeps
        epoch times to the microsecond, where 9 significant digits would round them to 10 s)."""
        formats = formats or {}
        fields = [_column_text(self._cols[name], float_format, formats.get(name)) for name in self._cols]
        lines = [",".join(self._cols)]
        lines.extend(",".join(row) for row in zip(*fields))
        return "\n".join(lines) + "\n"


def _column_text(a: np.ndarray, float_format: str, spec: str | None) -> list[str]:
    """One column's CSV fields (see `Table.to_csv`)."""
    if spec is not None:
        return [format(float(v), spec) for v in a.tolist()]
    if a.dtype == np.bool_:
        return ["True" if v else "False" for v in a.tolist()]
    if np.issubdtype(a.dtype, np.integer):
        return [str(v) for v in a.tolist()]
    if np.issubdtype(a.dtype, np.floating):
        # float32 values are formatted as the float64 they widen to, as pandas does
        return ["" if v != v else float_format % v for v in a.astype(np.float64).tolist()]
    return [_quoted(str(v)) for v in a.tolist()]


def _quoted(text: str) -> str:
    """A text field, quoted when it holds a comma, a quote or a line break (csv's minimal quoting)."""
    if any(ch in text for ch in ',"\n\r'):
        return '"' + text.replace('"', '""') + '"'
    return text


def read_csv(path: Path) -> Table:
    """A CSV file as `Table.to_csv` writes it (a header row, then one line per row) as a
    Table, with the columns pandas reads from it: bool (every field True or False), int64
    (every field an integer), float64 (numbers, an empty field NaN) or str. Raises
    ValueError naming the file and line when a row's field count differs from the header's."""
    with open(path, newline="", encoding="utf-8") as f:
        rows = list(csv.reader(f))
    if not rows:
        raise ValueError(f"{path}: empty file, no header row")
    header, body = rows[0], rows[1:]
    if len(header) == 1:  # a one-column table writes a NaN as an empty line
        body = [row or [""] for row in body]
    for k, row in enumerate(body):
        if len(row) != len(header):
            raise ValueError(f"{path}: line {k + 2} has {len(row)} fields, the header {len(header)}")
    return Table({name: _parse_column([row[j] for row in body]) for j, name in enumerate(header)})


def _parse_column(fields: list[str]) -> np.ndarray:
    """One column's fields as bool, int64, float64 (empty = NaN) or str (see `read_csv`)."""
    if fields and all(f in ("True", "False") for f in fields):
        return np.array([f == "True" for f in fields])
    text = np.array(fields, dtype=str)
    try:
        return text.astype(np.int64)
    except (ValueError, OverflowError):  # not all integers, or one beyond int64
        pass
    try:
        return np.where(text == "", "nan", text).astype(np.float64)
    except ValueError:
        return text
