"""The run directory contract (docs/RUN_DIRECTORY.md): every file name of a run, and the
readers and writers of the files whose format is plain data (JSON, TUM, NumPy archives).

The pipeline writes through it, the reports read through it and `slamlab-verify` compares
through it, so a file name is spelled once. It sits in the core layer (it needs nothing but
numpy and the other io helpers) so that every layer above can use it; the writers that need
the pipeline's formats (the map images, the CSV tables: `slamlab.artifacts`) take
their names from here.

Readers are forgiving where reports need them to be: an optional file that is absent reads
as None. Every write is atomic (`slamlab.io.atomic`).
"""

from __future__ import annotations

import json
import os
import zipfile
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, fields
from enum import StrEnum
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from slamlab.errors import DataError, SlamlabError
from slamlab.frames import GridImage
from slamlab.io.atomic import write_json, write_npz, write_npz_fast
from slamlab.io.run_metrics import RunMetrics
from slamlab.io.table import Table, read_csv
from slamlab.io.tum import read_tum, write_tum


class RunFile(StrEnum):
    """Every fixed name in a run directory (a `str`: `path / RunFile.METRICS` works)."""

    MAP_PNG = "map.png"
    MAP_PGM = "map.pgm"
    MAP_YAML = "map.yaml"
    MAP_LOGODDS = "map_logodds.npz"
    TRAJECTORY = "trajectory.tum"
    TRAJECTORY_CAUSAL = "trajectory_causal.tum"
    ODOMETRY = "odometry.tum"
    GROUNDTRUTH = "groundtruth.tum"
    STEPS_CSV = "steps.csv"
    CONSISTENCY = "consistency.csv"
    CONSISTENCY_MAP = "consistency_map.npz"  # where the scans contradict the map (the report's overlay)
    PARTICLES = "particles.npz"  # record.particles
    REPLAY = "replay.npz"  # record.replay
    RELATIONS = "relations.csv"  # logs with benchmark relations
    LOOPS = "loops.csv"  # filter=graph: every loop candidate, accepted or not
    FIRST_SCAN = "first_scan.npz"  # record.first_scan
    TEXTURE = "texture.png"
    TEXTURE_OVER_MAP = "texture_over_map.png"
    FLOOR_CLOUD = "floor.ply"
    TEXTURE_ODOMETRY = "texture_odometry.png"
    TEXTURE_ODOMETRY_OVER_MAP = "texture_odometry_over_map.png"
    FLOOR_CLOUD_ODOMETRY = "floor_odometry.ply"
    TEXTURE_TRUTH = "texture_truth.png"  # simulated data: the true floor on the textured cells
    GROUND_FRAMES = "ground_frames.npz"  # RGB-D runs: sample frames of ground detection
    METRICS = "metrics.json"
    MANIFEST = "manifest.json"
    REPORT = "report.html"
    LOG = "slamlab.log"
    ERROR = "error.txt"  # written by launchers that record a job's error outside the run
    CLAIM = ".slamlab-run"  # created exclusively when a run starts
    HYDRA_DIR = ".hydra"
    HYDRA_CONFIG = ".hydra/config.yaml"
    HYDRA_OVERRIDES = ".hydra/overrides.yaml"
    HYDRA_RECORD = ".hydra/hydra.yaml"


class SweepFile(StrEnum):
    """The names a sweep directory (`multirun/DATE/TIME/`) adds beside its runs `0/`, `1/`, ..."""

    MULTIRUN = "multirun.yaml"  # Hydra's record of the sweep
    REPORT = "report.html"  # the comparison report
    RUNS_CSV = "runs.csv"  # its table, one row per run


class TrajectoryKind(StrEnum):
    """The four TUM trajectories of a run."""

    SLAM = "slam"
    CAUSAL = "causal"
    ODOMETRY = "odometry"
    GROUNDTRUTH = "groundtruth"


TRAJECTORY_FILES: dict[TrajectoryKind, RunFile] = {
    TrajectoryKind.SLAM: RunFile.TRAJECTORY,
    TrajectoryKind.CAUSAL: RunFile.TRAJECTORY_CAUSAL,
    TrajectoryKind.ODOMETRY: RunFile.ODOMETRY,
    TrajectoryKind.GROUNDTRUTH: RunFile.GROUNDTRUTH,
}

# Files whose presence means a folder already holds a (finished, failed or running) run.
RUN_MARKERS: tuple[RunFile, ...] = (RunFile.CLAIM, RunFile.METRICS, RunFile.MANIFEST, RunFile.TRAJECTORY)
# Records about a run, not results: timings (report, log), the machine and folder
# (manifest), the config it was made from (.hydra/). `slamlab-verify` does not compare them.
RECORDS: frozenset[str] = frozenset({RunFile.REPORT, RunFile.LOG, RunFile.MANIFEST, RunFile.CLAIM, RunFile.HYDRA_DIR})


class TextureFiles(NamedTuple):
    """The texture stage's three outputs along one trajectory."""

    texture: Path  # RGBA, unobserved cells transparent
    over_map: Path  # the texture over the occupancy map
    cloud: Path  # the coloured floor cloud (PLY)


@dataclass(frozen=True, slots=True)
class ParticleRecord:
    """particles.npz: K steps of N particles. `t` (K,) s; `poses` (K, N, 3) (m, m, rad) after
    the update, before resampling; `weights` (K, N) normalised; `parents` (K, N) index into
    the previous step's particles; `resampled` (K,) bool."""

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
    `sensor_xy` (2,) where the lidar was (m), `pose` (3,) the robot's pose then (m, m, rad)."""

    points_xy: np.ndarray
    sensor_xy: np.ndarray
    pose: np.ndarray


# what reading a damaged or truncated .npz raises (zip, deflate, .npy header): turned into a DataError naming the file
_NPZ_ERRORS = (zipfile.BadZipFile, zlib.error, EOFError, ValueError, OSError, RuntimeError, NotImplementedError)


def read_logodds(path: Path) -> GridImage:
    """The one reader of `map_logodds.npz`: `data` (H, W) float32 log-odds, `resolution_m`
    (m), `origin_xy` (m) as a GridImage. A file without those arrays, or one that cannot be
    read, raises DataError naming it."""
    try:
        with np.load(path) as z:  # opened once for the place and the data
            res, origin = _logodds_place(z, path)
            try:
                data = np.asarray(z["data"], dtype=np.float32)
            except _NPZ_ERRORS as e:
                raise DataError(path, f"cannot be read ({e})", field="data") from None
    except _NPZ_ERRORS as e:
        raise DataError(path, f"cannot be read ({e})") from None
    return GridImage(data, res, origin)


def read_logodds_place(path: Path) -> tuple[float, tuple[float, float]]:
    """map_logodds.npz's (resolution_m, origin_xy), its `data` left unread; DataError naming
    the file when it lacks one of the three arrays or cannot be read."""
    try:
        with np.load(path) as z:
            return _logodds_place(z, path)
    except _NPZ_ERRORS as e:
        raise DataError(path, f"cannot be read ({e})") from None


def _logodds_place(z: Any, path: Path) -> tuple[float, tuple[float, float]]:
    """(resolution_m, origin_xy) of the open map_logodds.npz `z`, after checking it holds all three arrays."""
    need = ("data", "resolution_m", "origin_xy")
    missing = [name for name in need if name not in z]
    if missing:
        raise DataError(path, f"missing array(s) {', '.join(missing)} (need {', '.join(need)})")
    res = float(np.asarray(z["resolution_m"]).reshape(()))
    origin = np.asarray(z["origin_xy"], dtype=np.float64).reshape(2)
    return res, (float(origin[0]), float(origin[1]))


class LogOddsRows:
    """The `data` of a map_logodds.npz read a band of rows at a time from the file, for
    readers that reduce it (the report's map views): a building's map is ~200 MB of float32,
    its reduced views ~1 MB. `shape` (H, W) and `dtype` are the file's; `bands(r0, r1, rows)`
    gives the rows r0..r1 as float32 arrays of `rows` rows (the last may be shorter),
    decompressed as they are read. A file that no longer holds what it held when it was
    opened (a run replaced it), or cannot be read, raises DataError naming it."""

    def __init__(self, path: Path, shape: tuple[int, int], dtype: np.dtype) -> None:
        self.path = Path(path)
        self.shape = shape
        self.dtype = dtype

    def bands(self, r0: int, r1: int, rows: int) -> Iterator[np.ndarray]:
        w = self.shape[1]
        row_bytes = w * self.dtype.itemsize
        try:
            with zipfile.ZipFile(self.path) as z, z.open("data.npy") as f:
                shape, fortran, dtype = _npy_header(f)
                if tuple(shape) != self.shape or fortran or dtype != self.dtype:
                    raise DataError(self.path, f"changed while it was read: now {dtype} {shape}, was {self.dtype} {self.shape}", field="data")
                for r in range(0, r0, rows):  # the rows before r0, read and dropped
                    f.read(min(rows, r0 - r) * row_bytes)
                for r in range(r0, r1, rows):
                    n = min(rows, r1 - r)
                    buf = f.read(n * row_bytes)
                    if len(buf) != n * row_bytes:
                        raise DataError(self.path, f"ends after row {r + len(buf) // row_bytes} of {self.shape[0]}", field="data")
                    yield np.frombuffer(buf, dtype=self.dtype).reshape(n, w).astype(np.float32, copy=False)
        except _NPZ_ERRORS as e:
            raise DataError(self.path, f"cannot be read ({e})", field="data") from None


def _npy_header(f: Any) -> tuple[tuple[int, ...], bool, np.dtype]:
    """(shape, fortran_order, dtype) of the .npy stream `f`, read past its header."""
    version = np.lib.format.read_magic(f)
    read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
    return read(f)


def read_logodds_rows(path: Path) -> tuple[LogOddsRows | np.ndarray, float, tuple[float, float]]:
    """map_logodds.npz as (data, resolution_m, origin_xy), `data` a `LogOddsRows` (read band
    by band when used) when the file keeps it as a 2-D C-order float array; else the whole
    array (`read_logodds`, which raises DataError naming the file when it cannot be read)."""
    try:
        with zipfile.ZipFile(path) as z, z.open("data.npy") as f:
            shape, fortran, dtype = _npy_header(f)
    except (KeyError, *_NPZ_ERRORS):
        shape, fortran, dtype = (), True, np.dtype(object)  # not a plain npz member: read whole, or its error
    if fortran or len(shape) != 2 or dtype.kind != "f":
        whole = read_logodds(path)
        return whole.data, whole.resolution_m, whole.origin_xy
    res, origin = read_logodds_place(path)
    return LogOddsRows(path, (int(shape[0]), int(shape[1])), dtype), res, origin


def _read_record(path: Path, record: type) -> Any:
    """An .npz whose array names are `record`'s fields; None if the file is missing."""
    if not path.is_file():
        return None
    names = [f.name for f in fields(record)]
    with np.load(path) as z:
        missing = [n for n in names if n not in z]
        if missing:
            raise SlamlabError(f"{path}: missing array(s) {', '.join(missing)} (need {', '.join(names)})")
        return record(**{n: np.asarray(z[n]) for n in names})


def _read_json(path: Path) -> dict[str, Any] | None:
    """A JSON object, None if the file is missing (or holds no object); bad JSON raises."""
    if not path.is_file():
        return None
    try:
        with path.open(encoding="utf-8") as f:
            obj = json.load(f)
    except (OSError, json.JSONDecodeError) as exc:
        raise SlamlabError(f"{path}: not valid JSON ({exc})") from exc
    return obj if isinstance(obj, dict) else None


def read_yaml(path: Path) -> Any:
    """A YAML document, None if missing or unreadable (Hydra's records are best effort)."""
    import yaml

    if not path.is_file():
        return None
    try:
        with path.open(encoding="utf-8") as f:
            return yaml.safe_load(f)
    except (OSError, yaml.YAMLError):
        return None


@dataclass(frozen=True, slots=True)
class RunDirectory:
    """One run's folder: where each file is, and how the plain-data ones are read and written."""

    path: Path

    def __post_init__(self) -> None:
        object.__setattr__(self, "path", Path(self.path))

    # --- names ---------------------------------------------------------------------------
    def __truediv__(self, name: str) -> Path:
        return self.path / name

    def file(self, name: str) -> Path | None:
        """The path of an artifact if it exists, else None."""
        p = self.path / name
        return p if p.is_file() else None

    def trajectory_path(self, which: TrajectoryKind | str) -> Path:
        return self.path / TRAJECTORY_FILES[TrajectoryKind(which)]

    def texture_files(self, which: TrajectoryKind | str) -> TextureFiles:
        """The texture outputs along the SLAM or the odometry trajectory."""
        if TrajectoryKind(which) == TrajectoryKind.SLAM:
            names = (RunFile.TEXTURE, RunFile.TEXTURE_OVER_MAP, RunFile.FLOOR_CLOUD)
        elif TrajectoryKind(which) == TrajectoryKind.ODOMETRY:
            names = (RunFile.TEXTURE_ODOMETRY, RunFile.TEXTURE_ODOMETRY_OVER_MAP, RunFile.FLOOR_CLOUD_ODOMETRY)
        else:
            raise ValueError(f"no texture along the {which} trajectory")
        return TextureFiles(*(self.path / n for n in names))

    def holds_run(self) -> list[str]:
        """The run markers present (the claim file excepted): non-empty if a run owns the folder."""
        return [m for m in RUN_MARKERS if m != RunFile.CLAIM and (self.path / m).exists()]

    def is_run(self) -> bool:
        """A run directory has a metrics.json or Hydra's saved config."""
        return (self.path / RunFile.METRICS).is_file() or (self.path / RunFile.HYDRA_CONFIG).is_file()

    def claimed_by_this_process(self) -> bool:
        """True if the claim file names this process."""
        try:
            return (self.path / RunFile.CLAIM).read_text().strip() == str(os.getpid())
        except OSError:
            return False

    # --- writers -------------------------------------------------------------------------
    def write_metrics(self, metrics: RunMetrics) -> None:
        write_json(self.path / RunFile.METRICS, metrics.to_dict())

    def write_manifest(self, manifest: dict[str, Any]) -> None:
        write_json(self.path / RunFile.MANIFEST, manifest)

    def write_trajectory(self, which: TrajectoryKind | str, times: np.ndarray, poses: np.ndarray) -> None:
        """times (N,) s; poses (N, 3) x m, y m, yaw rad."""
        write_tum(self.trajectory_path(which), times, poses)

    # particles.npz and replay.npz at zlib level 1: the replay's map snapshots (4 MB on Intel) deflate in
    # 0.03 s instead of 0.11 s; Intel's replay.npz is 1.03 MB instead of 0.89 MB
    def write_particles(self, record: ParticleRecord) -> None:
        write_npz_fast(self.path / RunFile.PARTICLES, **{f.name: getattr(record, f.name) for f in fields(record)})

    def write_first_scan(self, scan: FirstScan) -> None:
        write_npz(self.path / RunFile.FIRST_SCAN, **{f.name: getattr(scan, f.name) for f in fields(scan)})

    def write_consistency_map(self, arrays: dict[str, np.ndarray]) -> None:
        """consistency_map.npz: the consistency replay's overlay layers (`slamlab.eval.consistency`)."""
        write_npz(self.path / RunFile.CONSISTENCY_MAP, **arrays)

    def write_replay(self, **arrays: np.ndarray) -> None:
        """replay.npz: the snapshot arrays of `slamlab.slam.replay` plus `scan_index`, `t`."""
        write_npz_fast(self.path / RunFile.REPLAY, **arrays)

    # --- readers -------------------------------------------------------------------------
    def read_metrics(self) -> RunMetrics | None:
        data = _read_json(self.path / RunFile.METRICS)
        return None if data is None else RunMetrics.from_dict(data)

    def read_manifest(self) -> dict[str, Any] | None:
        return _read_json(self.path / RunFile.MANIFEST)

    def read_config(self) -> Any:
        """Hydra's saved, composed config (.hydra/config.yaml) as plain data, or None."""
        return read_yaml(self.path / RunFile.HYDRA_CONFIG)

    def read_overrides(self) -> list[str]:
        """Hydra's saved task overrides (`key=value` strings); [] when none are recorded."""
        overrides = read_yaml(self.path / RunFile.HYDRA_OVERRIDES)
        return [str(o) for o in overrides] if isinstance(overrides, list) else []

    def read_choices(self) -> dict[str, str]:
        """The config group choices the run was composed with (Hydra's record,
        .hydra/hydra.yaml `hydra.runtime.choices`: e.g. {"filter": "rbpf", "experiment":
        "lidar2d"}; Hydra's own groups left out); {} when not recorded."""
        record = read_yaml(self.path / RunFile.HYDRA_RECORD)
        try:
            choices = record["hydra"]["runtime"]["choices"]
        except (TypeError, KeyError):
            return {}
        if not isinstance(choices, dict):
            return {}
        return {str(k): str(v) for k, v in choices.items() if not str(k).startswith("hydra/") and v is not None}

    def read_trajectory(self, which: TrajectoryKind | str) -> tuple[np.ndarray, np.ndarray] | None:
        """(times (N,) s, poses (N, 3) x m, y m, yaw rad); None if absent or empty."""
        path = self.trajectory_path(which)
        if not path.is_file():
            return None
        t, poses = read_tum(path)
        return None if t.size == 0 else (t, poses)

    def read_map(self) -> GridImage | None:
        """The log-odds grid (`read_logodds`), None if the run wrote none."""
        path = self.path / RunFile.MAP_LOGODDS
        return read_logodds(path) if path.is_file() else None

    def read_columns(self, name: RunFile) -> Table | None:
        """A CSV table of the run (steps.csv, relations.csv, consistency.csv) as NumPy columns
        (`io.table.read_csv`: no pandas; `Table.to_pandas` for a DataFrame), None if absent."""
        path = self.path / name
        return read_csv(path) if path.is_file() else None

    def read_particles(self) -> ParticleRecord | None:
        return _read_record(self.path / RunFile.PARTICLES, ParticleRecord)

    def read_first_scan(self) -> FirstScan | None:
        return _read_record(self.path / RunFile.FIRST_SCAN, FirstScan)

    def read_arrays(self, name: RunFile) -> dict[str, np.ndarray] | None:
        """Every array of an .npz (replay.npz, ground_frames.npz), None if absent."""
        path = self.path / name
        if not path.is_file():
            return None
        with np.load(path) as z:
            return {k: np.asarray(z[k]) for k in z.files}
