"""Reading the Intel log as a CARMEN log vs as ROS bags (ROS 1, ROS 2 sqlite3, ROS 2 mcap).

Run: `.venv/bin/python benchmarks/bench_read_rosbag.py [--repeat 3] [--keep DIR]`. Writes the
whole Intel log as bags into a temporary folder (or DIR) with `slamlab.datasets.rosbag_write`,
then prints one row per file: its size, the median wall time (s) of reading it into a
`Sequence` over the repeats, scans/s, and the raw-odometry relation error (the same for every
row when every reader read the same poses at the same times).
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import pandas as pd

from slamlab.datasets.carmen import load_carmen
from slamlab.datasets.rosbag import load_rosbag
from slamlab.datasets.rosbag_write import write_rosbag
from slamlab.eval.relations import relation_errors
from slamlab.frames import Sequence
from slamlab.paths import data_dir

BAGS = (  # (label, file name, ros, storage, odometry)
    ("ROS 1 .bag, Odometry", "intel.bag", 1, "sqlite3", "odom"),
    ("ROS 1 .bag, /tf", "intel_tf.bag", 1, "sqlite3", "tf"),
    ("ROS 2 sqlite3, Odometry", "intel_sqlite3", 2, "sqlite3", "odom"),
    ("ROS 2 mcap, Odometry", "intel_mcap", 2, "mcap", "odom"),
)


def size_mb(path: Path) -> float:
    files = [path] if path.is_file() else [p for p in path.rglob("*") if p.is_file()]
    return sum(p.stat().st_size for p in files) / 1e6


def timed(load: Callable[[], Sequence], repeat: int) -> tuple[float, Sequence]:
    """Median wall time (s) of `load()` and the last sequence it returned."""
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        seq = load()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), seq


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3, help="reads per file; the median is reported")
    parser.add_argument("--keep", type=Path, default=None, help="write the bags here and keep them")
    args = parser.parse_args(argv)

    root = data_dir()
    if root is None or not (root / "carmen").is_dir():
        print("shared data not found: set SLAMLAB_DATA_DIR to the folder holding carmen/", file=sys.stderr)
        return 2
    log = root / "carmen" / "intel.clf.bz2"
    relations = root / "carmen" / "intel.relations"
    out = args.keep or Path(tempfile.mkdtemp(prefix="slamlab-bags-"))
    out.mkdir(parents=True, exist_ok=True)
    try:
        rows = []
        read_s, seq = timed(lambda: load_carmen(log), args.repeat)
        rows.append(("CARMEN .clf.bz2", log, read_s, seq))
        for label, name, ros, storage, odometry in BAGS:
            bag = out / name
            if not bag.exists():
                write_rosbag(seq, bag, ros=ros, storage=storage, odometry=odometry)
            read_s, bag_seq = timed(lambda bag=bag: load_rosbag(bag, relations=relations), args.repeat)
            rows.append((label, bag, read_s, bag_seq))
        table = []
        for label, path, read_s, s in rows:
            e = relation_errors(s.times, s.odometry, s.relations)
            table.append({"file": label, "MB": size_mb(path), "read_s (median)": read_s, "scans": len(s),
                          "scans/s": len(s) / read_s, "odom rel. error m": f"{e['trans_abs_mean_m']:.4f}"})  # fmt: skip
        print(pd.DataFrame(table).to_string(index=False, formatters={
            "MB": "{:.1f}".format, "read_s (median)": "{:.2f}".format, "scans/s": "{:,.0f}".format}))  # fmt: skip
    finally:
        if args.keep is None:
            shutil.rmtree(out, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
