"""The particle-filter SLAM loop: predict, match + weigh, map, resample.

    run_slam(sequence, components) -> SlamResult

`components` are typed objects built once at the application edge from the config groups
(`slamlab.assemble.build_components`); the engine never sees a config dict.

Per processed step (see `steps.select_steps`):
1. predict: every particle moves by the odometry increment since the last step (+ noise,
   `motion/`);
2. update: each particle's scan is matched against the map (`matcher/`), optionally
   moving the particle to its best offset; the match score updates its weight
   (`weighting/`);
3. map (`map/`, `filter/`): `course` ray-casts the highest-weight particle's scan into one
   shared log-odds grid; `rbpf` ray-casts every particle's scan into its own map;
4. resample (`resampler/`) when N_eff = 1 / sum(w^2) < threshold * N (under `rbpf` the
   children share their parent's map tiles until they write).
Scans between two steps are not filtered: each gets its step's pose (+) the odometry since,
or (`steps.between=match`, mode slam) the motion since as matched against the best
particle's map right after step 3 (the map as it was then: causal; particles, weights and
maps are not changed).
Each particle's pose per step and its parent index are kept, so the final best particle's
own path (its ancestry) is the smoothed trajectory; the online (causal) estimate is, at each
step, the best particle or the particles' weighted mean (`filter.online`). `mode: odometry` skips 1, 2 and 4:
the map is built along the raw odometry (dead reckoning, for comparison). `mode: predict`
does 1 with noise for all N particles and skips 2 and 4 (weights stay uniform, nothing is
resampled): the prediction step of the course's preparation ladder; the map and the
trajectory are particle 0's, and the steps table gains the cloud's spread against the spread
the motion model's noise predicts (`spread.py`). `record.particles` keeps every particle's
pose and weight at every step for the report (`SlamResult.particle_history`).

One `numpy.random.Generator(PCG64(seed))` drives all randomness; the numba kernels either
run serial loops or (`rbpf`: per-particle matching and map updates) independent
per-particle iterations, so the same config and seed give a bit-identical trajectory
whatever the thread count.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import replace

import numba
import numpy as np

from slamlab.frames import Sequence
from slamlab.geometry import FloatArray, se2_between, se2_compose, weighted_mean_pose
from slamlab.io.table import Table
from slamlab.slam.odometry_scale import learn_scales, scaled_start
from slamlab.slam.plan import BetweenScans, Components, plan_steps
from slamlab.slam.replay import ReplayRecorder, snapshot_steps
from slamlab.slam.result import ParticleHistory, SlamResult
from slamlab.slam.scan import ScanBatch, beam_spacing_rad, points_to_world, project_scans, range_limits, scan_to_points
from slamlab.slam.spread import spread_columns
from slamlab.slam.steps import fill_between_steps
from slamlab.slam.tiles import decode_image
from slamlab.slam.weighting import effective_sample_size

log = logging.getLogger(__name__)


def ancestral_path(hist_poses: FloatArray, hist_parent: np.ndarray, last: int) -> FloatArray:
    """The path of particle `last` of the final step back through its ancestors.

    `hist_poses[k]` (n_steps, N, 3) are the particles at step k before resampling;
    `hist_parent[k, j]` is the index, in step k-1's set, of the particle that particle j
    of step k descends from. Returns (n_steps, 3)."""
    n_steps = hist_poses.shape[0]
    path = np.empty((n_steps, 3))
    j = int(last)
    for k in range(n_steps - 1, -1, -1):
        path[k] = hist_poses[k, j]
        j = int(hist_parent[k, j])
    return path


def run_slam(
    sequence: Sequence,
    c: Components,
    progress: Callable[[int, int], None] | None = None,
) -> SlamResult:
    """Run the filter (or dead reckoning, `mode: odometry`) over `sequence`.

    `progress(scans_done, scans_total)` is called after every processed step (scans between
    steps count as done: the progress bar shows scans, the log's unit); when it returns
    True the run stops there and returns the scans up to that step (Ctrl-C keeps a partial run).
    Returns one pose per scan (the first `steps.max_scans` scans when set; with
    `steps.max_steps`, the scans up to the last processed step)."""
    # the matcher's prior weighed for this lidar's beam density (matcher.prior_beam_deg)
    c = replace(c, matcher=c.matcher.for_beam_spacing(beam_spacing_rad(sequence)))
    # The kernels' parallel loops go to the threads one particle (or scan) at a time, not in
    # one block per thread: particles' searches and map updates differ in cost, and on the TBB
    # layer (slamlab/__init__.py) a thread that is done takes the next one. Intel's filter,
    # six alternated pairs: faster in five, by 0.6-1.7 s of 8-10 s (slower by 0.3 s in one);
    # ACES and the default sim run within their noise. OpenMP splits the loop in fixed blocks
    # whatever this says. Results do not depend on it.
    with numba.parallel_chunksize(1):
        if c.mode == "slam" and c.filter.family == "graph":  # one trajectory, its own loop
            from slamlab.slam.graph.run import run_graph

            return run_graph(sequence, c, progress)
        return _run_filter(sequence, c, progress)


def _run_filter(sequence: Sequence, c: Components, progress: Callable[[int, int], None] | None) -> SlamResult:
    """`run_slam`'s work."""
    plan = plan_steps(sequence, c)
    scans, times, odom, step_scans = plan.scans, plan.times, plan.odometry, plan.step_scans
    n_steps = len(step_scans)
    slam = c.mode == "slam"
    n = 1 if c.mode == "odometry" else c.particles

    ms = c.map
    min_r, max_r = range_limits(ms, sequence)
    start = odom[step_scans[0]].copy()
    maps = c.filter.maps(ms, n, (start[0], start[1]), c.matcher if slam else None)
    rng = np.random.Generator(np.random.PCG64(c.seed))

    poses = np.tile(start, (n, 1))
    # per-particle odometry scale (`odometry_scale.py`); None when the motion model learns none
    scales = np.ones(n) if slam and c.motion.scale_gain_per_m > 0 else None
    logw = np.full(n, -np.log(n))
    hist_poses = np.empty((n_steps, n, 3))
    hist_parent = np.empty((n_steps, n), dtype=np.int32)
    hist_w = np.empty((n_steps, n)) if c.record_particles else None
    parent = np.arange(n, dtype=np.int32)
    replay = ReplayRecorder(snapshot_steps(n_steps)) if c.record_replay else None
    causal = np.empty((n_steps, 3))
    rows: dict[str, list] = {k: [] for k in ("neff", "resampled", "best_weight", "step_time_s")}
    resample_count = 0
    # steps.between=match: the matched motion of each scan between steps from its step (NaN: none)
    between = np.full((len(scans), 3), np.nan) if slam and c.between == "match" else None

    def project(a: int, b: int) -> ScanBatch:
        return project_scans(scans, a, b, sequence.body_height_m, min_r, max_r, ms.ground_threshold_m)

    between_scans = BetweenScans(step_scans, len(scans), project, lambda batch: maps.prepare_scans(c.matcher, batch))  # used when `between`
    t_loop = time.perf_counter()
    for k, si in enumerate(step_scans):
        t0 = time.perf_counter()
        frame = scans[si]
        pts = scan_to_points(frame, sequence.body_height_m, min_r, max_r, ms.ground_threshold_m)
        if k > 0:
            inc = se2_between(odom[step_scans[k - 1]], odom[si])
            if slam:
                before = poses
                if scales is not None:
                    poses = scaled_start(poses, scales, inc)
                poses = c.motion.sample(poses, inc, rng)
                if len(pts.xy):
                    poses, scores = maps.match(c.matcher, poses, pts, c.filter.step_scale(inc))
                    logw = c.weighting.update(logw, scores)
                    if scales is not None:  # only a match says where the particle really went
                        scales = learn_scales(scales, before, poses, inc, c.motion.scale_gain_per_m)
            elif c.mode == "predict":
                poses = c.motion.sample(poses, inc, rng)
            else:
                poses = se2_compose(poses, inc)
        w = np.exp(logw)
        best = int(np.argmax(w))
        if scales is not None:  # the best particle's, before resampling renumbers them
            rows.setdefault("odometry_scale", []).append(float(scales[best]))
        hist_poses[k] = poses
        hist_parent[k] = parent
        causal[k] = weighted_mean_pose(poses, w) if c.filter.online == "mean" else poses[best]
        if hist_w is not None:
            hist_w[k] = w
        if k == 0:  # the first map is this scan alone, seen from the start pose
            first_scan = (points_to_world(pts.xy, poses[best]), points_to_world(pts.origin.reshape(1, 2), poses[best])[0])
        maps.update(poses, pts, best)
        if between is not None:
            # the scans up to the next step, matched against the best particle's map as it is
            # now (causal): each scan's pose is its step's (+) the matched motion since
            js, pts_between = between_scans.of_step(k)
            if len(js):
                since = se2_between(odom[si], odom[js])
                if scales is not None:  # the best particle's learnt odometry scale, as its steps use
                    since[:, :2] *= scales[best]
                pred = se2_compose(poses[best], since)
                matched = maps.match_scans(c.matcher, best, pred, pts_between)
                between[js] = se2_between(poses[best], matched)
        last = k == n_steps - 1
        want_snapshot = replay is not None and replay.wants(k)
        if last:
            final_map = maps.image(best)  # before a resample renumbers the particles' maps
        if want_snapshot:
            replay.add(k, poses, best, points_to_world(pts.xy, poses[best]), maps.snapshot(best))
        neff = effective_sample_size(w)
        resampled = False
        if slam and n > 1 and c.resampler.should_resample(w):
            idx = c.resampler.indices(w, rng)
            poses = poses[idx]
            if scales is not None:
                scales = scales[idx]
            maps.resample(idx)
            parent = idx.astype(np.int32)
            logw = np.full(n, -np.log(n))
            resampled = True
            resample_count += 1
        else:
            parent = np.arange(n, dtype=np.int32)
        rows["neff"].append(neff)
        rows["resampled"].append(resampled)
        rows["best_weight"].append(float(w[best]))
        step_s = time.perf_counter() - t0
        if between is not None:  # a chunk's preparation shared among the steps it serves
            step_s += between_scans.share_s - between_scans.spent_s
        rows["step_time_s"].append(step_s)
        if progress is not None and progress(len(scans) if k == n_steps - 1 else int(si) + 1, len(scans)):
            if k < n_steps - 1:  # asked to stop (Ctrl-C): the result of a run that ended here
                survivors = np.flatnonzero(parent == best) if resampled else [best]
                final_map = maps.image(int(survivors[0]) if len(survivors) else 0)
                n_steps, step_scans = k + 1, step_scans[: k + 1]
                hist_poses, hist_parent, causal = hist_poses[:n_steps], hist_parent[:n_steps], causal[:n_steps]
                hist_w = None if hist_w is None else hist_w[:n_steps]
                scans, times, odom = scans[: si + 1], times[: si + 1], odom[: si + 1]
            break
    runtime = time.perf_counter() - t_loop
    map_memory = maps.memory()
    unit = maps.unit
    del maps  # the particles' maps (tens of MB for the RBPF) go before the outputs are made
    final_map = decode_image(final_map, unit)  # float32 log-odds once the maps are gone

    # `best` indexes the last step's particles before resampling (the set hist_poses[-1]
    # holds); after a resample the weights are uniform and no longer say who was best.
    smooth = ancestral_path(hist_poses, hist_parent, best)
    if between is not None:
        between = between[: len(odom)]  # a run stopped early keeps its scans up to the stop

    steps = Table(
        {
            "step": np.arange(n_steps),
            "scan_index": np.array([scans[i].index for i in step_scans], dtype=np.int64),
            "t": times[step_scans],
            **rows,
            **(spread_columns(hist_poses, odom[step_scans], c.motion) if c.mode == "predict" else {}),
        }
    )
    underflows = int(getattr(c.weighting, "underflows", 0))
    overflows = int(getattr(c.weighting, "overflows", 0))
    if underflows or overflows:
        log.warning("weighting underflowed %d and overflowed %d times (uniform fallback used)", underflows, overflows)
    return SlamResult(
        times=times,
        trajectory=fill_between_steps(step_scans, smooth, odom, between),
        causal=fill_between_steps(step_scans, causal, odom, between),
        odometry=se2_compose(start, se2_between(odom[step_scans[0]], odom)),
        log_odds=final_map,
        steps=steps,
        particles=n,
        resample_count=resample_count,
        runtime_s=runtime,
        fill="odometry" if between is None else "match",
        particle_history=None if hist_w is None else ParticleHistory(hist_poses, hist_w, hist_parent, steps["resampled"].astype(bool)),
        first_scan_xy=first_scan[0],
        first_scan_origin=first_scan[1],
        replay=None if replay is None else replay.arrays(),
        extras={
            "mode": c.mode,
            "processed_steps": n_steps,
            "step_scans": step_scans,
            "weighting_underflows": underflows,
            "weighting_overflows": overflows,
            "neff_mean": float(np.mean(rows["neff"])),
            "neff_min": float(np.min(rows["neff"])),
            "filter": c.filter.name,
            "odometry_jumps": plan.jumps_up_to(len(odom)),
            "thin_scans": plan.thin_up_to(n_steps),
            **({} if scales is None else {"odometry_scale": rows["odometry_scale"][-1]}),
            "matcher_map_reads": int(c.matcher.map_reads) if slam else 0,
            **map_memory,
        },
    )
