"""slamlab.io.table: the run's own tables, written as pandas would write them."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from slamlab.io.table import Table


def _mixed() -> dict[str, np.ndarray]:
    return {
        "step": np.arange(5),
        "t": np.array([976052884.925008, 976052886.31619, np.nan, 1.5, 2.0]),
        "neff": np.array([30.0, 29.9996034, np.nan, np.inf, 1e-12]),
        "resampled": np.array([False, True, False, False, True]),
        "hit_fraction": np.array([1.0, 0.25, 0.333333, 0.1, 0.7], dtype=np.float32),
        "name": np.array(["a", "b,c", 'say "hi"', "d", "e"]),
    }


def _pandas_csv(cols: dict[str, np.ndarray], float_format: str) -> str:
    # what the run wrote before it stopped using pandas (artifacts.write_table, 2026-11-26)
    df = pd.DataFrame(cols)
    df["t"] = df["t"].map(lambda v: f"{v:.6f}")
    return df.to_csv(index=False, float_format=float_format)


@pytest.mark.parametrize("float_format", ["%.6g", "%.9g"])
def test_csv_text_is_what_pandas_writes(float_format):
    cols = _mixed()
    assert Table(cols).to_csv(float_format, {"t": ".6f"}) == _pandas_csv(cols, float_format)


def test_csv_reads_back_with_the_same_columns_and_values():
    cols = _mixed()
    from io import StringIO

    back = pd.read_csv(StringIO(Table(cols).to_csv("%.17g")))
    assert list(back.columns) == list(cols)
    assert back["resampled"].dtype == bool and back["step"].dtype == np.int64
    np.testing.assert_array_equal(back["neff"].to_numpy(), cols["neff"])


def test_an_empty_table_is_its_header():
    assert Table({"a": np.zeros(0), "b": np.zeros(0, dtype=int)}).to_csv() == "a,b\n"
    assert len(Table({})) == 0


def test_columns_keep_their_order_and_are_read_only():
    t = Table(_mixed())
    assert t.columns == list(_mixed()) and len(t) == 5 and "neff" in t and "x" not in t
    with pytest.raises(ValueError):
        t["neff"][0] = 1.0
    assert t.to_pandas()["resampled"].tolist() == [False, True, False, False, True]


def test_bad_columns_are_refused():
    with pytest.raises(ValueError, match="differ in length"):
        Table({"a": np.zeros(3), "b": np.zeros(4)})
    with pytest.raises(ValueError, match="1-D"):
        Table({"a": np.zeros((3, 2))})


def test_read_csv_gives_back_the_columns_pandas_reads(tmp_path):
    # the run report reads its tables with read_csv (no pandas): same columns, dtypes and values
    from io import StringIO

    from slamlab.io.table import read_csv

    text = Table(_mixed()).to_csv("%.17g")
    (tmp_path / "t.csv").write_text(text)
    mine, theirs = read_csv(tmp_path / "t.csv"), pd.read_csv(StringIO(text))
    assert mine.columns == list(theirs.columns)
    for name in mine:
        want = theirs[name].to_numpy()
        assert mine[name].dtype.kind == want.dtype.kind or (mine[name].dtype.kind == "U" and want.dtype == object), name
        if want.dtype.kind == "f":
            np.testing.assert_array_equal(mine[name], want)  # NaN where pandas has NaN, bit for bit elsewhere
        else:
            assert mine[name].tolist() == want.tolist(), name
    (tmp_path / "bad.csv").write_text("a,b\n1,2\n3\n")
    with pytest.raises(ValueError, match=r"bad.csv: line 3 has 1 fields, the header 2"):
        read_csv(tmp_path / "bad.csv")
    (tmp_path / "one.csv").write_text(Table({"v": np.array([1.5, np.nan, 2.0])}).to_csv())  # NaN: an empty line (pandas skips it)
    np.testing.assert_array_equal(read_csv(tmp_path / "one.csv")["v"], [1.5, np.nan, 2.0])
    (tmp_path / "big.csv").write_text("n\n1\n99999999999999999999\n")  # past int64: floats (pandas: text), no crash
    assert read_csv(tmp_path / "big.csv")["n"].dtype == np.float64
    (tmp_path / "empty.csv").write_text("a,b\n")
    empty = read_csv(tmp_path / "empty.csv")
    assert empty.columns == ["a", "b"] and len(empty) == 0
