"""The parsed-log cache of the CARMEN reader (`load_carmen(cache=True)`): a hit gives the
same scans bit for bit and the same warnings as parsing; a changed, moved or damaged file
or cache entry is parsed again."""

from __future__ import annotations

import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

from slamlab.datasets import carmen
from slamlab.datasets.carmen import load_carmen
from slamlab.paths import CACHE_DIR_ENV
from test_carmen import SMALL_LOG, flaser, robotlaser1, write

FIELDS = ("odom", "ranges", "angles", "valid", "lidar_to_body")


def assert_identical(a, b) -> None:
    """Same scans, bit for bit (dtypes and shapes too), same sequence attributes."""
    assert (len(a), a.name, a.max_range_m, a.sources) == (len(b), b.name, b.max_range_m, b.sources)
    for s, r in zip(a.scans, b.scans):
        assert (s.index, s.t, s.roll, s.pitch) == (r.index, r.t, r.roll, r.pitch)
        for f in FIELDS:
            x, y = getattr(s, f), getattr(r, f)
            assert x.dtype == y.dtype and x.shape == y.shape
            assert np.array_equal(x, y, equal_nan=True), f
            assert not y.flags.writeable
    assert (a.relations is None) == (b.relations is None)
    if a.relations is not None:
        for f in ("t1", "t2", "rel"):
            assert np.array_equal(getattr(a.relations, f), getattr(b.relations, f))


def load(path: Path, **kw) -> tuple[object, list[tuple[type, str]]]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        seq = load_carmen(path, **kw)
    return seq, [(w.category, str(w.message)) for w in caught]


def entries(cache: Path) -> list[Path]:
    folder = cache / "carmen"
    return sorted(p for p in folder.iterdir() if not p.name.startswith(".")) if folder.is_dir() else []


@pytest.fixture
def cache(tmp_path, monkeypatch) -> Path:
    """An empty cache folder, and every log big enough to be cached."""
    folder = tmp_path / "cache"
    monkeypatch.setenv(CACHE_DIR_ENV, str(folder))
    monkeypatch.setattr(carmen, "CACHE_MIN_BYTES", 0)
    return folder


# a log that warns twice: FLASER copies beside ROBOTLASER1, and NaN / negative readings
WARNING_LOG = "\n".join([
    robotlaser1([1.0, "nan", 2.0], [], (0, 0, 0), (0, 0, 0), t=5.0),
    robotlaser1([-1.0, 3.0, 2.5], [], (0.1, 0, 0), (0.1, 0, 0), t=5.1),
    flaser([1.0, 2.0, 2.0], t=5.0),
])  # fmt: skip


@pytest.mark.parametrize("text", [SMALL_LOG, WARNING_LOG])
def test_a_hit_gives_what_parsing_gives(cache, tmp_path, text):
    path = write(tmp_path / "log.clf", text)
    parsed, parse_warnings = load(path)
    cold, cold_warnings = load(path, cache=True)
    assert len(entries(cache)) == 1
    warm, warm_warnings = load(path, cache=True)
    assert_identical(parsed, cold)
    assert_identical(parsed, warm)
    assert parse_warnings == cold_warnings == warm_warnings
    assert len(parse_warnings) == (0 if text == SMALL_LOG else 2)


def mapped_file(arr: np.ndarray) -> str | None:
    """The file an array's memory is mapped from (walking its bases), None when it is on the heap."""
    while arr is not None:
        if isinstance(arr, np.memmap) and arr.filename:
            return arr.filename
        arr = arr.base if isinstance(arr, np.ndarray) else None
    return None


def test_the_run_that_writes_the_entry_goes_on_with_the_written_copy(cache, tmp_path):
    # the parse's arrays are let go for the entry's mapped files, as the next run reads them
    # (the hospital's first run: 395 -> 380 MB at its peak); parsing alone stays on the heap
    path = write(tmp_path / "log.clf", WARNING_LOG)
    cold, _ = load(path, cache=True)
    parsed, _ = load(path)
    for f in ("odom", "ranges", "valid"):
        written = mapped_file(getattr(cold.scans[0], f))
        assert written is not None and Path(written).is_relative_to(cache), f
        assert mapped_file(getattr(parsed.scans[0], f)) is None, f


def test_skip_mode_warning_and_options_are_part_of_the_key(cache, tmp_path):
    lines = [flaser([1.0, 2.0, 3.0], t=float(k)) for k in range(4)]
    lines.insert(2, "FLASER 3 1.0 2.0 x3 0 0 0 0 0 0 1.5 nohost 0.2")
    path = write(tmp_path / "broken.clf", "\n".join(lines))
    parsed, parse_warnings = load(path, on_bad_line="skip")
    for _ in range(2):
        seq, seq_warnings = load(path, on_bad_line="skip", cache=True)
        assert_identical(parsed, seq)
        assert seq_warnings == parse_warnings and "skipped 1 bad line" in seq_warnings[0][1]
    load(path, on_bad_line="skip", max_range_m=2.5, cache=True)
    assert len(entries(cache)) == 2  # another max_range_m: another entry
    with pytest.raises(Exception, match=r"broken\.clf: line 3 \(FLASER\), field 'range\[2\]'"):
        load_carmen(path, cache=True)  # error mode: nothing cached, the same error


def test_a_changed_file_is_parsed_again(cache, tmp_path):
    path = write(tmp_path / "log.clf", SMALL_LOG)
    load(path, cache=True)
    write(path, SMALL_LOG.replace("1.1 20.0 2.5", "1.1 20.0 2.7"))
    seq, _ = load(path, cache=True)
    assert seq.scans[1].ranges[2] == np.float32(2.7)
    assert len(entries(cache)) == 2


def test_warnings_name_the_file_as_given(cache, tmp_path):
    (tmp_path / "a").mkdir()
    first = write(tmp_path / "a" / "log.clf", WARNING_LOG)
    load(first, cache=True)
    moved = tmp_path / "b" / "log.clf"
    moved.parent.mkdir()
    shutil.copy(first, moved)
    _, moved_warnings = load(moved, cache=True)
    assert moved_warnings and all(m.startswith(str(moved)) for _, m in moved_warnings)


def _cached_log(cache, tmp_path):
    """A small log read once and cached: (its path, what it parses to, its first ranges file in the cache)."""
    path = write(tmp_path / "log.clf", SMALL_LOG)
    parsed, _ = load(path)
    load(path, cache=True)
    (entry,) = entries(cache)
    return path, parsed, entry / "0.ranges.npy"


def test_a_damaged_entry_is_parsed_again_and_repaired(cache, tmp_path):
    path, parsed, victim = _cached_log(cache, tmp_path)
    victim.write_bytes(victim.read_bytes()[:20])  # cut short
    seq, _ = load(path, cache=True)
    assert_identical(parsed, seq)
    seq, _ = load(path, cache=True)  # the entry was written again
    assert_identical(parsed, seq)
    assert len(victim.read_bytes()) > 20


def test_an_unwritable_cache_is_no_error(tmp_path, monkeypatch):
    blocker = write(tmp_path / "not-a-folder", "x")  # the cache "folder" is a file
    monkeypatch.setenv(CACHE_DIR_ENV, str(blocker))
    monkeypatch.setattr(carmen, "CACHE_MIN_BYTES", 0)
    path = write(tmp_path / "log.clf", SMALL_LOG)
    assert_identical(load(path)[0], load(path, cache=True)[0])


def test_small_logs_are_not_cached(tmp_path, monkeypatch):
    monkeypatch.setenv(CACHE_DIR_ENV, str(tmp_path / "cache"))
    load(write(tmp_path / "log.clf", SMALL_LOG), cache=True)
    assert entries(tmp_path / "cache") == []


def test_missing_file_message_unchanged(cache, tmp_path):
    with pytest.raises(Exception, match=r"nothing\.clf: file not found"):
        load_carmen(tmp_path / "nothing.clf", cache=True)


@pytest.mark.data
@pytest.mark.parametrize("log", ["intel.clf.bz2", "aces.clf.bz2"])
def test_benchmark_logs_through_the_cache(shared_data, tmp_path, monkeypatch, log):
    monkeypatch.setenv(CACHE_DIR_ENV, str(tmp_path / "cache"))
    parsed, parse_warnings = load(shared_data / "carmen" / log)
    cold, cold_warnings = load(shared_data / "carmen" / log, cache=True)
    warm, warm_warnings = load(shared_data / "carmen" / log, cache=True)
    assert len(entries(tmp_path / "cache")) == 1
    assert_identical(parsed, cold)
    assert_identical(parsed, warm)
    assert parse_warnings == cold_warnings == warm_warnings


def test_an_entry_edited_on_disk_is_caught_said_once_and_parsed_again(cache, tmp_path):
    """Issue 45: a cached file with one range changed (same size, still a valid .npy) was read
    back silently. Its checksum no longer matches: one warning naming it, the log is parsed
    again (the scans are the log's, not the edit) and the entry is written again."""
    path, parsed, victim = _cached_log(cache, tmp_path)
    ranges = np.load(victim)
    edited = ranges.copy()
    edited.flat[2] += 1.0
    size = victim.stat().st_size
    np.save(victim, edited)
    assert victim.stat().st_size == size
    seq, said = load(path, cache=True)
    assert_identical(parsed, seq)
    assert said == [(RuntimeWarning, f"{victim}: the cached copy changed since it was written (its checksum differs):"
                                     " reading the log again")]
    again, said = load(path, cache=True)  # repaired: no warning, the log's values
    assert said == [] and np.array_equal(np.load(victim), ranges)


def test_an_entry_cut_short_warns_once(cache, tmp_path):
    path, parsed, victim = _cached_log(cache, tmp_path)
    victim.write_bytes(victim.read_bytes()[:-8])  # the last two float32 ranges lost
    seq, said = load(path, cache=True)
    assert_identical(parsed, seq)
    assert len(said) == 1 and said[0][1].startswith(f"{victim}: the cached copy is unreadable (")
