"""Benchmark relations files (Kuemmerle et al., Autonomous Robots 2009) as dataset input:
read `t1 t2 x y z roll pitch yaw` lines, find the file beside a log, and snap every stamp to
the log's scan times. The metric itself is `slamlab.eval.relations`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from slamlab.datasets.stamps import nearest_pair
from slamlab.errors import ConfigError, DataError
from slamlab.frames import Relations
from slamlab.io.compressed import read_text
from slamlab.config.datasets import RELATIONS_TIME_TOL_S

# Matching a relations file to a log (`dataset.relations_time_tol_s`): some published files
# round their stamps to 10 us, so a stamp is matched to the nearest scan within this (s).
DEFAULT_RELATIONS_TOL_S = RELATIONS_TIME_TOL_S  # one source: the dataset schemas (slamlab.config.datasets)
_RELATION_FIELDS = ("t1", "t2", "x", "y", "z", "roll", "pitch", "yaw")


def load_relations(path: str | Path) -> Relations:
    """Read a benchmark relations file: lines `t1 t2 x y z roll pitch yaw` (s, m, rad).

    Returns `Relations(t1, t2, rel=(x, y, yaw), path)`; z, roll and pitch (0 in the
    benchmark) are read but dropped. Blank lines and `#` comments are skipped. Any other
    line that is not 8 finite numbers raises DataError naming the line and field.
    """
    return _read_relations(Path(path))[0]


def relations_for_log(
    log_path: Path, stem: str, relations: str | Path | None, times: np.ndarray, tol_s: float
) -> tuple[Relations | None, Path | None]:
    """The benchmark relations of a log (CARMEN, ROS bag): the file `relations`, else
    `<stem>.relations` beside the log when there is one (else (None, None)). A relations file
    of another log would only fail at evaluation, after a long run: every stamp is matched to
    its scan (`times`, s) within `tol_s` now, and the scan's own time is used from here on."""
    if relations is not None:
        rel_path = Path(relations)
    else:
        rel_path = log_path.parent / f"{stem}.relations"
        if not rel_path.is_file():
            return None, None
    rel, rel_lines = _read_relations(rel_path)
    return snap_relations(rel, rel_lines, times, tol_s, log_name=log_path.name), rel_path


def _read_relations(path: Path) -> tuple[Relations, list[int]]:
    """The relations and the line number of each."""
    text = read_text(path)
    arr, linenos = _parse_well_formed(text)
    if arr is None:  # something is wrong: find the line and field to name
        arr, linenos = _parse_line_by_line(path, text)
    return Relations(t1=arr[:, 0], t2=arr[:, 1], rel=arr[:, [2, 3, 7]].copy(), path=str(path)), linenos


def _parse_well_formed(text: str) -> tuple[np.ndarray | None, list[int]]:
    """Every relation line's 8 numbers in one NumPy conversion ((None, []) unless each
    non-blank line holds 8 finite numbers and none is a comment): a run reads a benchmark's
    file once, and the line-by-line parse took 40 ms of every Intel run (2,984 lines)."""
    lines = text.split("\n")
    linenos = [k for k, line in enumerate(lines, 1) if line.strip()]
    tokens = [lines[k - 1].split() for k in linenos]
    if not tokens or any(len(t) != len(_RELATION_FIELDS) or t[0].startswith("#") for t in tokens):
        return None, []
    try:
        arr = np.array([v for t in tokens for v in t], dtype=np.float64).reshape(-1, len(_RELATION_FIELDS))
    except ValueError:
        return None, []
    return (arr, linenos) if np.isfinite(arr).all() else (None, [])


def _parse_line_by_line(path: Path, text: str) -> tuple[np.ndarray, list[int]]:
    """The relations of `text`, each line checked alone: raises DataError naming the line
    and field of the first that is not 8 finite numbers (comments and blank lines skipped)."""
    rows: list[list[float]] = []
    linenos: list[int] = []
    for lineno, line in enumerate(text.split("\n"), 1):
        parts = line.split()
        if not parts or parts[0].startswith("#"):
            continue
        record = f"line {lineno}"
        if len(parts) != len(_RELATION_FIELDS):
            fld = _RELATION_FIELDS[len(parts)] if len(parts) < len(_RELATION_FIELDS) else "yaw"
            what = "missing" if len(parts) < len(_RELATION_FIELDS) else "followed by extra values"
            raise DataError(path, f"{what}: expected 8 values (t1 t2 x y z roll pitch yaw), got {len(parts)}",
                            record=record, field=fld)  # fmt: skip
        row = []
        for name, tok in zip(_RELATION_FIELDS, parts):
            try:
                value = float(tok)
            except ValueError:
                raise DataError(path, f"expected a number, got {tok!r}", record=record, field=name) from None
            if not np.isfinite(value):
                raise DataError(path, f"expected a finite number, got {tok!r}", record=record, field=name)
            row.append(value)
        rows.append(row)
        linenos.append(lineno)
    if not rows:
        raise DataError(path, "no relations in file")
    return np.asarray(rows, dtype=np.float64), linenos


def snap_relations(
    relations: Relations, linenos: list[int], times: np.ndarray, tol_s: float, log_name: str = "the log"
) -> Relations:
    """The relations with each stamp replaced by the time of the scan nearest to it (`times`,
    s, file order), so that later lookups are exact.

    Raises DataError naming the relations file, the line, the stamp and the nearest scan
    time when a stamp has no scan within `tol_s` s (another log's relations?) or lies within
    `tol_s` of two scans of different times (ambiguous: lower the tolerance).
    """
    if not (np.isfinite(tol_s) and tol_s >= 0):
        raise ConfigError("dataset.relations_time_tol_s", f"must be a number of seconds >= 0, got {tol_s}")
    distinct = np.unique(np.asarray(times, dtype=np.float64))  # sorted; repeated scan times count once
    snapped = {}
    for name, query in (("t1", relations.t1), ("t2", relations.t2)):
        near, beside = nearest_pair(distinct, query)
        nearest, other = distinct[near], distinct[beside]  # other: the next nearest distinct time
        far = np.abs(nearest - query) > tol_s
        ambiguous = ~far & (other != nearest) & (np.abs(other - query) <= tol_s)
        for k in np.flatnonzero(far | ambiguous)[:1]:
            where = dict(record=f"line {linenos[k]}", field=name)
            if far[k]:
                raise DataError(relations.path, f"stamp {query[k]:.6f} has no scan in {log_name} within "
                                f"{tol_s:g} s (nearest scan time {nearest[k]:.6f}, {abs(nearest[k] - query[k]):.6f} s "
                                f"away; {int(np.count_nonzero(far))} stamps affected; wrong relations file?)", **where)
            raise DataError(relations.path, f"stamp {query[k]:.6f} is within {tol_s:g} s of two scans of "
                            f"{log_name} ({nearest[k]:.6f} and {other[k]:.6f}): ambiguous; lower "
                            "dataset.relations_time_tol_s", **where)  # fmt: skip
        snapped[name] = nearest
    return Relations(snapped["t1"], snapped["t2"], relations.rel, relations.path)
