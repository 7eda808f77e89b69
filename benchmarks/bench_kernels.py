"""The RBPF's three kernels alone, on real inputs, timed in one process (issue 10).

    .venv/bin/python benchmarks/bench_kernels.py [--log intel] [--scans 4000] [--sample 12] [--repeat 15] [--threads 1]

Runs `+experiment=lidar2d` on the first `--scans` scans of a benchmark log in-process and
keeps a copy of the inputs of `--sample` calls, spread over the run, of each kernel:
- `search (steps)`: `tiled_match.tiled_field_search` at a filter step (every particle
  against its own map: coarse grid and hill climb);
- `search (between)`: the same kernel on the scans between two steps (`steps.between=match`);
- `map update`: `tiles.insert_scans` (every particle's ray cast and likelihood-field update).
Each kept call is then replayed `--repeat` times on fresh copies of its inputs, with
`--threads` numba threads, and its fastest time taken; the table gives the sum over the kept
calls of those minima (ms), and that per call times the number of calls in the run of
`--scans` scans (`run s`: the kernel's share of that run at that speed). `same` says
whether every replay wrote what the run's own call wrote, byte for byte (a kernel's result
depends only on its inputs).

Why this and not only `bench_speed.py`: on this shared 2-core machine whole runs spread by
10-20 % from one run to the next, more than most kernel changes move them; the fastest of
repeated calls on the same inputs spreads by a few percent. Run it in both checkouts of an
A/B, alternated, and quote both.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numba
import numpy as np
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate

from slamlab.assemble import build_components
from slamlab.paths import data_dir
from slamlab.slam import matcher as matcher_module
from slamlab.slam import tiles as tiles_module
from slamlab.slam.engine import run_slam

REPO = Path(__file__).resolve().parents[1]

# the arrays each kernel writes (replayed on fresh copies; compared with the run's own results)
SEARCH_OUT = (-6, -5, -4)  # out_poses, out_scores, out_evals: positions in tiled_field_search's arguments
UPDATE_OUT = (0, 1, 2, 4, 6, 8)  # table, pool_lo, pool_f, ref, released, used: what insert_scans writes


@dataclass
class Recorder:
    """Copies of the inputs and results of the calls numbered `keep` (1 = the first) of one kernel."""

    name: str
    keep: set[int]
    outputs: tuple[int, ...]
    calls: int = 0
    kept: list[tuple[tuple, list]] = field(default_factory=list)

    def wrap(self, kernel):
        def recorded(*args):
            self.calls += 1
            keep = self.calls in self.keep
            before = _copy(args) if keep else None
            result = kernel(*args)
            if keep:
                self.kept.append((before, [np.array(args[i], copy=True) for i in self.outputs]))
            return result
        return recorded


def _spread(calls: int, sample: int) -> set[int]:
    """`sample` call numbers spread evenly over 1..calls."""
    return {int(k) for k in np.linspace(1, calls, min(sample, calls)).round()} if calls else set()


def _same_layout_copy(a: np.ndarray) -> np.ndarray:
    """A copy with a's strides: numba compiles a kernel per array layout, so a slice of a
    larger buffer (the map update's scratch rows) must stay a non-contiguous array, or the
    replay would time another compiled version than the run's."""
    if a.flags.c_contiguous or a.ndim == 0 or min(a.strides) < 0:
        return np.array(a, copy=True)
    span = sum((n - 1) * st for n, st in zip(a.shape, a.strides)) // a.itemsize + 1
    out = np.lib.stride_tricks.as_strided(np.empty(span, dtype=a.dtype), a.shape, a.strides)
    out[...] = a
    return out


def _copy(args: tuple) -> tuple:
    return tuple(_same_layout_copy(a) if isinstance(a, np.ndarray) else a for a in args)


def _compose(overrides: list[str]):
    with initialize_config_dir(config_dir=str(REPO / "conf"), version_base=None):
        return compose(config_name="config", overrides=overrides)


def replay(kernel, rec: Recorder, repeat: int) -> tuple[float, bool]:
    """Sum over the kept calls of the fastest of `repeat` replays (s), and whether every replay
    wrote the run's results."""
    total = 0.0
    same = True
    for args, want in rec.kept:
        best = float("inf")
        for _ in range(repeat):
            fresh = _copy(args)
            t0 = time.perf_counter()
            kernel(*fresh)
            best = min(best, time.perf_counter() - t0)
            same &= all(fresh[i].tobytes() == w.tobytes() for i, w in zip(rec.outputs, want))
        total += best
    return total, same


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--log", default="intel", help="a CARMEN log of the shared data (intel, aces)")
    ap.add_argument("--scans", type=int, default=4000, help="the run's first scans")
    ap.add_argument("--sample", type=int, default=12, help="calls kept per kernel")
    ap.add_argument("--repeat", type=int, default=15, help="replays per kept call (the fastest counts)")
    ap.add_argument("--threads", type=int, default=1, help="numba threads for the replays")
    a = ap.parse_args()
    d = data_dir()
    if d is None:
        sys.exit("shared data not found: set SLAMLAB_DATA_DIR")
    cfg = _compose(["+experiment=lidar2d", f"dataset.path={d / 'carmen' / (a.log + '.clf.bz2')}", f"steps.max_scans={a.scans}"])
    seq = instantiate(cfg.dataset)
    search, update = matcher_module.tiled_field_search, tiles_module.insert_scans
    match_scans = matcher_module.LikelihoodFieldMatcher.match_scans
    between = [False]  # inside match_scans: the search is of the scans between two steps

    def flagged(self, *args, **kwargs):
        between[0] = True
        try:
            return match_scans(self, *args, **kwargs)
        finally:
            between[0] = False

    def run(on_search, on_update) -> None:
        matcher_module.tiled_field_search, tiles_module.insert_scans = on_search, on_update
        matcher_module.LikelihoodFieldMatcher.match_scans = flagged
        try:
            run_slam(seq, build_components(cfg))
        finally:
            matcher_module.tiled_field_search, tiles_module.insert_scans = search, update
            matcher_module.LikelihoodFieldMatcher.match_scans = match_scans

    # a first run loads the kernels and counts their calls
    counts = {"steps": 0, "between": 0, "update": 0}

    def count_search(*args):
        counts["between" if between[0] else "steps"] += 1
        return search(*args)

    def count_update(*args):
        counts["update"] += 1
        return update(*args)

    run(count_search, count_update)
    recs = {
        "steps": Recorder("search (steps)", _spread(counts["steps"], a.sample), SEARCH_OUT),
        "between": Recorder("search (between)", _spread(counts["between"], a.sample), SEARCH_OUT),
        "update": Recorder("map update", _spread(counts["update"], a.sample), UPDATE_OUT),
    }
    step_search, between_search = recs["steps"].wrap(search), recs["between"].wrap(search)
    run(lambda *args: (between_search if between[0] else step_search)(*args), recs["update"].wrap(update))

    numba.set_num_threads(a.threads)
    print(f"{a.log}, first {a.scans} scans of +experiment=lidar2d; {a.threads} thread(s), fastest of {a.repeat} replays per kept call")
    print(f"{'kernel':<18} {'run calls':>9} {'kept':>5} {'poses/call':>10} {'kept ms':>9} {'ms/call':>8} {'run s':>7}  same")
    for key, kernel in (("steps", search), ("between", search), ("update", update)):
        rec = recs[key]
        if not rec.kept:
            continue
        total, same = replay(kernel, rec, a.repeat)
        poses = np.mean([len(args[7] if key != "update" else args[9]) for args, _ in rec.kept])  # poses / particles updated
        per_call = total / len(rec.kept)
        print(f"{rec.name:<18} {counts[key]:>9} {len(rec.kept):>5} {poses:>10.1f} {total * 1e3:>9.1f} {per_call * 1e3:>8.2f} {per_call * counts[key]:>7.2f}  {'yes' if same else 'NO'}")


if __name__ == "__main__":
    main()
