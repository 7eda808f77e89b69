"""One run, start to finish: load -> SLAM -> evaluate -> texture -> artifacts.

The Hydra app (`slamlab.cli.app`) only resolves the config and the run directory and
calls `run_pipeline`, then writes the run's report (the report layer sits above this one:
`slamlab.cli.app.run_and_report`); tests call either directly with a composed config.
"""

from __future__ import annotations

import logging
import math
import os
import sys
import time
import traceback
import warnings
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor, wait
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from hydra.errors import InstantiationException
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

from slamlab import artifacts
from slamlab.datasets.stamps import repeated_stamps
from slamlab.errors import ConfigError, DataError, SlamlabError
from slamlab.frames import Relations, Sequence
from slamlab.interrupt import RunInterrupted, StopOnSigint
from slamlab.io.atomic import DiskFullError
from slamlab.io.run_metrics import STATUS_FAILED, STATUS_INTERRUPTED, RunMetrics
from slamlab.io.rundir import FirstScan, ParticleRecord, RunDirectory, RunFile, TrajectoryKind
from slamlab.io.table import Table
from slamlab.manifest import build_manifest
from slamlab.heap import release_freed_memory
from slamlab.memory import RunPeakMemory
from slamlab.progress import make_progress
from slamlab.slam.result import SlamResult

if TYPE_CHECKING:
    from slamlab.assemble import RunSetup

log = logging.getLogger("slamlab")

# Created exclusively when a run starts: two processes given the same folder cannot both run.
CLAIM_FILE = RunFile.CLAIM


# Runs started in this process so far (this one included): a job of a launcher that reuses
# its worker processes is not the first.
_RUNS_BEFORE = [0]
SCOPE_REUSED = "run, in a process that ran other runs before"


class RunDirectoryInUse(SlamlabError):
    """The run directory already holds another run's artifacts."""


def user_error(exc: BaseException) -> SlamlabError | None:
    """The SlamlabError behind `exc` (Hydra wraps errors raised while instantiating)."""
    seen = 0
    while exc is not None and seen < 10:
        if isinstance(exc, SlamlabError):
            return exc
        exc = exc.__cause__ or exc.__context__
        seen += 1
    return None


def load_sequence(dataset_cfg: DictConfig) -> Sequence:
    """Build the dataset named by the `dataset` config group (`_target_` loader)."""
    try:
        with warnings.catch_warnings(record=True) as caught:  # to the run's log, one line each
            warnings.simplefilter("always")
            seq = instantiate(dataset_cfg, _convert_="all")
    except InstantiationException as exc:
        err = user_error(exc)
        if err is not None:
            raise err from None
        raise
    for w in caught:
        log.warning("%s", w.message)
    if not isinstance(seq, Sequence):
        raise ConfigError("dataset._target_", f"must return a slamlab Sequence, got {type(seq).__name__}")
    if len(seq) == 0:
        raise DataError(",".join(seq.sources) or seq.name, "the log holds no scans")
    repeated = repeated_stamps(seq.times, ",".join(seq.sources) or seq.name)
    if repeated:
        log.warning("%s", repeated)
    return seq


def require_values(cfg: DictConfig) -> None:
    """Keys marked `???` in the config (e.g. `dataset.path`) must be given by the user."""
    missing = sorted(k for k in OmegaConf.missing_keys(cfg) if not k.startswith("hydra."))
    if missing:
        raise ConfigError(missing[0], f"is required: give it on the command line, e.g. {missing[0]}=...")


def claim_run_dir(run_dir: Path) -> None:
    """Make `run_dir` this process's own, or raise RunDirectoryInUse if another run holds it.

    The claim file is created exclusively (O_EXCL, atomic) and holds the claiming process's
    id, so of two runs started together only one gets the folder, and the process that
    claimed it early (the CLI, before Hydra writes `.hydra/`) may claim it again here."""
    run_dir = Path(run_dir)
    taken: list[str] = RunDirectory(run_dir).holds_run()
    if not taken:
        try:
            fd = os.open(run_dir / CLAIM_FILE, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
            os.write(fd, str(os.getpid()).encode())
            os.close(fd)
            return
        except FileExistsError:
            if claimed_by_this_process(run_dir):
                return
            taken = [CLAIM_FILE]
    raise RunDirectoryInUse(
        f"{run_dir} already holds a run ({', '.join(taken)}); slamlab never overwrites a run. "
        "Choose another hydra.run.dir."
    )


def claimed_by_this_process(run_dir: Path) -> bool:
    """True if `run_dir`'s claim file names this process."""
    return RunDirectory(run_dir).claimed_by_this_process()


def filter_metrics(seq: Sequence, result: SlamResult, cfg: DictConfig) -> RunMetrics:
    """Runtime and filter statistics common to every dataset."""
    span = float(np.ptp(result.times)) if len(result.times) > 1 else 0.0
    steps = result.steps
    neff = steps["neff"].astype(float) if len(steps) else np.array([float("nan")])
    runtime = max(result.runtime_s, 1e-9)
    return RunMetrics(
        dataset=seq.name,
        mode=str(cfg.mode),
        filter=str(result.extras.get("filter", "course")),
        scans=len(result.times),
        processed_steps=int(len(steps)),
        particles=int(result.particles),
        seed=int(cfg.seed),
        duration_s=span,
        runtime_s=result.runtime_s,
        scans_per_s=len(result.times) / runtime,
        realtime_factor=span / runtime if span > 0 else float("nan"),
        resample_count=int(result.resample_count),
        neff_mean=float(np.nanmean(neff)),
        neff_min=float(np.nanmin(neff)),
        trajectory_fill=result.fill,
        # linear / linear_exp weighting: steps where the weights underflowed (all 0) or
        # overflowed (exp(corr) = inf) and uniform weights took over
        weighting_underflows=int(result.extras.get("weighting_underflows", 0)),
        weighting_overflows=int(result.extras.get("weighting_overflows", 0)),
        # map cells the matcher read (bilinear field value = 4, hit test = 1; the RBPF's coarse
        # grid of whole-cell shifts: each yaw's window once per point): at ~1 ns a read, a floor
        # under the matcher's CPU time
        matcher_map_reads=int(result.extras.get("matcher_map_reads", 0)),
        # MB held by the map(s): shared tiles counted once (rbpf); at the end and at peak
        map_memory={k: v for k, v in result.extras.items() if k.startswith("map_")},
        odometry_scale=result.extras.get("odometry_scale"),
        odometry_jumps=result.extras.get("odometry_jumps") or None,  # absent when the odometry never jumped
        thin_scans=thin.as_dict() if (thin := result.extras.get("thin_scans")) is not None else None,  # absent unless worth a warning
        graph=result.extras.get("graph"),
    )


def accuracy_metrics(seq: Sequence, result: SlamResult) -> dict:
    """Accuracy against what the dataset knows: ground truth (sim) or relations (CARMEN)."""
    out: dict = {}
    gt = seq.ground_truth
    n = len(result.times)  # fewer than len(seq) when steps.max_scans is set
    if gt is not None:
        from slamlab.eval.trajectory import map_agreement, trajectory_errors

        # one processed scan (the ladder's first step) sits at the true start pose: its
        # "error" is 0 by construction and would rank it best in a sweep, so accuracy needs
        # at least two processed steps
        if int(result.extras.get("processed_steps", n)) >= 2:
            truth = gt.poses[:n]
            traj = trajectory_errors(result.trajectory, truth)
            causal = trajectory_errors(result.causal, truth)
            odom = trajectory_errors(result.odometry, truth)
            traj.update(
                causal_rmse_m=causal["rmse_m"],
                causal_mean_m=causal["mean_m"],
                odometry_rmse_m=odom["rmse_m"],
                odometry_mean_m=odom["mean_m"],
            )
            out["trajectory"] = traj
        if gt.occupancy is not None:
            out["map"] = map_agreement(result.log_odds, gt.occupancy)
        if result.extras.get("loop_candidates") is not None:  # filter=graph: its closures against the truth
            from slamlab.eval.closures import closure_truth

            out["loop_truth"] = closure_truth(result.extras["loop_candidates"], result.extras["step_scans"], gt.poses)
    if seq.relations is not None:
        from slamlab.eval.relations import LOOP_MIN_DT_S, loop_end_offsets, relation_errors

        relations = relations_within(seq.relations, result.times)
        if len(relations.t1):
            # each path as a whole, and its local and loop relations apart
            rel = relation_errors(result.times, result.trajectory, relations, loop_min_dt_s=LOOP_MIN_DT_S)
            rel["causal"] = relation_errors(result.times, result.causal, relations, loop_min_dt_s=LOOP_MIN_DT_S)
            # where the online path's loop error sits: before the loop closed, or at the return
            rel["causal"]["loop_offsets"] = loop_end_offsets(result.times, result.causal, result.trajectory, relations, LOOP_MIN_DT_S)
            rel["odometry"] = relation_errors(result.times, result.odometry, relations, loop_min_dt_s=LOOP_MIN_DT_S)
            rel["of_total"] = int(len(seq.relations.t1))
            rel["loop_min_dt_s"] = LOOP_MIN_DT_S
            out["relations"] = rel
    return out


def relations_within(relations: Relations, times: np.ndarray) -> Relations:
    """The relations whose two timestamps both belong to processed scans (all of them for a
    full run; those inside the slice when `steps.max_scans` is set)."""
    from slamlab.eval.relations import find_times

    keep = find_times(times, relations.t1)[1] & find_times(times, relations.t2)[1]
    if keep.all():
        return relations
    return Relations(relations.t1[keep], relations.t2[keep], relations.rel[keep], relations.path)


def relation_table(seq: Sequence, result: SlamResult) -> Table | None:
    """One row per relation inside the run, for the report's error-over-time plot
    (relations.csv): t1, t2 (s), length_m (the relation's true translation), and the
    SLAM and odometry errors (trans m, rot deg)."""
    if seq.relations is None:
        return None
    from slamlab.eval.relations import relation_residuals

    rel = relations_within(seq.relations, result.times)
    if not len(rel.t1):
        return None
    cols = {"t1": rel.t1, "t2": rel.t2, "length_m": np.hypot(rel.rel[:, 0], rel.rel[:, 1])}
    for name, poses in (("slam", result.trajectory), ("odometry", result.odometry)):
        trans, rot = relation_residuals(result.times, poses, rel)
        cols[f"{name}_trans_m"], cols[f"{name}_rot_deg"] = trans, np.degrees(np.abs(rot))
    return Table(cols)


def write_recordings(run_dir: Path, result: SlamResult, first_scan: bool) -> None:
    """particles.npz, replay.npz and first_scan.npz, when `record.*` asks for them (docs/RUN_DIRECTORY.md)."""
    run = RunDirectory(run_dir)
    h = result.particle_history
    if h is not None:
        step_scans = np.asarray(result.extras["step_scans"])
        run.write_particles(ParticleRecord(t=result.times[step_scans],
                                           poses=h.poses, weights=h.weights, parents=h.parents, resampled=h.resampled))
    if result.replay is not None:
        step_scans = np.asarray(result.extras["step_scans"])
        run.write_replay(scan_index=step_scans[result.replay["step"]],
                         t=result.times[step_scans[result.replay["step"]]], **result.replay)
    if first_scan and result.first_scan_xy is not None:
        run.write_first_scan(FirstScan(points_xy=result.first_scan_xy,
                                       sensor_xy=np.asarray(result.first_scan_origin), pose=result.trajectory[int(result.extras["step_scans"][0])]))


def run_texture_stage(seq: Sequence, result: SlamResult, setup: RunSetup, run_dir: Path) -> dict:
    """Texture the floor with the SLAM and the odometry trajectories; write its outputs.

    Any failure here is reported in metrics and never loses the SLAM results.
    """
    from slamlab.eval.texture import texture_metrics
    from slamlab.texture.pipeline import run_textures, save_texture_outputs, save_truth_texture
    from slamlab.texture.samples import SAMPLE_FRAMES, write_samples
    from slamlab.texture.texture_map import resample_to_grid

    run = RunDirectory(run_dir)
    occ = artifacts.occupancy_probability(result.log_odds.data)
    out: dict = {}
    # one pass over the RGB-D stream places every frame with both trajectories; detection
    # scores do not depend on the trajectory, so only the SLAM one scores the detectors
    textures = run_textures(seq, result.times, {"slam": result.trajectory, "odometry": result.odometry},
                            result.log_odds, setup.ground, setup.texture, sample_frames=SAMPLE_FRAMES)
    slam_tex, odo_tex = textures["slam"], textures["odometry"]
    # the scores and the true texture's image first: their float64 temporaries (the true floor
    # averaged into the grid: ~20 MB for the default run's 800 x 800 cells) then come and go
    # before Open3D's libraries are loaded for the clouds, not on top of them (`make run`'s peak).
    # Should they fail, the textures are still written before the error goes up
    failed: Exception | None = None
    truth = seq.ground_truth
    try:
        # both textures are on the occupancy grid: the true floor is averaged into it once
        on_grid = (resample_to_grid(truth.floor_texture, slam_tex.count.shape, slam_tex.resolution_m, slam_tex.origin_xy)
                   if truth is not None and truth.floor_texture is not None else None)
        same_grid = (odo_tex.count.shape, odo_tex.resolution_m, odo_tex.origin_xy) == (slam_tex.count.shape, slam_tex.resolution_m, slam_tex.origin_xy)
        out = texture_metrics(slam_tex, truth, on_grid)
        if truth is not None:
            out["odometry"] = texture_metrics(odo_tex, truth, on_grid if same_grid else None)
        if on_grid is not None:
            save_truth_texture(slam_tex, truth.floor_texture, run / RunFile.TEXTURE_TRUTH, on_grid)
        del on_grid
    except Exception as exc:  # noqa: BLE001 - raised again below, once the textures are on disk
        failed = exc
    release_freed_memory()
    save_texture_outputs(slam_tex, occ, run.texture_files(TrajectoryKind.SLAM))
    if slam_tex.samples:
        write_samples(run / RunFile.GROUND_FRAMES, slam_tex.samples)
    save_texture_outputs(odo_tex, occ, run.texture_files(TrajectoryKind.ODOMETRY))
    if failed is not None:
        raise failed
    return out


def _finish_background(pool: ThreadPoolExecutor, job: Future, failing: bool = False) -> None:
    """Wait for `job` to end, through any Ctrl-C meanwhile (re-raised once it has ended), so a
    run folder is never cleaned up while its thread still writes into it. `failing`: an error
    is already on its way up; the job's own error, which it would hide, is logged."""
    interrupted = False
    while True:
        try:
            wait([job])
            break
        except KeyboardInterrupt:
            interrupted = True
    pool.shutdown()
    if failing and job.exception() is not None:
        going_up = sys.exc_info()[1]
        if not (isinstance(job.exception(), DiskFullError) and isinstance(going_up, DiskFullError)):  # said once
            log.error("writing the map failed too: %s", job.exception())
    if interrupted:
        raise KeyboardInterrupt


def run_pipeline(
    cfg: DictConfig,
    run_dir: Path,
    overrides: list[str] | None = None,
    progress: Callable[[int, int], None] | str | None = "auto",
) -> dict:
    """Run SLAM (+ texture) for `cfg` and write every artifact into `run_dir`.

    Returns the metrics as the dict written to metrics.json (`RunMetrics.to_dict`). User mistakes raise a
    SlamlabError; a failed run still writes metrics.json with status "failed" and the error.
    """
    from slamlab.eval.consistency import consistency_metrics
    from slamlab.assemble import assemble  # builds the components: imports the numba kernels
    from slamlab.slam.engine import run_slam
    from slamlab.texture.pipeline import texture_enabled

    run_dir = Path(run_dir)
    run = RunDirectory(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    claim_run_dir(run_dir)
    t0 = time.perf_counter()
    cpu0 = time.process_time()  # CPU s of this process: comparable when jobs share the cores
    memory = RunPeakMemory()  # this run's own peak, also when a sweep runs many in one process
    _RUNS_BEFORE[0] += 1
    stopper: StopOnSigint | None = None
    metrics: RunMetrics | None = None
    try:
        require_values(cfg)
        setup = assemble(cfg)  # every component built and checked once, before any work
        seq = load_sequence(cfg.dataset)
        log.info("dataset %s: %d scans, %s RGB-D frames", seq.name, len(seq), seq.rgbd_count if seq.rgbd else "no")
        texture_on = texture_enabled(seq, setup.texture)
        if not texture_on and seq.ground_truth is not None:
            # only the texture stage reads the true floor texture and the ground labels (the
            # hard simulated world's: 38 MB): not held through a run without it
            seq.ground_truth = replace(seq.ground_truth, floor_texture=None, ground_labels={})
        release_freed_memory()  # what reading freed (a THOR log's loadmat: ~130 MB), before the filter
        reporter = make_progress(progress, label="SLAM") if not callable(progress) else progress
        stopper = StopOnSigint(reporter)
        cpu_slam0 = time.process_time()
        try:
            with stopper:  # Ctrl-C here stops after the current step, keeping the run so far
                result = run_slam(seq, setup.components, progress=stopper)
        finally:
            if hasattr(reporter, "close"):
                reporter.close()
        cpu_slam = time.process_time() - cpu_slam0
        release_freed_memory()  # the particles' maps and the filter's work arrays

        # SLAM results first: whatever happens to texture afterwards, these are kept. The map's
        # PNG (seconds on a building: one zlib stream; zlib and its row filter let go of the GIL) is written on
        # a second thread while the metrics and the other files are made; the thread is waited
        # for before anything else happens, also when something here fails or Ctrl-C comes
        # (`_finish_background`), so nothing is written after the cleanup below.
        background = ThreadPoolExecutor(max_workers=1)
        map_written = background.submit(artifacts.write_map, run_dir, result.log_odds)
        try:
            metrics = filter_metrics(seq, result, cfg)
            metrics.cpu_time_s = cpu_slam
            metrics = replace(metrics, **accuracy_metrics(seq, result))
            consistency = consistency_metrics(seq, result.trajectory, result.log_odds, setup.components.map)
            metrics.consistency = consistency.summary
            run.write_trajectory(TrajectoryKind.SLAM, result.times, result.trajectory)
            run.write_trajectory(TrajectoryKind.CAUSAL, result.times, result.causal)
            run.write_trajectory(TrajectoryKind.ODOMETRY, result.times, result.odometry)
            if seq.ground_truth is not None:
                run.write_trajectory(TrajectoryKind.GROUNDTRUTH, result.times, seq.ground_truth.poses[: len(result.times)])
            artifacts.write_steps(run_dir, result.steps)
            artifacts.write_consistency(run_dir, consistency.series)
            run.write_consistency_map(consistency.overlay)
            relations = relation_table(seq, result)
            if relations is not None:
                artifacts.write_table(run / RunFile.RELATIONS, relations)
            if result.extras.get("loops") is not None:
                artifacts.write_table(run / RunFile.LOOPS, result.extras["loops"])
            write_recordings(run_dir, result, setup.run.record.first_scan)
            run.write_manifest(build_manifest(cfg, seq.sources, overrides or [], str(Path.cwd())))
        except BaseException:
            _finish_background(background, map_written, failing=True)
            raise
        _finish_background(background, map_written)
        map_written.result()  # its error, if any, is raised here
        if stopper.requested:
            raise KeyboardInterrupt

        if texture_on:
            # the texture stage reads the RGB-D stream, not the scans: they are let go first (the 2x `sim_loops`
            # building's 27,560 THOR scans: ~114 MB of ranges, resident through the texture stage's peak)
            seq = replace(seq, scans=())
            release_freed_memory()
            try:
                metrics.texture = run_texture_stage(seq, result, setup, run_dir)
            except Exception as exc:  # keep SLAM results; say what went wrong
                err = user_error(exc) or exc
                log.error("texture mapping failed, SLAM results kept: %s", err)
                metrics.texture = {"status": STATUS_FAILED, "error": str(err)}

        metrics.total_runtime_s = time.perf_counter() - t0
        metrics.total_cpu_time_s = time.process_time() - cpu0
        metrics.peak_memory_mb = memory.peak_mb()
        # a process that ran other runs before this one still holds some of what they
        # allocated: this run's peak then sits on that floor (`slamlab -m` runs each job in a
        # fresh child process; a launcher's reused workers do not)
        metrics.peak_memory_scope = memory.scope if _RUNS_BEFORE[0] == 1 or memory.scope != "run" else SCOPE_REUSED
        run.write_metrics(metrics)
        release_freed_memory()  # the report (in the CLI) or a sweep's next run starts from what is held
    except KeyboardInterrupt:
        memory.peak_mb()  # stops its sampling thread, if any
        artifacts.remove_partials(run_dir)
        raise _record_interruption(run_dir, stopper, metrics) from None
    except BaseException as exc:
        memory.peak_mb()
        artifacts.remove_partials(run_dir)
        _write_failure(run_dir, exc)
        raise
    summary = metrics.to_dict()
    _log_summary(summary)
    return summary


def _record_interruption(run_dir: Path, stopper: StopOnSigint | None, metrics: RunMetrics | None) -> RunInterrupted:
    """metrics.json for a Ctrl-C'd run (status "interrupted"; with the SLAM metrics and
    "partial": true when the map and trajectory so far were written), and the user's line."""
    done, total = (stopper.done, stopper.total) if stopper else (0, 0)
    if metrics is None:  # nothing computed yet (loading, or a second Ctrl-C mid-step)
        where = f"at scan {done}/{total}" if total else "before the first scan"
        message = f"interrupted {where}; no results in {run_dir}"
        info = RunMetrics(status=STATUS_INTERRUPTED, error=message)
    else:
        stage = "" if done < total else " after the SLAM loop"
        message = f"interrupted at scan {done}/{total}{stage}; partial results in {run_dir}"
        info = replace(metrics, status=STATUS_INTERRUPTED, error=message, partial=True)
    info = replace(info, interrupted_at_scan=done, scans_total=total)
    try:
        RunDirectory(run_dir).write_metrics(info)
    except OSError:
        pass
    return RunInterrupted(message)


def _write_failure(run_dir: Path, exc: BaseException) -> None:
    """metrics.json with the error, so sweep reports show the failed run."""
    run = RunDirectory(run_dir)
    if (run / RunFile.METRICS).exists():
        return
    err = user_error(exc)
    info = RunMetrics(status=STATUS_FAILED, error=str(err or exc) or type(exc).__name__)
    if err is None:
        info.traceback = "".join(traceback.format_exception(exc))
    try:
        run.write_metrics(info)
    except OSError:
        pass


def _log_summary(m: dict) -> None:
    parts = [f"{m['scans']} scans in {m['runtime_s']:.1f} s ({m['scans_per_s']:.0f} scans/s)"]
    if "trajectory" in m:
        parts.append(f"trajectory RMSE {m['trajectory']['rmse_m']:.3f} m (odometry {m['trajectory']['odometry_rmse_m']:.3f} m)")
    if "relations" in m:
        r = m["relations"]
        parts.append(f"relation error {r['trans_abs_mean_m']:.3f} m / {r['rot_abs_mean_deg']:.2f} deg")
    if isinstance(m.get("texture"), dict) and "colour_error" in m["texture"]:
        parts.append(f"texture colour error {m['texture']['colour_error']:.1f}")
    if not math.isnan(m.get("peak_memory_mb", float("nan"))):
        parts.append(f"peak memory {m['peak_memory_mb']:.0f} MB")
    log.info("done: %s", "; ".join(parts))
