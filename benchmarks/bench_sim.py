"""Simulator speed: time to generate the default simulated sequence (dataset=sim) and to
read it back through load_thor, with its size. Prints a table.

    .venv/bin/python benchmarks/bench_sim.py [--seed 0] [--duration-s 85] [--kinect-scale 0.25]

Generates into a temporary folder (not the user's cache), removed afterwards.
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from pathlib import Path

from slamlab.datasets.sim import SimParams, generate_atomic, read_sim_folder


def main() -> None:
    defaults = SimParams()
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seed", type=int, default=defaults.seed)
    ap.add_argument("--duration-s", type=float, default=defaults.duration_s)
    ap.add_argument("--kinect-scale", type=float, default=defaults.kinect_scale)
    args = ap.parse_args()
    params = SimParams(seed=args.seed, duration_s=args.duration_s, kinect_scale=args.kinect_scale)

    # warm-up: loads (or compiles once, then caches) the numba kernels, so the table shows
    # the steady-state cost a sweep pays per sequence; the first-ever run pays ~5 s more.
    tmp = Path(tempfile.mkdtemp(prefix="slamlab-bench-sim-"))
    try:
        t0 = time.perf_counter()
        generate_atomic(tmp / "warm", SimParams(duration_s=1.0, kinect_scale=0.05))
        warm = time.perf_counter() - t0

        t0, c0 = time.perf_counter(), time.process_time()
        folder = generate_atomic(tmp / "seq", params)
        t_gen, c_gen = time.perf_counter() - t0, time.process_time() - c0
        t0 = time.perf_counter()
        seq = read_sim_folder(folder)
        t_read = time.perf_counter() - t0
        t0 = time.perf_counter()
        n_rgbd = sum(1 for _ in seq.rgbd()) if seq.rgbd else 0
        t_rgbd = time.perf_counter() - t0

        sizes = {p.name: p.stat().st_size for p in sorted(folder.glob("*.mat"))}
        sizes["truth/"] = sum(p.stat().st_size for p in (folder / "truth").iterdir())
        total = sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())
        ir, rgb = seq.calibration.ir, seq.calibration.rgb
        rows = [
            ("sequence", f"seed {params.seed}, {params.duration_s:g} s, kinect_scale {params.kinect_scale:g}"),
            ("scans (40 Hz x 1081 beams)", f"{len(seq)}"),
            ("RGB-D frames", f"{n_rgbd} (depth {ir.width}x{ir.height}, colour {rgb.width}x{rgb.height})"),
            ("kernel warm-up (1 s sequence)", f"{warm:.2f} s"),
            ("generate (write all files)", f"{t_gen:.2f} s wall, {c_gen:.2f} s CPU (all threads)"),
            ("read back: load_thor + ground truth", f"{t_read:.2f} s"),
            ("stream all RGB-D frames", f"{t_rgbd:.2f} s"),
        ]
        rows += [(f"size {name}", f"{b / 1e6:.1f} MB") for name, b in sizes.items()]
        rows.append(("size total", f"{total / 1e6:.1f} MB"))
        # the machine's load: wall times on a busy shared machine are not the simulator's
        rows.append(("load average (1 min) / CPUs", f"{os.getloadavg()[0]:.1f} / {os.cpu_count()}"))
        w = max(len(k) for k, _ in rows)
        print(f"| {'bench_sim'.ljust(w)} | value |\n| {'-' * w} | ----- |")
        for k, v in rows:
            print(f"| {k.ljust(w)} | {v} |")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
