"""How fast the CARMEN reader loads the benchmark logs (Intel, ACES).

Run: `.venv/bin/python benchmarks/bench_read_carmen.py [--repeat 3]`. Prints one row per log:
median wall time (s) of `load_carmen` over the repeats, scans, scans/s, and the raw-odometry
relation error as a sanity check that what was read is right.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import pandas as pd

from slamlab.datasets.carmen import load_carmen
from slamlab.eval.relations import relation_errors
from slamlab.paths import data_dir

LOGS = ("intel.clf.bz2", "aces.clf.bz2")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3, help="loads per log; the median is reported")
    args = parser.parse_args(argv)

    root = data_dir()
    if root is None or not (root / "carmen").is_dir():
        print("shared data not found: set SLAMLAB_DATA_DIR to the folder holding carmen/", file=sys.stderr)
        return 2

    rows = []
    for log in LOGS:
        path = root / "carmen" / log
        times = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            seq = load_carmen(path)
            times.append(time.perf_counter() - t0)
        med = statistics.median(times)
        row = {"log": log, "read_s (median)": med, "scans": len(seq), "scans/s": len(seq) / med}
        if seq.relations is not None:
            e = relation_errors(seq.times, seq.odometry, seq.relations)
            row["odom rel. error m"] = f"{e['trans_abs_mean_m']:.3f} +- {e['trans_abs_std_m']:.3f}"
        rows.append(row)
    table = pd.DataFrame(rows)
    print(table.to_string(index=False, formatters={"read_s (median)": "{:.3f}".format, "scans/s": "{:,.0f}".format}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
