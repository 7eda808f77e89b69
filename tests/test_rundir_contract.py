"""The run directory contract (slamlab.io.rundir) and the typed metrics.json (RunMetrics)."""

from __future__ import annotations

import json
import math

import numpy as np

from slamlab.io.run_metrics import RunMetrics
from slamlab.io.rundir import RUN_MARKERS, FirstScan, ParticleRecord, RunDirectory, RunFile, TrajectoryKind

# A metrics.json as a run writes it, in its key order (docs/RUN_DIRECTORY.md).
WRITTEN = {
    "status": "ok", "dataset": "sim", "mode": "slam", "filter": "course", "scans": 3, "processed_steps": 3,
    "particles": 5, "seed": 0, "duration_s": 0.2, "runtime_s": 0.5, "scans_per_s": 6.0, "realtime_factor": None,
    "resample_count": 1, "neff_mean": 4.5, "neff_min": 3.0, "trajectory_fill": "odometry",
    "weighting_underflows": 0, "weighting_overflows": 0, "matcher_map_reads": 12, "map_memory": {"map_mb": 0.1},
    "cpu_time_s": 0.4, "trajectory": {"rmse_m": 0.01}, "consistency": {"scans_scored": 3},
    "total_runtime_s": 1.0, "total_cpu_time_s": 0.9, "peak_memory_mb": 100.0, "peak_memory_scope": "run",
}  # fmt: skip


def test_metrics_round_trip_is_byte_identical(tmp_path):
    src = tmp_path / "a"
    src.mkdir()
    text = json.dumps(WRITTEN, indent=2) + "\n"
    (src / RunFile.METRICS).write_text(text)
    m = RunDirectory(src).read_metrics()
    assert m is not None and m.ok and m.particles == 5 and m.trajectory == {"rmse_m": 0.01}
    assert math.isnan(m.realtime_factor)  # null in the file: not a number
    out = tmp_path / "b"
    out.mkdir()
    RunDirectory(out).write_metrics(m)
    assert (out / RunFile.METRICS).read_text() == text


def test_fields_in_file_order_when_built_by_the_pipeline():
    # the pipeline holds NaN where the file says null
    m = RunMetrics(**{k: math.nan if v is None else v for k, v in WRITTEN.items() if k != "status"})
    assert list(m.to_dict()) == list(WRITTEN)
    failed = RunMetrics(status="failed", error="boom", traceback="tb")
    assert failed.to_dict() == {"status": "failed", "error": "boom", "traceback": "tb"}


def test_old_files_keep_unknown_keys_and_their_order():
    old = {"dataset": "x", "legacy_metric": 3, "scans": 2}  # no status: an early version's run
    m = RunMetrics.from_dict(old)
    assert m.status is None and not m.ok and m.extra == {"legacy_metric": 3}
    assert m.to_dict() == old and list(m.to_dict()) == list(old)


def test_records_and_trajectories_round_trip(tmp_path):
    run = RunDirectory(tmp_path)
    rec = ParticleRecord(t=np.arange(2.0), poses=np.zeros((2, 3, 3)), weights=np.full((2, 3), 1 / 3),
                         parents=np.zeros((2, 3), np.int64), resampled=np.array([False, True]))
    run.write_particles(rec)
    back = run.read_particles()
    assert back is not None and back.particles == 3 and np.array_equal(back.resampled, rec.resampled)
    run.write_first_scan(FirstScan(points_xy=np.ones((4, 2)), sensor_xy=np.zeros(2), pose=np.zeros(3)))
    assert run.read_first_scan().points_xy.shape == (4, 2)
    t, poses = np.array([0.0, 1.0]), np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 0.5]])
    run.write_trajectory(TrajectoryKind.ODOMETRY, t, poses)
    assert (tmp_path / "odometry.tum").is_file()
    rt, rp = run.read_trajectory("odometry")
    assert np.allclose(rp, poses) and run.read_trajectory(TrajectoryKind.SLAM) is None


def test_names_are_the_documented_ones(tmp_path):
    run = RunDirectory(tmp_path)
    assert [p.name for p in run.texture_files("odometry")] == [
        "texture_odometry.png", "texture_odometry_over_map.png", "floor_odometry.ply"]
    assert run.holds_run() == [] and not run.is_run()
    (tmp_path / RunFile.METRICS).write_text("{}")
    assert run.holds_run() == ["metrics.json"] and run.is_run()
    assert RunFile.CLAIM in RUN_MARKERS


def test_reports_see_metrics_json_as_written(tmp_path):
    """An older run's metrics.json (other key order, keys this version does not know, nulls)
    reaches the report pages exactly as the file holds it."""
    from slamlab.report.rundir import load_run

    old = {"dataset": "sim", "scans": 4, "neff_mean": None, "legacy": {"a": 1}, "status": "ok", "runtime_s": 2.0}
    (tmp_path / RunFile.METRICS).write_text(json.dumps(old))
    run = load_run(tmp_path)
    assert run.ok and run.metrics == old and list(run.metrics) == list(old)
    del old["status"]  # written before slamlab recorded a status: read as ok, shown as written
    (tmp_path / RunFile.METRICS).write_text(json.dumps(old))
    run = load_run(tmp_path)
    assert run.ok and run.metrics == old
