"""The sweep comparison report and slamlab-report, on a fabricated 12-run sweep with failures."""

from __future__ import annotations

import json
import re
import time
from pathlib import Path

import pandas as pd
import pytest

from report_fixtures import make_sweep, particles_seed_grid
from slamlab.cli.report import main as report_main
from slamlab.report import build_sweep_report
from slamlab.report.columns import METRICS, get_metric
from slamlab.report.rundir import load_run

PARTICLES = [5, 10, 20, 50]
SEEDS = [0, 1, 2]
FAILED = {4: "metrics", 7: "log"}


@pytest.fixture(scope="module")
def sweep(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("multirun") / "2025-01-01" / "10-00-00-000000"
    make_sweep(root, particles_seed_grid(PARTICLES, SEEDS, ["dataset.duration_s=10"]),
               ["particles=5,10,20,50", "seed=0,1,2", "dataset.duration_s=10"], failures=FAILED, n_steps=200)
    return root


@pytest.fixture(scope="module")
def built(sweep: Path) -> tuple[Path, float]:
    t0 = time.perf_counter()
    out = build_sweep_report([sweep], sweep)
    return out, time.perf_counter() - t0


def _rows(page: str) -> dict[str, str]:
    return dict(re.findall(r'<tr class="\w+" data-run="([^"]+)">(.*?)</tr>', page, flags=re.S))


def test_every_run_present_with_status(built) -> None:
    out, seconds = built
    page = out.read_text()
    rows = _rows(page)
    assert sorted(rows, key=int) == [str(i) for i in range(12)]
    for i in range(12):
        status = "failed" if i in FAILED else "ok"
        assert f'<tr class="{status}" data-run="{i}">' in page
    assert seconds < 30.0


def test_numbers_equal_metrics_files(built, sweep: Path) -> None:
    """Every metric cell's sort key is the exact float from metrics.json; runs.csv too."""
    out, _ = built
    rows = _rows(out.read_text())
    csv = pd.read_csv(sweep / "runs.csv", dtype={"run": str}).set_index("run")
    shown = [m for m in METRICS if m.table]
    checked = 0
    for i in range(12):
        if not (sweep / str(i) / "metrics.json").is_file():
            continue  # the run killed before writing metrics
        metrics = json.loads((sweep / str(i) / "metrics.json").read_text())
        for spec in shown:
            v = get_metric(metrics, spec.key)
            if v == v:  # not NaN
                assert f'data-v="{v!r}"' in rows[str(i)], (i, spec.key)
                assert csv.loc[str(i), spec.key] == v
                checked += 1
    assert checked > 100


def test_swept_columns_best_marks_and_failures(built) -> None:
    page = built[0].read_text()
    head = re.search(r'id="runs-table">\s*<thead><tr>(.*?)</tr></thead>', page, re.S).group(1)
    headers = re.findall(r">([^<>]+)</th>", head)
    assert headers[:5] == ["run", "status", "particles", "seed", "error"]
    assert "dataset.duration_s" not in headers  # the same in every run: stated once, not a column
    assert "dataset.duration_s=10" in page
    assert "slamlab -m particles=5,10,20,50 seed=0,1,2 dataset.duration_s=10" in page
    # Best ATE RMSE is marked once, in a 50-particle run; failed runs are never best.
    best_rows = [run for run, body in _rows(page).items() if re.search(r'class="best" data-v="[^"]+">', body)]
    assert best_rows and not set(best_rows) & {"4", "7"}
    assert "expected 360 beams" in page and "MemoryError" in page
    assert "Failed or incomplete runs" in page


def test_plots_aggregates_and_config_diff(built) -> None:
    page = built[0].read_text()
    assert "versus particles" in page
    assert "Mean and spread across seeds" in page
    # 4 configurations, n seeds = 3 except where a seed failed.
    agg = re.search(r'id="seeds".*?<tbody>(.*?)</tbody>', page, re.S).group(1)
    assert len(re.findall(r"<tr>", agg)) == 4
    assert re.findall(r'<td class="" data-v="(\d)">', agg) == ["3", "2", "2", "3"]
    # Config differences: only particles and seed differ.
    diff_head = re.search(r'id="config".*?<thead><tr>(.*?)</tr>', page, re.S).group(1)
    assert re.findall(r">([^<>]+)</th>", diff_head) == ["run", "particles", "seed"]
    assert page.count("data:image/png;base64,") >= 4  # param plot, overlay, map grid, N_eff


@pytest.mark.slow
def test_cli_combines_sweeps_and_reports_errors(sweep: Path, tmp_path: Path, monkeypatch, capsys) -> None:
    other = tmp_path / "multirun" / "2025-01-02" / "09-00-00-000000"
    make_sweep(other, particles_seed_grid([100], [0]), ["particles=100", "seed=0"], n_steps=100)
    out = tmp_path / "cmp.html"
    assert report_main([str(sweep), str(other), "-o", str(out), "--title", "two sweeps"]) == 0
    page = out.read_text()
    assert "<title>two sweeps</title>" in page
    assert len(_rows(page)) == 13
    assert "10-00-00-000000/0" in page and "09-00-00-000000/0" in page
    # Default output: reports/<timestamp>/report.html under the current directory.
    monkeypatch.chdir(tmp_path)
    assert report_main([str(other)]) == 0
    made = list((tmp_path / "reports").glob("*/report.html"))
    assert len(made) == 1 and (made[0].parent / "runs.csv").is_file()
    capsys.readouterr()
    (tmp_path / "empty").mkdir()
    assert report_main([str(tmp_path / "empty")]) == 2
    assert "no run directories found" in capsys.readouterr().err
    # a run's own report.html is never replaced by a comparison page
    run0 = other / "0"
    before = (run0 / "metrics.json").read_bytes(), (run0 / "report.html").read_bytes() if (run0 / "report.html").exists() else None
    assert report_main([str(other), "-o", str(run0)]) == 2
    assert "is a run directory" in capsys.readouterr().err
    after = (run0 / "metrics.json").read_bytes(), (run0 / "report.html").read_bytes() if (run0 / "report.html").exists() else None
    assert after == before


def test_report_survives_broken_artifacts(tmp_path: Path) -> None:
    root = tmp_path / "sw"
    make_sweep(root, particles_seed_grid([5, 10], [0]), ["particles=5,10"], n_steps=50)
    (root / "0" / "map_logodds.npz").write_bytes(b"garbage")
    (root / "1" / "metrics.json").write_text("{broken")
    page = build_sweep_report([root], root).read_text()
    assert len(_rows(page)) == 2
    assert "unreadable run directory" in page
    assert load_run(root / "0").ok


def test_weighting_fallback_columns_show_only_when_a_run_had_one(tmp_path: Path) -> None:
    from report_fixtures import make_run_dir

    from slamlab.report.sweep_report import build_sweep_report

    def sweep(name: str, overflows: list[int]) -> str:
        for i, n in enumerate(overflows):
            d = make_run_dir(tmp_path / name / str(i), overrides=[f"weighting={'linear_exp' if n else 'logsumexp'}"], n_steps=50)
            m = json.loads((d / "metrics.json").read_text())
            m.update(weighting_overflows=n, weighting_underflows=0)
            (d / "metrics.json").write_text(json.dumps(m))
        return build_sweep_report([tmp_path / name], tmp_path / name / "out").read_text()

    page = sweep("some", [0, 37])
    assert "weight overflows" in page and 'data-v="37.0"' in page
    assert "weight underflows" not in page  # zero everywhere: not worth a column
    assert "weight overflows" not in sweep("none", [0, 0])
