"""Write a run's artifacts: every file goes to a temporary name first and is renamed into
place when complete, so an interrupted run never leaves a half-written file behind.

File names and formats are a contract (docs/RUN_DIRECTORY.md).
"""

from __future__ import annotations

import io
import json
import os
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pandas as pd

from slamlab.errors import DataError
from slamlab.frames import GridImage
from slamlab.geometry import FloatArray, wrap_angle, yaw_to_quaternion

TMP_MARK = ".partial-"

# ROS map_server thresholds on P(occupied).
OCCUPIED_THRESH = 0.65
FREE_THRESH = 0.196


@contextmanager
def atomic_path(path: Path) -> Iterator[Path]:
    """Yield a temporary path beside `path`; rename it to `path` only if the block succeeds."""
    path = Path(path)
    tmp = path.with_name(f"{TMP_MARK}{os.getpid()}-{path.name}")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def write_bytes(path: Path, data: bytes) -> None:
    """Atomically write bytes."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def write_text(path: Path, text: str) -> None:
    """Atomically write UTF-8 text."""
    write_bytes(path, text.encode("utf-8"))


def write_json(path: Path, obj: object) -> None:
    """Atomically write pretty JSON (NaN written as null so every JSON reader accepts it)."""
    write_text(path, json.dumps(_json_safe(obj), indent=2, sort_keys=False) + "\n")


def _json_safe(obj: object) -> object:
    if isinstance(obj, dict):
        return {str(k): _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_json_safe(v) for v in obj]
    if isinstance(obj, (np.floating, float)):
        f = float(obj)
        return f if np.isfinite(f) else None
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, np.ndarray):
        return _json_safe(obj.tolist())
    return obj


def remove_partials(run_dir: Path) -> None:
    """Delete temporary files a killed process may have left (only this run's folder)."""
    for p in Path(run_dir).glob(f"{TMP_MARK}*"):
        p.unlink(missing_ok=True)


def tum_text(times: FloatArray, poses: FloatArray) -> str:
    """TUM trajectory text: `timestamp x y z qx qy qz qw` per line (s, m, unit quaternion).

    Fixed formatting (%.6f time, %.9f values) so identical arrays give identical bytes.
    """
    times = np.asarray(times, dtype=np.float64)
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    q = yaw_to_quaternion(poses[:, 2])
    table = np.column_stack([times, poses[:, 0], poses[:, 1], np.zeros(len(times)), q])
    buf = io.StringIO()
    buf.write("# timestamp x y z qx qy qz qw\n")
    np.savetxt(buf, table, fmt=["%.6f"] + ["%.9f"] * 7)
    return buf.getvalue()


def write_tum(path: Path, times: FloatArray, poses: FloatArray) -> None:
    """Atomically write a planar trajectory in TUM format."""
    write_text(path, tum_text(times, poses))


def read_tum(path: Path) -> tuple[FloatArray, FloatArray]:
    """Read a planar TUM file: (times (N,), poses (N, 3) x, y, yaw), yaw from the
    quaternion's rotation about z. A file that is not TUM raises DataError naming it."""
    try:
        with warnings.catch_warnings():  # an empty file is an empty trajectory, not a warning
            warnings.simplefilter("ignore", UserWarning)
            table = np.loadtxt(path, comments="#", ndmin=2, dtype=np.float64)
    except (OSError, ValueError) as exc:
        raise DataError(path, f"cannot read TUM trajectory ({exc})") from None
    if table.size == 0:
        return np.zeros(0), np.zeros((0, 3))
    if table.shape[1] != 8:
        raise DataError(path, f"expected 8 columns 'timestamp x y z qx qy qz qw', got {table.shape[1]}")
    qx, qy, qz, qw = table[:, 4], table[:, 5], table[:, 6], table[:, 7]
    yaw = np.arctan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
    return table[:, 0], np.column_stack([table[:, 1], table[:, 2], wrap_angle(yaw)])


def occupancy_probability(log_odds: np.ndarray) -> np.ndarray:
    """P(occupied) from log-odds."""
    return 1.0 / (1.0 + np.exp(-np.asarray(log_odds, dtype=np.float64)))


def map_image(log_odds: np.ndarray) -> np.ndarray:
    """uint8 image in map_server colours, top row = highest y: 0 occupied, 254 free, 205 unknown."""
    p = occupancy_probability(log_odds)
    img = np.full(p.shape, 205, dtype=np.uint8)
    img[p > OCCUPIED_THRESH] = 0
    img[p < FREE_THRESH] = 254
    return np.flipud(img)


def write_map(run_dir: Path, grid: GridImage) -> None:
    """map.png (for people), map.pgm + map.yaml (ROS map_server), map_logodds.npz (raw)."""
    import matplotlib.pyplot as plt

    run_dir = Path(run_dir)
    img = map_image(grid.data)
    # map.png: grey levels from the probability itself so uncertain cells are visible.
    shade = np.flipud(1.0 - occupancy_probability(grid.data))
    with atomic_path(run_dir / "map.png") as tmp:
        plt.imsave(tmp, shade, cmap="gray", vmin=0.0, vmax=1.0, format="png")
    h, w = img.shape
    write_bytes(run_dir / "map.pgm", f"P5\n{w} {h}\n255\n".encode("ascii") + img.tobytes())
    ox, oy = grid.origin_xy
    write_text(
        run_dir / "map.yaml",
        "image: map.pgm\n"
        f"resolution: {grid.resolution_m:.6f}\n"
        f"origin: [{ox:.6f}, {oy:.6f}, 0.0]\n"
        "negate: 0\n"
        f"occupied_thresh: {OCCUPIED_THRESH}\n"
        f"free_thresh: {FREE_THRESH}\n",
    )
    write_npz(
        run_dir / "map_logodds.npz",
        data=grid.data.astype(np.float32),
        resolution_m=np.float64(grid.resolution_m),
        origin_xy=np.asarray(grid.origin_xy, dtype=np.float64),
    )


def read_map(run_dir: Path) -> GridImage:
    """Load `map_logodds.npz` back into a GridImage."""
    with np.load(Path(run_dir) / "map_logodds.npz") as z:
        return GridImage(z["data"], float(z["resolution_m"]), tuple(float(v) for v in z["origin_xy"]))


def write_consistency(run_dir: Path, series: dict[str, np.ndarray]) -> None:
    """consistency.csv: t (s), scan_index, hit_fraction of the scans the consistency score
    replayed (slamlab.eval.consistency)."""
    write_table(Path(run_dir) / "consistency.csv", pd.DataFrame(series))


def write_table(path: Path, table: pd.DataFrame) -> None:
    """A CSV table; a `t*` column of epoch times keeps microseconds."""
    table = table.copy()
    for col in table.columns:
        if col in ("t", "t1", "t2"):
            table[col] = table[col].map(lambda v: f"{v:.6f}")
    write_text(Path(path), table.to_csv(index=False, float_format="%.6g"))


def write_npz(path: Path, **arrays: np.ndarray) -> None:
    """Atomically write compressed NumPy arrays (np.load reads them back by name)."""
    with atomic_path(path) as tmp:
        with tmp.open("wb") as f:
            np.savez_compressed(f, **arrays)


def write_steps(run_dir: Path, steps: pd.DataFrame) -> None:
    """steps.csv (people, spreadsheets) and steps.parquet (typed, fast)."""
    run_dir = Path(run_dir)
    table = steps.copy()
    if "t" in table:  # epoch times need microseconds, not 9 significant digits
        table["t"] = table["t"].map(lambda v: f"{v:.6f}")
    write_text(run_dir / "steps.csv", table.to_csv(index=False, float_format="%.9g"))
    with atomic_path(run_dir / "steps.parquet") as tmp:
        steps.to_parquet(tmp, index=False)
