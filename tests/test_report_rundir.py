"""Reading run directories: statuses, trajectories, maps, and finding runs under folders."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from report_fixtures import make_run_dir, make_sweep, particles_seed_grid
from slamlab.errors import SlamlabError
from slamlab.report.rundir import find_run_dirs, load_run, read_tum


def test_ok_run_loads_everything(tmp_path: Path) -> None:
    d = make_run_dir(tmp_path / "r", overrides=["particles=20", "seed=3"])
    run = load_run(d)
    assert run.status == "ok" and run.error is None
    assert run.particles == 20 and run.seed == 3 and run.dataset == "sim"
    assert run.overrides_dict() == {"particles": "20", "seed": "3"}
    assert run.config["resampler"]["threshold"] == 0.5
    m = run.load_map()
    assert m is not None and m.data.dtype == np.float32 and m.resolution_m == pytest.approx(0.1)
    for kind in ("slam", "causal", "odometry", "groundtruth"):
        assert len(run.load_trajectory(kind)) == 300
    assert list(run.load_steps().columns)[:4] == ["step", "scan_index", "t", "neff"]


def test_plain_override_wins_over_added_one(tmp_path: Path) -> None:
    # a sweep preset (+experiment=ladder) whose sweeper picks experiment=X per job ran X,
    # whichever order Hydra saved the two in
    for order in (["experiment=ladder_predict", "+experiment=ladder"], ["+experiment=ladder", "experiment=ladder_predict"]):
        d = make_run_dir(tmp_path / str(len(list(tmp_path.iterdir()))), overrides=[*order, "particles=5"])
        assert load_run(d).overrides_dict() == {"experiment": "ladder_predict", "particles": "5"}
    d = make_run_dir(tmp_path / "plus", overrides=["+experiment=sim"])
    assert load_run(d).overrides_dict() == {"experiment": "sim"}


def test_tum_yaw_from_quaternion(tmp_path: Path) -> None:
    p = tmp_path / "x.tum"
    th = 2.5
    p.write_text(f"# timestamp x y z qx qy qz qw\n1.0 2.0 3.0 0 0 0 {np.sin(th / 2)} {np.cos(th / 2)}\n")
    tr = read_tum(p)
    assert tr.xy.tolist() == [[2.0, 3.0]] and tr.yaw[0] == pytest.approx(th)
    p.write_text("1 2 3\n")
    with pytest.raises(SlamlabError, match="x.tum"):
        read_tum(p)


def test_failed_runs(tmp_path: Path) -> None:
    r = load_run(make_run_dir(tmp_path / "a", failure="metrics"))
    assert r.status == "failed" and "expected 360 beams" in r.error
    r = load_run(make_run_dir(tmp_path / "b", failure="log"))
    assert r.status == "failed" and "MemoryError" in r.error and "Traceback" in r.log_tail
    # Killed before writing anything but Hydra's files: incomplete, not silently ok.
    d = tmp_path / "c"
    (d / ".hydra").mkdir(parents=True)
    (d / ".hydra" / "config.yaml").write_text("particles: 5\n")
    r = load_run(d)
    assert r.status == "incomplete" and r.particles == 5
    # Broken JSON names the file.
    (d / "metrics.json").write_text("{not json")
    with pytest.raises(SlamlabError, match="metrics.json"):
        load_run(d)


def test_optional_files_missing(tmp_path: Path) -> None:
    d = make_run_dir(tmp_path / "r", groundtruth=False)
    for name in ("map_logodds.npz", "steps.csv", "manifest.json"):
        (d / name).unlink()
    run = load_run(d)
    assert run.load_map() is None and run.load_steps() is None
    assert run.load_trajectory("groundtruth") is None
    assert run.config["particles"] == 100  # from .hydra/config.yaml when there is no manifest
    assert "trajectory" not in json.loads((d / "metrics.json").read_text())


def test_find_run_dirs(tmp_path: Path) -> None:
    jobs = particles_seed_grid([5, 10], [0, 1, 2, 3, 4, 5])  # 12 jobs: '10' must sort after '9'
    make_sweep(tmp_path / "multirun" / "d" / "s1", jobs, ["particles=5,10", "seed=0,1,2,3,4,5"])
    make_sweep(tmp_path / "multirun" / "d" / "s2", jobs[:2], ["particles=5", "seed=0,1"])
    runs = find_run_dirs([tmp_path / "multirun" / "d" / "s1"])
    assert [p.name for p in runs] == [str(i) for i in range(12)]
    assert len(find_run_dirs([tmp_path / "multirun"])) == 14
    # A run dir, its metrics file, and duplicates are accepted.
    one = tmp_path / "multirun" / "d" / "s2" / "1"
    assert find_run_dirs([one, one / "metrics.json", tmp_path / "multirun" / "d" / "s2"]) == [one.resolve(), (one.parent / "0").resolve()]
    (tmp_path / "empty").mkdir()
    with pytest.raises(SlamlabError, match="no run directories"):
        find_run_dirs([tmp_path / "empty"])
    with pytest.raises(SlamlabError, match="no such file"):
        find_run_dirs([tmp_path / "nope"])
