"""Read a run directory (docs/RUN_DIRECTORY.md) into one typed object, and find run
directories under any folder.

Reports never recompute SLAM: everything here is a file read. Reading is forgiving on
purpose: a missing optional file (no ground truth, no texture, no steps table) becomes
None and the report simply omits that section; a run that failed or never finished is
still loaded, with its error and the tail of its log, so a sweep report can show it.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from slamlab.errors import SlamlabError
from slamlab.io.atomic import json_ready
from slamlab.io.rundir import FirstScan, ParticleRecord, RunDirectory, RunFile, TrajectoryKind  # noqa: F401 (types the report modules use)
from slamlab.io.rundir import LogOddsRows, read_logodds_rows
from slamlab.io.table import Table
from slamlab.io.tum import read_tum as read_tum_file

STATUS_OK = "ok"
STATUS_FAILED = "failed"
STATUS_INCOMPLETE = "incomplete"  # no metrics.json and no recorded error: killed or still running


@dataclass(frozen=True, slots=True)
class Trajectory:
    """A planar trajectory read from a TUM file: `t` (N,) s, `xy` (N, 2) m, `yaw` (N,) rad."""

    t: np.ndarray
    xy: np.ndarray
    yaw: np.ndarray

    def __len__(self) -> int:
        return int(self.t.shape[0])


@dataclass(frozen=True, slots=True)
class LogOddsMap:
    """The raw occupancy grid: `data` (H, W) log-odds (float32, or a `LogOddsRows` whose
    bands are), row 0 = lowest y;
    cell (r, c) covers x in [origin_x + c*res, +res), y in [origin_y + r*res, +res).
    A run's map is `data` = a `LogOddsRows`, read from its file a band of rows at a time
    (`bands`) whenever a figure reduces it: a building's map is ~200 MB as an array, and a
    report, or a sweep's report of many runs, held each one whole."""

    data: np.ndarray | LogOddsRows
    resolution_m: float
    origin_xy: tuple[float, float]
    known: dict = field(default_factory=dict, compare=False, repr=False)  # figures' cache of what they found in `data`

    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.data.shape)  # type: ignore[return-value]

    def bands(self, r0: int, r1: int, rows: int) -> Iterator[np.ndarray]:
        """Rows r0..r1 of `data`, `rows` at a time (the last band may be shorter)."""
        if isinstance(self.data, LogOddsRows):
            yield from self.data.bands(r0, r1, rows)
            return
        for r in range(r0, r1, rows):
            yield self.data[r:min(r + rows, r1)]

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """(x_min, x_max, y_min, y_max) in metres, for matplotlib's imshow."""
        h, w = self.shape
        ox, oy = self.origin_xy
        return (ox, ox + w * self.resolution_m, oy, oy + h * self.resolution_m)


@dataclass(slots=True)
class RunDir:
    """Everything a report shows about one run, loaded from its directory.

    `status` is "ok", "failed" (an error was recorded) or "incomplete" (no metrics and no
    error: the run was killed or is still running). `config` is the resolved config
    (manifest.json "config", else .hydra/config.yaml); `overrides` the Hydra task overrides
    (`key=value` strings). The large arrays (map, trajectories, steps) are loaded lazily by
    the methods below and cached, so finding and tabulating many runs stays cheap.
    """

    path: Path
    status: str
    error: str | None
    metrics: dict[str, Any]
    manifest: dict[str, Any]
    config: dict[str, Any]
    overrides: list[str]
    log_tail: str | None = None
    _cache: dict[str, Any] = field(default_factory=dict, repr=False)

    # --- convenience -------------------------------------------------------------------
    @property
    def name(self) -> str:
        """The directory name (the job number inside a sweep)."""
        return self.path.name

    @property
    def ok(self) -> bool:
        return self.status == STATUS_OK

    @property
    def particles(self) -> int | None:
        v = self.metrics.get("particles", self.config.get("particles"))
        return int(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else None

    @property
    def one_trajectory(self) -> bool:
        """A run of a filter that keeps one trajectory and no particles (`filter=graph`): no
        N_eff, weights or resampling to show."""
        return isinstance(self.metrics.get("graph"), dict)

    @property
    def seed(self) -> Any:
        return self.metrics.get("seed", self.config.get("seed"))

    @property
    def dataset(self) -> str | None:
        v = self.metrics.get("dataset")
        if v is None:
            ds = self.config.get("dataset")
            if isinstance(ds, dict):
                v = ds.get("name")
            elif isinstance(ds, str):
                v = ds
        return str(v) if v is not None else None

    def overrides_dict(self) -> dict[str, str]:
        """Task overrides as {key: value}; Hydra prefixes (+, ++, ~) stripped from keys.

        A plain `key=value` wins over `+key=value` for the same key whatever their order, as
        in Hydra: a sweep preset (`+experiment=ladder`) whose sweeper sets `experiment=X`
        per job ran preset X."""
        out: dict[str, str] = {}
        plain: set[str] = set()
        for item in self.overrides:
            key, sep, value = str(item).partition("=")
            if not sep:
                continue
            name = key.lstrip("+~")
            if name in plain and key != name:
                continue
            out[name] = value
            if key == name:
                plain.add(name)
        return out

    def setting(self, key: str) -> Any:
        """What the run used for `key` (a dotted config key, or a config group such as
        "filter" or "experiment") when no override of its own says: the group's choice from
        Hydra's record, else the resolved config's value; None when neither knows it."""
        choice = self.choices.get(key)
        if choice is not None:
            return choice
        node: Any = self.config
        for part in key.split("."):
            if not isinstance(node, dict) or part not in node:
                return None
            node = node[part]
        return None if isinstance(node, (dict, list)) else node

    @property
    def choices(self) -> dict[str, str]:
        """The config group choices (`RunDirectory.read_choices`), read once."""
        return self._cached("choices", self.files.read_choices)

    @property
    def files(self) -> RunDirectory:
        """The run directory contract on this folder (names, readers)."""
        return RunDirectory(self.path)

    def file(self, name: str) -> Path | None:
        """The path of an artifact if it exists, else None."""
        return self.files.file(name)

    # --- lazily loaded arrays ------------------------------------------------------------
    def _cached(self, key: str, loader):
        if key not in self._cache:
            self._cache[key] = loader()
        return self._cache[key]

    def load_map(self) -> LogOddsMap | None:
        """The log-odds grid, or None when the run wrote no map (a file that cannot be read
        raises DataError naming it, when it is opened or when a figure reads its rows)."""
        return self._cached("map", lambda: read_logodds(self.path / RunFile.MAP_LOGODDS))

    def load_trajectory(self, which: str = "slam") -> Trajectory | None:
        """One of "slam", "causal", "odometry", "groundtruth"; None when absent."""
        kind = TrajectoryKind(which)
        return self._cached("traj:" + which, lambda: _trajectory(self.files.read_trajectory(kind)))

    def load_particles(self) -> ParticleRecord | None:
        """Every particle's pose and weight per step (record.particles), or None."""
        return self._cached("particles", self.files.read_particles)

    def load_first_scan(self) -> FirstScan | None:
        """The first scan in the world frame (record.first_scan), or None."""
        return self._cached("first_scan", self.files.read_first_scan)

    def load_steps(self) -> Table | None:
        """The per-step table (steps.csv) as NumPy columns, or None."""
        return self._cached("steps", lambda: self.files.read_columns(RunFile.STEPS_CSV))

    def load_loops(self) -> Table | None:
        """A graph run's loop candidates (loops.csv) as NumPy columns, or None (other filters):
        read by the loop-closure section and by the consistency section's broken stretches."""
        return self._cached("loops", lambda: self.files.read_columns(RunFile.LOOPS))


# --- file readers (the contract reads, these wrap for the figures) -----------------------
def _trajectory(read: tuple[np.ndarray, np.ndarray] | None) -> Trajectory | None:
    if read is None:
        return None
    t, poses = read
    return Trajectory(t=t, xy=poses[:, :2].copy(), yaw=poses[:, 2])


def read_tum(path: Path) -> Trajectory | None:
    """A TUM trajectory file (slamlab.io.tum.read_tum); None if the file is missing or holds
    no poses."""
    return _trajectory(read_tum_file(path) if path.is_file() else None)


def read_logodds(path: Path) -> LogOddsMap | None:
    """A map_logodds.npz (slamlab.io.rundir.read_logodds_rows: its data read band by band
    when a figure reduces it); None if missing."""
    if not path.is_file():
        return None
    data, res, origin = read_logodds_rows(path)
    return LogOddsMap(data=data, resolution_m=res, origin_xy=origin)


def _tail(path: Path, max_lines: int = 40, max_bytes: int = 64_000) -> str | None:
    """The last lines of a text file (bounded read: logs can be long)."""
    if not path.is_file():
        return None
    size = path.stat().st_size
    with path.open("rb") as f:
        f.seek(max(0, size - max_bytes))
        text = f.read().decode("utf-8", errors="replace")
    lines = text.splitlines()[-max_lines:]
    return "\n".join(lines) if lines else None


def _error_from_log(log: str | None) -> str | None:
    """Best guess at the error from a log tail: the last traceback's final line or ERROR line."""
    if not log:
        return None
    for line in reversed(log.splitlines()):
        s = line.strip()
        if "[ERROR]" in s or "[CRITICAL]" in s or (s and ("Error:" in s or "Exception:" in s)):
            return s
    return None


def is_run_dir(path: Path) -> bool:
    """A run directory has a metrics.json or Hydra's saved .hydra/config.yaml."""
    return RunDirectory(path).is_run()


def load_run(path: Path | str) -> RunDir:
    """Load one run directory. Raises SlamlabError if `path` is not a run directory or its
    metrics/manifest are unreadable JSON; missing optional artifacts are fine."""
    path = Path(path)
    if not path.is_dir():
        raise SlamlabError(f"{path}: not a directory")
    if not is_run_dir(path):
        raise SlamlabError(f"{path}: not a run directory (no {RunFile.METRICS} and no {RunFile.HYDRA_CONFIG})")
    files = RunDirectory(path)
    record = files.read_metrics()
    # the page shows metrics.json as written: NaN back to null, the file's key order
    metrics = json_ready(record.to_dict()) if record is not None else None
    manifest = files.read_manifest() or {}
    config = manifest.get("config") if isinstance(manifest.get("config"), dict) else None
    if config is None:
        config = files.read_config()
    if not isinstance(config, dict):
        config = {}
    overrides = files.read_overrides()

    log_tail = _tail(path / RunFile.LOG)
    error_txt = (path / RunFile.ERROR).read_text(encoding="utf-8", errors="replace").strip() if (path / RunFile.ERROR).is_file() else None
    if metrics is None:
        error = error_txt or _error_from_log(log_tail)
        status = STATUS_FAILED if error else STATUS_INCOMPLETE
        if status == STATUS_INCOMPLETE:
            error = f"no {RunFile.METRICS}: the run was interrupted or is still running"
        metrics = {}
    else:
        status = record.status or STATUS_OK  # files from before `status` was written
        error = record.error or error_txt
        if status != STATUS_OK and not error:
            error = _error_from_log(log_tail) or f"status '{status}' without an error message"
    return RunDir(
        path=path,
        status=status,
        error=str(error) if error else None,
        metrics=metrics,
        manifest=manifest,
        config=config,
        overrides=[str(o) for o in overrides],
        log_tail=log_tail,
    )


def find_run_dirs(paths: list[Path] | tuple[Path, ...]) -> list[Path]:
    """Every run directory at or under `paths` (a run dir, a sweep dir, or a folder of
    sweeps), de-duplicated, in a stable order (numeric job numbers sort as numbers).

    Raises SlamlabError naming the path when a path does not exist or holds no runs, so a
    typo on the command line is not silently an empty report.
    """
    found: dict[Path, None] = {}
    for p in paths:
        p = Path(p)
        if not p.exists():
            raise SlamlabError(f"{p}: no such file or directory")
        if p.is_file():
            # Accept a path to a run's metrics.json / report.html: the run is its folder.
            p = p.parent
        runs: list[Path] = []
        if is_run_dir(p):
            runs.append(p)
        else:
            for root, dirs, _files in os.walk(p):
                r = Path(root)
                if is_run_dir(r):
                    runs.append(r)
                    dirs[:] = []  # a run's subfolders (.hydra, ...) hold no runs
                    continue
                # Skip hidden folders and generated report folders: they never hold runs.
                dirs[:] = sorted(d for d in dirs if not d.startswith("."))
        if not runs:
            raise SlamlabError(
                f"{p}: no run directories found (looked for {RunFile.METRICS} or {RunFile.HYDRA_CONFIG})"
            )
        for r in sorted(runs, key=_natural_key):
            found.setdefault(r.resolve(), None)
    return list(found)


def _natural_key(p: Path) -> tuple:
    """Sort '2' before '10' in job numbers."""
    return tuple((0, int(part), "") if part.isdigit() else (1, 0, part) for part in p.parts)


def flatten(d: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested dict to {"a.b.c": value}; lists are kept as values (compared as a whole)."""
    out: dict[str, Any] = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict) and v:
            out.update(flatten(v, key + "."))
        else:
            out[key] = v
    return out


def as_float(v: Any) -> float:
    """A metric value as float, NaN when absent or not numeric (bools are not numbers here)."""
    if isinstance(v, bool) or v is None:
        return math.nan
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan
