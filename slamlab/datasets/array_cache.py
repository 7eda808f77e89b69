"""A small on-disk cache of parsed data: named NumPy arrays plus a JSON header per entry.

A text log that takes a second to decompress and parse (CARMEN's Intel: 0.6-0.9 s of CPU
and ~100 MB of transient memory) reads back from here in milliseconds. Entries live under
`paths.cache_dir()/<kind>/<name>/` as one `.npy` file per array and `meta.json`, written into
a temporary folder and renamed into place, so a reader never sees half an entry and two
writers of the same entry do not clash. Arrays come back memory-mapped read-only: pages are
read when touched. Any failure to read or write an entry counts as a miss; the caller
parses again. Each array's CRC-32 is kept in meta.json and checked when the entry is read: an
entry changed or cut short on disk is a miss too, said in one warning naming the file.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
import uuid
import warnings
import zlib
from pathlib import Path

import numpy as np

from slamlab import paths
from slamlab.heap import give_back_file_pages

log = logging.getLogger(__name__)

META = "meta.json"


def file_sha256(path: Path) -> str:
    """sha256 (hex) of a file's bytes (about 5 ms for Intel's 2.3 MB .bz2)."""
    h = hashlib.sha256()
    with Path(path).open("rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def entry_dir(kind: str, name: str) -> Path:
    """Where entry `name` of `kind` (e.g. "carmen") lives."""
    return paths.cache_dir() / kind / name


def checksum(arr: np.ndarray) -> int:
    """CRC-32 of an array's bytes (C order): a cached entry is checked against it when read
    (Intel's 12.8 MB in 5 ms). Against disk damage and edits, not against an adversary."""
    return zlib.crc32(memoryview(np.ascontiguousarray(arr)).cast("B"))


def read_entry(kind: str, name: str) -> tuple[dict[str, np.ndarray], dict] | None:
    """(arrays, meta) of an entry, or None when it is missing, unreadable or its content is
    not what was written (each array's CRC-32 in meta.json): a damaged or edited entry warns
    once (RuntimeWarning, naming the file) and the caller parses again."""
    folder = entry_dir(kind, name)
    if not (folder / META).is_file():
        return None
    key = META
    try:
        meta = json.loads((folder / META).read_text())
        arrays = {}
        for key in meta["arrays"]:
            mapped = np.load(folder / f"{key}.npy", mmap_mode="r")
            if checksum(mapped) != int(meta["crc32"][key]):
                warnings.warn(f"{folder / (key + '.npy')}: the cached copy changed since it was written (its checksum"
                              " differs): reading the log again", RuntimeWarning, stacklevel=2)
                return None
            give_back_file_pages(mapped)  # the check read every page; the run reads a scan at a time
            arrays[key] = np.asarray(mapped)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        warnings.warn(f"{folder / (key if key == META else key + '.npy')}: the cached copy is unreadable ({exc}):"
                      " reading the log again", RuntimeWarning, stacklevel=2)
        return None
    return arrays, meta


def write_entry(kind: str, name: str, arrays: dict[str, np.ndarray], meta: dict) -> bool:
    """Store an entry, replacing one of the same name (called after a miss, so that one was
    unreadable). True when stored; False when the cache folder cannot be written (the
    caller goes on without it)."""
    folder = entry_dir(kind, name)
    tag = f"{name}-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    tmp = folder.parent / f".tmp-{tag}"
    try:
        tmp.mkdir(parents=True)
        for key, arr in arrays.items():
            np.save(tmp / f"{key}.npy", np.ascontiguousarray(arr), allow_pickle=False)
        crc = {key: checksum(arr) for key, arr in arrays.items()}
        (tmp / META).write_text(json.dumps({**meta, "arrays": list(arrays), "crc32": crc}))
        if folder.exists():  # a broken entry: move it aside (readers of its files keep them)
            old = folder.parent / f".old-{tag}"
            try:
                os.rename(folder, old)
            except OSError:
                pass  # another writer moved it first
            shutil.rmtree(old, ignore_errors=True)
        try:
            os.rename(tmp, folder)
        except OSError:
            if not (folder / META).is_file():  # else another writer got there first
                raise
        return True
    except OSError as exc:
        log.debug("cannot write cache entry %s (%s)", folder, exc)
        return False
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
