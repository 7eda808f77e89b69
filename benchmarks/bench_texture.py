"""Texture mapping speed at full Kinect v2 resolution (512x424 depth, 1920x1080 colour).

Renders a few frames of a textured floor with a wall with the simulator's Kinect renderer
(tests/synthetic_rgbd.py; real THOR calibration numbers when ../shared/data is present, the
images an ideal pinhole's, the back-projection still undistorting with the real lens), then streams copies of them
through `run_texture` once per ground detector and prints the median per-frame time (depth to
accumulated colour, detector included, evaluation excluded) and peak memory. Memory is
measured with tracemalloc over the run for a short and a 4x longer stream: equal peaks mean
memory does not grow with the sequence length.

    .venv/bin/python benchmarks/bench_texture.py [--frames 4] [--repeat 3]
"""

from __future__ import annotations

import argparse
import dataclasses
import resource
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

from slamlab.datasets.sim.calib import default_calibration
from slamlab.frames import GridImage
from slamlab.paths import data_dir
from slamlab.config import SCHEMAS
from slamlab.config.texture import TextureConfig
from slamlab.texture.pipeline import run_texture

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))  # the test frames' renderer (test support, not the library)
from synthetic_rgbd import synthetic_sequence  # noqa: E402

CONF = ROOT / "slamlab" / "conf"
DETECTORS = ("threshold", "plane", "image_plane")


def _calibration():
    d = data_dir()
    if d is not None and (d / "thor" / "cameraParam").is_dir():
        from slamlab.datasets.calibration import load_kinect_calibration

        return load_kinect_calibration(d / "thor" / "cameraParam"), "real (with lens distortion)"
    return default_calibration(), "built-in THOR numbers (no distortion)"


def _stream(seq, copies: int):
    """Fresh copies of the frames, like a reader decoding them one at a time."""
    frames = list(seq.rgbd())

    def gen():
        k = 0
        for _ in range(copies):
            for f in frames:
                yield dataclasses.replace(f, index=k, depth_m=f.depth_m.copy(), rgb=f.rgb.copy())
                k += 1

    return gen


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=4, help="distinct full-resolution frames to render")
    ap.add_argument("--repeat", type=int, default=3, help="times each frame is streamed per detector")
    args = ap.parse_args()

    calib, calib_note = _calibration()
    n = args.frames
    poses = np.column_stack([0.3 * np.arange(n), 0.1 * np.arange(n), 0.15 * np.arange(n)])
    t0 = time.perf_counter()
    seq = synthetic_sequence(calib, poses, head_pitch_rad=0.6, wall_x_m=3.0, noise_mm=2.0)
    render_s = time.perf_counter() - t0
    seq = dataclasses.replace(seq, ground_truth=None)  # timing only: no evaluation work
    grid = GridImage(np.zeros((300, 300), dtype=np.float32), 0.05, (-5.0, -7.5))
    times = np.arange(n * args.repeat, dtype=np.float64)
    tpl = np.tile(poses, (args.repeat, 1))
    tcfg = TextureConfig(evaluate_detectors=[])

    print(f"Kinect {calib.ir.width}x{calib.ir.height} depth, {calib.rgb.width}x{calib.rgb.height} colour; calibration: {calib_note}")
    print(f"{n} frames rendered in {render_s:.1f} s, each streamed {args.repeat}x per detector\n")
    print(f"{'detector':<12} {'stride':>6} {'points/frame':>12} {'median ms':>10} {'p90 ms':>8} {'detector ms':>12} {'floor pts/frame':>15}")
    for name in DETECTORS:
        ground = SCHEMAS["ground"][name]()
        for stride in (1, 2):
            tcfg.stride = stride
            s = dataclasses.replace(seq, rgbd=_stream(seq, args.repeat), rgbd_count=n * args.repeat)
            run_texture(dataclasses.replace(s, rgbd=_stream(seq, 1)), times, tpl, grid, ground, tcfg)  # warm-up (numba, tables)
            res = run_texture(s, times, tpl, grid, ground, tcfg)
            ft = res.frame_time_s * 1e3
            valid_pts = int(np.count_nonzero(seq.rgbd().__next__().depth_m[::stride, ::stride] > 0))
            print(
                f"{name:<12} {stride:>6} {valid_pts:>12} {np.median(ft):>10.1f} {np.percentile(ft, 90):>8.1f} "
                f"{np.median(res.detect_time_s) * 1e3:>12.2f} {res.points_added / max(res.frames_used, 1):>15.0f}"
            )

    # Memory: peak of traced allocations during a run, short vs 4x longer stream.
    tcfg.stride = 1
    ground = SCHEMAS["ground"]["threshold"]()
    peaks = []
    for copies in (1, 4):
        s = dataclasses.replace(seq, rgbd=_stream(seq, copies), rgbd_count=n * copies)
        tt = np.arange(n * copies, dtype=np.float64)
        tracemalloc.start()
        run_texture(s, tt, np.tile(poses, (copies, 1)), grid, ground, tcfg)
        peaks.append(tracemalloc.get_traced_memory()[1] / 2**20)
        tracemalloc.stop()
    frame_mb = (seq.rgbd().__next__().rgb.nbytes + seq.rgbd().__next__().depth_m.nbytes) / 2**20
    print(
        f"\npeak traced memory during run_texture: {peaks[0]:.1f} MB for {n} frames, {peaks[1]:.1f} MB for {4 * n} frames "
        f"(one frame = {frame_mb:.1f} MB; grid {grid.data.shape[0]}x{grid.data.shape[1]})"
    )
    print(f"process peak RSS (incl. rendering and Open3D): {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")


if __name__ == "__main__":
    main()
