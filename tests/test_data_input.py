"""Imperfect input files as users meet them through `slamlab`: CARMEN logs cut mid-line or with
a garbage line, impossible ranges, repeated timestamps, relation files with rounded stamps,
and calibration pickles that hold more than numbers."""

from __future__ import annotations

import json
import os
import pickle
import subprocess
from pathlib import Path

import numpy as np
import pytest

from slamlab.datasets.calibration import load_kinect_calibration
from slamlab.datasets.carmen import load_carmen
from slamlab.datasets.sim.calib import default_calibration, write_camera_params
from slamlab.errors import DataError
from slamlab.datasets.relations import snap_relations
from slamlab.frames import Relations

N_SCANS = 40
T0 = 1000.0  # s
DT = 0.1  # s between scans


def room_flaser(k: int, t: float, ranges: list | None = None) -> str:
    """A FLASER line of a robot walking along x in a 10 x 6 m box (181 beams, -90..90 deg)."""
    x, y = 2.0 + 0.05 * k, 3.0
    if ranges is None:
        ang = np.radians(np.arange(-90, 91))
        c, s = np.cos(ang), np.sin(ang)
        with np.errstate(divide="ignore"):
            tx = np.where(c > 0, (10.0 - x) / c, np.where(c < 0, -x / c, np.inf))
            ty = np.where(s > 0, (6.0 - y) / s, np.where(s < 0, -y / s, np.inf))
        ranges = [f"{r:.3f}" for r in np.minimum(tx, ty)]
    pose = f"{x:.6f} {y:.6f} 0.000000"
    return f"FLASER {len(ranges)} {' '.join(map(str, ranges))} {pose} {pose} {t:.6f} nohost {t:.6f}"


def room_log(times: list[float] | None = None) -> list[str]:
    times = times or [T0 + DT * k for k in range(N_SCANS)]
    return [room_flaser(k, t) for k, t in enumerate(times)]


@pytest.fixture
def slamlab(slamlab_app):
    """`slamlab ARGS` (quick settings), called in this process: these tests read only the exit
    status, the messages and the files it writes."""
    quick = ["particles=5", "texture=none", "report=false", "progress=off"]

    def run(args: list[str], tmp_path: Path, cache: Path | None = None) -> subprocess.CompletedProcess:
        return slamlab_app([*quick, *args], tmp_path, cache)

    return run


def warnings_in(stderr: str) -> list[str]:
    return [line.split("[WARNING] ", 1)[1] for line in stderr.splitlines() if "[WARNING] " in line]


# ----------------------------------------------------------------------------- bad lines


def test_a_log_cut_mid_line_says_it_was_truncated(tmp_path, slamlab):
    lines = room_log()
    cut = "\n".join(lines[:-1]) + "\n" + lines[-1][: len(lines[-1]) // 2]  # no final newline
    (tmp_path / "cut.clf").write_text(cut)
    proc = slamlab(["dataset=carmen", f"dataset.path={tmp_path / 'cut.clf'}", f"hydra.run.dir={tmp_path / 'r'}"], tmp_path)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    [line] = [x for x in proc.stderr.splitlines() if "cut.clf" in x]
    assert line.endswith(
        f"cut.clf: line {N_SCANS} (FLASER), field 'range[97]': missing: the line has 99 values but num_readings=181 "
        "needs 192 (this is the file's last line: the file looks truncated; it ends without a newline); "
        "dataset.on_bad_line=skip drops bad lines and goes on")


def test_skip_drops_bad_lines_with_one_warning_and_runs(tmp_path, slamlab):
    lines = room_log()
    lines[11] = lines[11].replace(" 0.000000 ", " x0.0 ", 1)  # garbage in the middle
    lines[20] = room_flaser(20, T0 + DT * 20, ranges=["nan", -1.0, "inf"] + ["2.0"] * 178)
    text = "\n".join(lines[:-1]) + "\n" + lines[-1][:100]  # and cut mid-line
    (tmp_path / "messy.clf").write_text(text)
    run = tmp_path / "r"
    proc = slamlab(["dataset=carmen", f"dataset.path={tmp_path / 'messy.clf'}", "dataset.on_bad_line=skip",
                    f"hydra.run.dir={run}"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert warnings_in(proc.stderr) == [
        f"{tmp_path / 'messy.clf'}: skipped 2 bad line(s): 12, {N_SCANS} (the last line of the file: truncated); "
        f"first: {tmp_path / 'messy.clf'}: line 12 (FLASER), field 'theta': expected a number, got 'x0.0'",
        f"{tmp_path / 'messy.clf'}: 3 negative, NaN or inf range readings dropped as invalid beams",
    ]
    assert json.loads((run / "metrics.json").read_text())["scans"] == N_SCANS - 2


def test_skip_is_refused_when_misspelled(tmp_path, slamlab):
    (tmp_path / "a.clf").write_text("\n".join(room_log()) + "\n")
    proc = slamlab(["dataset=carmen", f"dataset.path={tmp_path / 'a.clf'}", "dataset.on_bad_line=ignore",
                    f"hydra.run.dir={tmp_path / 'r'}"], tmp_path)
    assert proc.returncode == 2
    assert "config 'dataset.on_bad_line': must be one of error, skip, got 'ignore'" in proc.stderr


# ----------------------------------------------------------------------------- timestamps


def test_repeated_timestamps_are_warned_about(tmp_path, slamlab):
    times = [T0 + DT * k for k in range(N_SCANS)]
    times[10:17] = [times[10]] * 7  # the clock stood still for 7 scans
    (tmp_path / "stuck.clf").write_text("\n".join(room_log(times)) + "\n")
    proc = slamlab(["dataset=carmen", f"dataset.path={tmp_path / 'stuck.clf'}", f"hydra.run.dir={tmp_path / 'r'}"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert warnings_in(proc.stderr) == [
        f"{tmp_path / 'stuck.clf'}: 7 scans in 1 run(s) of 5 or more repeat one timestamp (longest: scans 10-16, "
        f"7 scans at {times[10]:.6f}); relations and RGB-D frames cannot be matched to scans by time there"]


def test_all_equal_timestamps_are_warned_about(tmp_path, slamlab):
    (tmp_path / "flat.clf").write_text("\n".join(room_log([T0] * N_SCANS)) + "\n")
    proc = slamlab(["dataset=carmen", f"dataset.path={tmp_path / 'flat.clf'}", f"hydra.run.dir={tmp_path / 'r'}"], tmp_path)
    assert f"all {N_SCANS} scans have the same timestamp {T0:.6f}" in proc.stderr


# ----------------------------------------------------------------------------- relations


def write_relations(path: Path, pairs: list[tuple[float, float]]) -> Path:
    path.write_text("".join(f"{a:.5f} {b:.5f} 0.5 0.0 0 0 0 0.0\n" for a, b in pairs))
    return path


def test_relations_rounded_to_10_us_are_matched(tmp_path, slamlab):
    times = [T0 + DT * k + 3e-6 for k in range(N_SCANS)]  # stamps with microseconds the file rounds away
    (tmp_path / "room.clf").write_text("\n".join(room_log(times)) + "\n")
    write_relations(tmp_path / "room.relations", [(times[k], times[k + 10]) for k in range(0, 25, 5)])
    run = tmp_path / "r"
    proc = slamlab(["dataset=carmen", f"dataset.path={tmp_path / 'room.clf'}", f"hydra.run.dir={run}"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    rel = json.loads((run / "metrics.json").read_text())["relations"]
    assert rel["count"] == rel["of_total"] == 5


def test_a_relation_far_from_every_scan_names_line_stamp_and_nearest_scan(tmp_path, slamlab):
    (tmp_path / "room.clf").write_text("\n".join(room_log()) + "\n")
    write_relations(tmp_path / "room.relations", [(T0, T0 + 1.0), (T0 + 0.5, T0 + 1.0502)])
    proc = slamlab(["dataset=carmen", f"dataset.path={tmp_path / 'room.clf'}", f"hydra.run.dir={tmp_path / 'r'}"], tmp_path)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert (f"room.relations: line 2, field 't2': stamp {T0 + 1.0502:.6f} has no scan in room.clf within 0.0001 s "
            f"(nearest scan time {T0 + 1.1:.6f}, 0.049800 s away; 1 stamps affected; wrong relations file?)") in proc.stderr
    # a tolerance wide enough to reach it reaches the scan after it too: ambiguous
    proc = slamlab(["dataset=carmen", f"dataset.path={tmp_path / 'room.clf'}", "dataset.relations_time_tol_s=0.06",
                    f"hydra.run.dir={tmp_path / 'r2'}"], tmp_path)
    assert proc.returncode == 2
    assert (f"room.relations: line 2, field 't2': stamp {T0 + 1.0502:.6f} is within 0.06 s of two scans of room.clf "
            f"({T0 + 1.1:.6f} and {T0 + 1.0:.6f}): ambiguous; lower dataset.relations_time_tol_s") in proc.stderr


def test_an_ambiguous_relation_stamp_is_refused():
    times = np.array([0.0, 1.0, 1.00008, 2.0])
    rel = Relations(np.array([0.0, 1.00004]), np.array([2.0, 2.0]), np.zeros((2, 3)), "x.relations")
    with pytest.raises(DataError, match=r"x\.relations: line 7, field 't1': stamp 1\.000040 is within 0\.0001 s of "
                                        r"two scans of log\.clf \(1\.000000 and 1\.000080\): ambiguous"):
        snap_relations(rel, [3, 7], times, 1e-4, log_name="log.clf")
    ok = Relations(np.array([0.000004, 1.000081]), np.array([2.0, 1.99999]), np.zeros((2, 3)), "x.relations")
    out = snap_relations(ok, [3, 7], times, 1e-4, log_name="log.clf")
    assert out.t1.tolist() == [0.0, 1.00008] and out.t2.tolist() == [2.0, 2.0]


def test_the_benchmark_relations_still_match_exactly(shared_data):
    seq = load_carmen(shared_data / "carmen" / "aces.clf.bz2")
    times = np.array([s.t for s in seq.scans])
    assert np.isin(seq.relations.t1, times).all() and np.isin(seq.relations.t2, times).all()


# ----------------------------------------------------------------------------- calibration


class _RunsCode:
    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def test_a_calibration_pickle_that_would_run_code_is_refused(tmp_path, sim_cache, slamlab):
    cal = write_camera_params(tmp_path / "cameraParam", default_calibration())
    assert load_kinect_calibration(cal).ir.width == 512  # the plain pickles load
    marker = tmp_path / "pwned"
    with (cal / "exParams.pkl").open("wb") as f:
        pickle.dump({"R": np.eye(3), "T": _RunsCode(marker)}, f, protocol=2)
    proc = slamlab([f"dataset.calibration_dir={cal}", "dataset.duration_s=5", f"hydra.run.dir={tmp_path / 'r'}"],
                   tmp_path, sim_cache)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert (f"{cal / 'exParams.pkl'}: holds a Python object 'posix.system', not only numbers, arrays, dicts and "
            "lists; not loaded (a pickle can run code when loaded)") in proc.stderr
    assert not marker.exists()
