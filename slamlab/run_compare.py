"""Compare two run directories file by file: is the second one the same result as the first?

Every result file counts (maps, trajectories, steps table, metrics, texture images, point
clouds, anything a future version adds): a file present in only one folder is a difference.
Only what measures the machine or the moment is left out: the timing and memory figures
inside metrics.json and the steps table, and the files that are records rather than results
(`NOT_RESULTS`). `slamlab-verify` uses this after re-running a run.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np

from slamlab.io.atomic import TMP_MARK
from slamlab.io.rundir import RECORDS, RunFile

# Records about the run, not results: the report and log hold timings, the manifest the
# machine, folder and commit; .hydra/ is the config the re-run was made from (the run
# directory contract's RECORDS). Log files (`*.log`) are records too.
NOT_RESULTS = RECORDS
# Runs before 2026-11-27 also wrote the steps table as steps.parquet, a twin of steps.csv
# (which is compared): a re-run made now does not write it, and that is no difference.
RETIRED_TWINS = frozenset({"steps.parquet"})
# Metrics (and step columns) that measure the machine or the implementation, not the
# algorithm's results: timings, memory, and the matcher's map reads (a faster kernel doing
# the same search reads fewer cells and finds the same poses).
# The graph filter's seconds per part (`graph.search_s`, ..., steps.csv's `optimise_s`) are timings too.
VOLATILE = re.compile(r"(runtime|_per_s$|realtime|memory|(^|_)ms(_|$)|time_s$|map_reads$|(^|_)(optimise|update|search|screen|match)_s$)")
TEXT_SUFFIXES = (".tum", ".yaml", ".txt")
IMAGE_SUFFIXES = (".png", ".pgm")


def result_files(run_dir: Path) -> set[str]:
    """Names of the result files in a run directory (sub-folders by relative path)."""
    run_dir = Path(run_dir)
    names = set()
    for p in run_dir.rglob("*"):
        rel = p.relative_to(run_dir)
        if (p.is_file() and rel.parts[0] not in NOT_RESULTS and rel.suffix != ".log"
                and rel.as_posix() not in RETIRED_TWINS and not rel.name.startswith(TMP_MARK)):
            names.add(rel.as_posix())
    return names


def first_text_difference(a: Path, b: Path) -> str | None:
    """None if the files are byte-identical, else where they first differ."""
    if a.read_bytes() == b.read_bytes():
        return None
    la, lb = a.read_text(errors="replace").splitlines(), b.read_text(errors="replace").splitlines()
    for i, (x, y) in enumerate(zip(la, lb), start=1):
        if x != y:
            return f"{a.name} line {i}:\n  original: {x}\n  re-run:   {y}"
    return f"{a.name}: {len(la)} lines originally, {len(lb)} in the re-run"


def first_nested_difference(
    a: object, b: object, skip: Callable[[str, str], bool], path: str = ""
) -> tuple[str, str] | None:
    """The first place where nested dicts `a` and `b` differ, as (dotted key, what), with
    what = "only a" / "only b" / "value"; keys where `skip(key, dotted key)` is true are
    ignored. None when equal."""
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b), key=str):
            key = f"{path}.{k}" if path else str(k)
            if skip(str(k), key):
                continue
            if k not in a or k not in b:
                return key, "only a" if k in a else "only b"
            diff = first_nested_difference(a[k], b[k], skip, key)
            if diff:
                return diff
        return None
    return (path, "value") if a != b else None


def value_at(d: object, key: str) -> object:
    """`d["a"]["b"]` for key "a.b"."""
    for part in key.split("."):
        d = d[part]  # type: ignore[index]
    return d


def first_metric_difference(a: dict, b: dict) -> str | None:
    """Compare metrics recursively, skipping volatile (timing/memory) keys."""
    diff = first_nested_difference(a, b, lambda k, _: bool(VOLATILE.search(k)))
    if diff is None:
        return None
    key, what = diff
    if what != "value":
        return f"metrics.json '{key}' present in only one run"
    return f"metrics.json '{key}': original {value_at(a, key)!r}, re-run {value_at(b, key)!r}"


def _metrics_difference(a: Path, b: Path) -> str | None:
    return first_metric_difference(json.loads(a.read_text()), json.loads(b.read_text()))


def _table_difference(a: Path, b: Path) -> str | None:
    """Per-step tables, every column but the step wall times (compared as the text written)."""
    import pandas as pd

    ta, tb = pd.read_csv(a, dtype=str), pd.read_csv(b, dtype=str)
    if list(ta.columns) != list(tb.columns) or len(ta) != len(tb):
        return f"{a.name}: shape {ta.shape} originally, {tb.shape} in the re-run"
    cols = [c for c in ta.columns if not VOLATILE.search(c)]
    for i, (ra, rb) in enumerate(zip(ta[cols].itertuples(index=False), tb[cols].itertuples(index=False))):
        if tuple(ra) != tuple(rb):
            return f"{a.name} row {i}:\n  original: {tuple(ra)}\n  re-run:   {tuple(rb)}"
    return None


def _npz_difference(a: Path, b: Path) -> str | None:
    """Arrays compared exactly (the zip container's own bytes may carry dates)."""
    with np.load(a) as za, np.load(b) as zb:
        if sorted(za.files) != sorted(zb.files):
            return f"{a.name}: arrays {sorted(za.files)} originally, {sorted(zb.files)} in the re-run"
        for key in sorted(za.files):
            x, y = za[key], zb[key]
            if x.shape != y.shape or x.dtype != y.dtype:
                return f"{a.name} '{key}': {x.dtype}{x.shape} originally, {y.dtype}{y.shape} in the re-run"
            same = x == y
            if x.dtype.kind == "f":
                same |= np.isnan(x) & np.isnan(y)
            if not same.all():
                return f"{a.name} '{key}': {int(same.size - same.sum())} of {x.size} values differ"
    return None


def _read_pixels(path: Path) -> np.ndarray:
    from PIL import Image

    with Image.open(path) as im:
        return np.asarray(im)


def _image_difference(a: Path, b: Path) -> str | None:
    """Images: the same bytes, else how many pixels differ and where the first one is."""
    if a.read_bytes() == b.read_bytes():
        return None
    try:
        pa, pb = _read_pixels(a), _read_pixels(b)
    except Exception as exc:  # noqa: BLE001 - an unreadable image is itself the difference
        return f"{a.name}: differs and cannot be decoded ({exc})"
    if pa.shape != pb.shape:
        return f"{a.name}: {pa.shape} pixels originally, {pb.shape} in the re-run"
    diff = pa != pb
    if diff.ndim == 3:
        diff = diff.any(axis=2)
    if not diff.any():
        return f"{a.name}: same pixels, different file bytes"
    r, c = np.argwhere(diff)[0]
    return f"{a.name}: {int(diff.sum())} of {diff.size} pixels differ (first at row {r}, column {c})"


def _bytes_difference(a: Path, b: Path) -> str | None:
    da, db = a.read_bytes(), b.read_bytes()
    if da == db:
        return None
    if len(da) != len(db):
        return f"{a.name}: {len(da)} bytes originally, {len(db)} in the re-run"
    first = next(i for i, (x, y) in enumerate(zip(da, db)) if x != y)
    return f"{a.name}: differs from byte {first} on"


def _comparer(name: str) -> Callable[[Path, Path], str | None]:
    if name == RunFile.METRICS:
        return _metrics_difference
    if name == RunFile.STEPS_CSV:
        return _table_difference
    suffix = Path(name).suffix
    if suffix == ".npz":
        return _npz_difference
    if suffix in IMAGE_SUFFIXES:
        return _image_difference
    if suffix in TEXT_SUFFIXES:
        return first_text_difference
    return _bytes_difference


def compared_order(names: set[str]) -> list[str]:
    """Trajectories first (the most telling difference), then the rest by name."""
    return sorted(names, key=lambda n: (not n.endswith(".tum"), n != RunFile.STEPS_CSV, n))


def compare_runs(original: Path, rerun: Path) -> str | None:
    """None when `rerun` reproduces every result file of `original`, else the first difference."""
    original, rerun = Path(original), Path(rerun)
    mine, theirs = result_files(original), result_files(rerun)
    for name in compared_order(mine | theirs):
        if name not in theirs:
            return f"{name} missing from the re-run"
        if name not in mine:
            return f"{name} written by the re-run but missing from the run"
        diff = _comparer(name)(original / name, rerun / name)
        if diff:
            return diff
    return None
