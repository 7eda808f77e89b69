"""Write a run's artifacts: every file goes to a temporary name first and is renamed into
place when complete, so an interrupted run never leaves a half-written file behind.

File names and formats are a contract (docs/RUN_DIRECTORY.md).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from slamlab.frames import GridImage

# The writers live in slamlab.io (below datasets and texture, which use them too); they are
# re-exported so a run's files are written through one namespace.
from slamlab.io.atomic import TMP_MARK, atomic_path, remove_partials, write_bytes, write_json, write_npz, write_npz_fast, write_text  # noqa: F401
from slamlab.io.rundir import RunFile, read_logodds  # noqa: F401
from slamlab.io.table import Table
from slamlab.io.tum import read_tum, tum_text, write_tum  # noqa: F401

# ROS map_server thresholds on P(occupied).
OCCUPIED_THRESH = 0.65
FREE_THRESH = 0.196


def occupancy_probability(log_odds: np.ndarray) -> np.ndarray:
    """P(occupied) from log-odds."""
    return 1.0 / (1.0 + np.exp(-np.asarray(log_odds, dtype=np.float64)))


BAND_ROWS = 64  # map rows converted at a time: float64 temporaries of a whole building's map are GBs (256 rows
# of the Freiburg hospital's map: ~50 MB of them at once in its files phase)


def map_image_bands(log_odds: np.ndarray) -> Iterator[np.ndarray]:
    """The uint8 image in map_server colours (0 occupied, 254 free, 205 unknown), top row =
    highest y, a band of `BAND_ROWS` rows at a time from the top: map.pgm's pixel rows in file
    order without the whole image (41 MB on a building's map) in memory."""
    h = log_odds.shape[0]
    for hi in range(h, 0, -BAND_ROWS):
        lo = max(hi - BAND_ROWS, 0)
        p = occupancy_probability(log_odds[lo:hi])
        band = np.full(p.shape, 205, dtype=np.uint8)
        band[p > OCCUPIED_THRESH] = 0
        band[p < FREE_THRESH] = 254
        yield np.flipud(band)


def map_png_bands(log_odds: np.ndarray) -> Iterator[np.ndarray]:
    """map.png's (rows, W, 4) uint8 pixels a band of `BAND_ROWS` rows at a time, top row =
    highest y first: grey levels of 1 - P(occupied) (`grey_rgba`), so uncertain cells are
    visible. The whole RGBA image of a building's map is ~200 MB; a band is ~2 MB."""
    from slamlab.io.png import grey_rgba

    h = log_odds.shape[0]
    for hi in range(h, 0, -BAND_ROWS):
        lo = max(hi - BAND_ROWS, 0)
        yield grey_rgba(np.flipud(1.0 - occupancy_probability(log_odds[lo:hi])))


def write_map(run_dir: Path, grid: GridImage) -> None:
    """map.png (for people), map.pgm + map.yaml (ROS map_server), map_logodds.npz (raw)."""
    from concurrent.futures import ThreadPoolExecutor

    from slamlab.io.png import write_png_bands

    run_dir = Path(run_dir)
    # map.png is the long pole on a building's map (one zlib stream of seconds, its bytes fixed:
    # see below), so it starts at once; the npz's deflate and the PGM run beside it (zlib, the
    # PNG row filter and numpy's element-wise loops let go of the GIL)
    with ThreadPoolExecutor(max_workers=1) as pool:
        others = pool.submit(_write_map_raw_and_ros, run_dir, grid)
        # map.png: the bytes plt.imsave(cmap="gray", vmin=0, vmax=1) wrote before, a band of rows at a time
        h, w = grid.data.shape
        with atomic_path(run_dir / RunFile.MAP_PNG) as tmp:
            write_png_bands(tmp, w, h, map_png_bands(grid.data))
        others.result()  # its error, if any, is raised here


def _write_map_raw_and_ros(run_dir: Path, grid: GridImage) -> None:
    """map_logodds.npz (fast deflate: the arrays, not the zip's bytes, are what runs compare),
    then map.pgm + map.yaml."""
    write_npz_fast(
        run_dir / RunFile.MAP_LOGODDS,
        data=np.asarray(grid.data, dtype=np.float32),  # no copy of a float32 map
        resolution_m=np.float64(grid.resolution_m),
        origin_xy=np.asarray(grid.origin_xy, dtype=np.float64),
    )
    h, w = grid.data.shape
    with atomic_path(run_dir / RunFile.MAP_PGM) as tmp, open(tmp, "wb") as f:
        f.write(f"P5\n{w} {h}\n255\n".encode("ascii"))
        for band in map_image_bands(grid.data):  # a band of rows at a time, not the whole image
            f.write(np.ascontiguousarray(band).data)
    ox, oy = grid.origin_xy
    write_text(
        run_dir / RunFile.MAP_YAML,
        f"image: {RunFile.MAP_PGM}\n"
        f"resolution: {grid.resolution_m:.6f}\n"
        f"origin: [{ox:.6f}, {oy:.6f}, 0.0]\n"
        "negate: 0\n"
        f"occupied_thresh: {OCCUPIED_THRESH}\n"
        f"free_thresh: {FREE_THRESH}\n",
    )


def read_map(run_dir: Path) -> GridImage:
    """A run folder's map (`map_logodds.npz`, see `read_logodds`)."""
    return read_logodds(Path(run_dir) / RunFile.MAP_LOGODDS)


def write_consistency(run_dir: Path, series: dict[str, np.ndarray]) -> None:
    """consistency.csv: t (s), scan_index, hit_fraction, contradiction and
    contradiction_window of the scans the consistency replay scored (slamlab.eval.consistency)."""
    write_table(Path(run_dir) / RunFile.CONSISTENCY, Table(series))


# epoch times need microseconds, not the floats' significant digits
_TIME_FORMATS = {"t": ".6f", "t1": ".6f", "t2": ".6f", "t_anchor": ".6f"}


def write_table(path: Path, table: Table, float_format: str = "%.6g") -> None:
    """A CSV table; a `t*` column of epoch times keeps microseconds."""
    write_text(Path(path), table.to_csv(float_format, _TIME_FORMATS))


def write_steps(run_dir: Path, steps: Table) -> None:
    """steps.csv, the per-step table, with 9 significant digits (N_eff and weights read back
    as the engine had them to ~1e-9). Runs before 2026-11-27 also wrote the same table as
    steps.parquet: that loaded pyarrow and pandas, ~100 MB of the Intel run's 327 MB peak,
    for a table of a few thousand rows."""
    write_table(Path(run_dir) / RunFile.STEPS_CSV, steps, "%.9g")
