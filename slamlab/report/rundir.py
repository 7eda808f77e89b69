"""Read a run directory (docs/RUN_DIRECTORY.md) into one typed object, and find run
directories under any folder.

Reports never recompute SLAM: everything here is a file read. Reading is forgiving on
purpose: a missing optional file (no ground truth, no texture, no steps table) becomes
None and the report simply omits that section; a run that failed or never finished is
still loaded, with its error and the tail of its log, so a sweep report can show it.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import yaml

from slamlab import artifacts
from slamlab.errors import SlamlabError

# File names are a contract (docs/RUN_DIRECTORY.md); keep them in one place.
METRICS_FILE = "metrics.json"
MANIFEST_FILE = "manifest.json"
MAP_FILE = "map_logodds.npz"
STEPS_CSV = "steps.csv"
STEPS_PARQUET = "steps.parquet"
TRAJECTORY_FILE = "trajectory.tum"
CAUSAL_FILE = "trajectory_causal.tum"
ODOMETRY_FILE = "odometry.tum"
GROUNDTRUTH_FILE = "groundtruth.tum"
PARTICLES_FILE = "particles.npz"  # record.particles
FIRST_SCAN_FILE = "first_scan.npz"  # record.first_scan
# Pairs (SLAM, odometry) so the page shows them side by side.
TRUTH_TEXTURE_FILE = "texture_truth.png"  # simulated data: the true floor on the textured cells
RELATIONS_FILE = "relations.csv"  # logs with benchmark relations: error per relation
GROUND_FRAMES_FILE = "ground_frames.npz"
REPLAY_FILE = "replay.npz"  # record.replay: snapshots for the replay  # RGB-D runs: sample frames of ground detection
LOG_FILE = "slamlab.log"
ERROR_FILE = "error.txt"
REPORT_FILE = "report.html"
HYDRA_DIR = ".hydra"

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
    """The raw occupancy grid: `data` (H, W) float32 log-odds, row 0 = lowest y;
    cell (r, c) covers x in [origin_x + c*res, +res), y in [origin_y + r*res, +res)."""

    data: np.ndarray
    resolution_m: float
    origin_xy: tuple[float, float]

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """(x_min, x_max, y_min, y_max) in metres, for matplotlib's imshow."""
        h, w = self.data.shape
        ox, oy = self.origin_xy
        return (ox, ox + w * self.resolution_m, oy, oy + h * self.resolution_m)


@dataclass(frozen=True, slots=True)
class ParticleRecord:
    """particles.npz: K steps of N particles. `t` (K,) s; `poses` (K, N, 3) after the
    update, before resampling; `weights` (K, N) normalised; `parents` (K, N) index into the
    previous step's particles; `resampled` (K,) bool."""

    t: np.ndarray
    poses: np.ndarray
    weights: np.ndarray
    parents: np.ndarray
    resampled: np.ndarray

    @property
    def particles(self) -> int:
        return int(self.poses.shape[1])


@dataclass(frozen=True, slots=True)
class FirstScan:
    """first_scan.npz: `points_xy` (M, 2) the first scan's points in the world frame (m),
    `sensor_xy` (2,) where the lidar was, `pose` (3,) the robot's pose then."""

    points_xy: np.ndarray
    sensor_xy: np.ndarray
    pose: np.ndarray


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

    def file(self, name: str) -> Path | None:
        """The path of an artifact if it exists, else None."""
        p = self.path / name
        return p if p.is_file() else None

    # --- lazily loaded arrays ------------------------------------------------------------
    def _cached(self, key: str, loader):
        if key not in self._cache:
            self._cache[key] = loader()
        return self._cache[key]

    def load_map(self) -> LogOddsMap | None:
        """The log-odds grid, or None when the run wrote no (readable) map."""
        return self._cached("map", lambda: read_logodds(self.path / MAP_FILE))

    def load_trajectory(self, which: str = "slam") -> Trajectory | None:
        """One of "slam", "causal", "odometry", "groundtruth"; None when absent."""
        files = {
            "slam": TRAJECTORY_FILE,
            "causal": CAUSAL_FILE,
            "odometry": ODOMETRY_FILE,
            "groundtruth": GROUNDTRUTH_FILE,
        }
        name = files[which]
        return self._cached("traj:" + which, lambda: read_tum(self.path / name))

    def load_particles(self) -> ParticleRecord | None:
        """Every particle's pose and weight per step (record.particles), or None."""
        return self._cached("particles", lambda: _read_npz(self.path / PARTICLES_FILE, ParticleRecord))

    def load_first_scan(self) -> FirstScan | None:
        """The first scan in the world frame (record.first_scan), or None."""
        return self._cached("first_scan", lambda: _read_npz(self.path / FIRST_SCAN_FILE, FirstScan))

    def load_steps(self) -> pd.DataFrame | None:
        """The per-step table (steps.parquet preferred, steps.csv otherwise), or None."""
        return self._cached("steps", lambda: read_steps(self.path))


# --- file readers ------------------------------------------------------------------------
def read_tum(path: Path) -> Trajectory | None:
    """A run's TUM trajectory (slamlab.artifacts.read_tum); None if the file is missing or
    holds no poses."""
    if not path.is_file():
        return None
    t, poses = artifacts.read_tum(path)
    if t.size == 0:
        return None
    return Trajectory(t=t, xy=poses[:, :2].copy(), yaw=poses[:, 2])


def read_logodds(path: Path) -> LogOddsMap | None:
    """Read map_logodds.npz (`slamlab.artifacts.read_logodds`); None if missing."""
    if not path.is_file():
        return None
    grid = artifacts.read_logodds(path)
    return LogOddsMap(data=grid.data, resolution_m=grid.resolution_m, origin_xy=grid.origin_xy)


def _read_npz(path: Path, record: type) -> Any:
    """An .npz written by the pipeline as `record` (its fields are the array names); None
    if the file is missing."""
    if not path.is_file():
        return None
    names = record.__dataclass_fields__
    with np.load(path) as z:
        missing = [n for n in names if n not in z]
        if missing:
            raise SlamlabError(f"{path}: missing array(s) {', '.join(missing)} (need {', '.join(names)})")
        return record(**{n: np.asarray(z[n]) for n in names})


def read_steps(run_dir: Path) -> pd.DataFrame | None:
    """The per-step table; Parquet first (typed, faster), CSV as fallback. None if absent."""
    pq = run_dir / STEPS_PARQUET
    if pq.is_file():
        try:
            return pd.read_parquet(pq)
        except Exception:  # noqa: BLE001 - a broken parquet falls back to the CSV twin
            pass
    csv = run_dir / STEPS_CSV
    if csv.is_file():
        return pd.read_csv(csv)
    return None


def _read_json(path: Path) -> dict[str, Any] | None:
    if not path.is_file():
        return None
    try:
        with path.open(encoding="utf-8") as f:
            obj = json.load(f)
    except (OSError, json.JSONDecodeError) as exc:
        raise SlamlabError(f"{path}: not valid JSON ({exc})") from exc
    return obj if isinstance(obj, dict) else None


def _read_yaml(path: Path) -> Any:
    if not path.is_file():
        return None
    try:
        with path.open(encoding="utf-8") as f:
            return yaml.safe_load(f)
    except (OSError, yaml.YAMLError):
        return None


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
    return (path / METRICS_FILE).is_file() or (path / HYDRA_DIR / "config.yaml").is_file()


def load_run(path: Path | str) -> RunDir:
    """Load one run directory. Raises SlamlabError if `path` is not a run directory or its
    metrics/manifest are unreadable JSON; missing optional artifacts are fine."""
    path = Path(path)
    if not path.is_dir():
        raise SlamlabError(f"{path}: not a directory")
    if not is_run_dir(path):
        raise SlamlabError(f"{path}: not a run directory (no {METRICS_FILE} and no {HYDRA_DIR}/config.yaml)")
    metrics = _read_json(path / METRICS_FILE)
    manifest = _read_json(path / MANIFEST_FILE) or {}
    config = manifest.get("config") if isinstance(manifest.get("config"), dict) else None
    if config is None:
        config = _read_yaml(path / HYDRA_DIR / "config.yaml")
    if not isinstance(config, dict):
        config = {}
    overrides = _read_yaml(path / HYDRA_DIR / "overrides.yaml")
    if not isinstance(overrides, list):
        overrides = []

    log_tail = _tail(path / LOG_FILE)
    error_txt = (path / ERROR_FILE).read_text(encoding="utf-8", errors="replace").strip() if (path / ERROR_FILE).is_file() else None
    if metrics is None:
        error = error_txt or _error_from_log(log_tail)
        status = STATUS_FAILED if error else STATUS_INCOMPLETE
        if status == STATUS_INCOMPLETE:
            error = f"no {METRICS_FILE}: the run was interrupted or is still running"
        metrics = {}
    else:
        status = str(metrics.get("status", STATUS_OK))
        error = metrics.get("error") or error_txt
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
                f"{p}: no run directories found (looked for {METRICS_FILE} or {HYDRA_DIR}/config.yaml)"
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
