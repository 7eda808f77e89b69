"""The per-run report.html: self-contained, every section present when its inputs are."""

from __future__ import annotations

import html
import json
import re
from pathlib import Path

from report_fixtures import make_run_dir
from slamlab.report import write_run_report
from slamlab.report.html import fmt_number


def _external_refs(page: str) -> list[str]:
    """src/href values that would need the network (links to local files are fine)."""
    refs = re.findall(r'(?:src|href)="([^"]+)"', page)
    return [r for r in refs if re.match(r"^(https?:)?//", r)]


def test_run_report_content(tmp_path: Path) -> None:
    d = make_run_dir(tmp_path / "run", overrides=["particles=40", "seed=7", "dataset.duration_s=10"], texture=True)
    out = write_run_report(d)
    assert out == d / "report.html"
    page = out.read_text()
    assert not _external_refs(page), "report must open with no network"
    assert "<script src" not in page and "<link" not in page
    # Map, texture, N_eff, best weight / step time: four embedded PNGs at least.
    assert page.count("data:image/png;base64,") >= 4
    for section in ('id="map"', 'id="texture"', 'id="filter"', 'id="metrics"', 'id="config"'):
        assert section in page
    assert "ground truth" in page and "threshold" in page and "resampler.threshold = 0.5 × N" in page
    # Every top-level metric number appears as formatted in the table.
    metrics = json.loads((d / "metrics.json").read_text())
    for key in ("runtime_s", "scans_per_s", "resample_count", "neff_mean", "peak_memory_mb"):
        assert f"<td>{fmt_number(metrics[key])}</td>" in page, key
    assert f"<td>{fmt_number(metrics['trajectory']['rmse_m'])}</td>" in page
    # How to re-run it: the overrides, and the exact saved config.
    assert "slamlab particles=40 seed=7 dataset.duration_s=10" in html.unescape(page)
    assert "--config-name config" in page
    # Atomic write leaves no temp file behind.
    assert not [p for p in d.iterdir() if p.name.endswith(".tmp")]


def test_run_report_without_ground_truth_or_steps(tmp_path: Path) -> None:
    d = make_run_dir(tmp_path / "run", groundtruth=False)
    (d / "steps.csv").unlink()
    page = write_run_report(d).read_text()
    assert "No ground truth for this dataset." in page
    assert "No per-step table" in page
    assert 'id="texture"' not in page


def test_failed_run_report(tmp_path: Path) -> None:
    d = make_run_dir(tmp_path / "a", failure="metrics")
    page = write_run_report(d).read_text()
    assert "This run failed" in page and "expected 360 beams" in page
    d = make_run_dir(tmp_path / "b", failure="log")
    page = write_run_report(d).read_text()
    assert "MemoryError" in page and "No map or trajectory" in page


def test_user_text_is_escaped(tmp_path: Path) -> None:
    d = make_run_dir(tmp_path / "a", failure="metrics")
    m = json.loads((d / "metrics.json").read_text())
    m["error"] = "<script>alert(1)</script>"
    (d / "metrics.json").write_text(json.dumps(m))
    page = write_run_report(d).read_text()
    assert "<script>alert(1)" not in page and "&lt;script&gt;alert(1)" in page


def test_rolling_median_is_pandas_centred_rolling_median() -> None:
    # the run report smooths without pandas; the curves must be the ones pandas drew
    import numpy as np
    import pandas as pd

    from slamlab.report.figures import rolling_median

    rng = np.random.default_rng(3)
    y = rng.normal(size=103)
    y[[0, 7, 8, 9, 50]] = np.nan
    for n in (1, 2, 5, 103):
        for win in (1, 2, 3, 4, 25, 40, 200):
            want = pd.Series(y[:n]).rolling(win, center=True, min_periods=1).median().to_numpy()
            np.testing.assert_array_equal(rolling_median(y[:n], win), want, err_msg=f"n={n} window={win}")
    assert rolling_median(np.zeros(0), 5).shape == (0,)


def test_odometry_jumps_are_named_in_the_summary_and_listed_in_the_metrics(tmp_path: Path) -> None:
    """A run whose odometry jumped (steps.odom_jump_m) says so among its headline numbers, with
    where and how far; the metrics table lists every jump as JSON, not as a Python repr."""
    d = make_run_dir(tmp_path / "run")
    m = json.loads((d / "metrics.json").read_text())
    m["odometry_jumps"] = [{"scan": 100 * k, "t_s": 10.0 * k, "m": 41.28, "deg": 57.35} for k in range(1, 6)]
    (d / "metrics.json").write_text(json.dumps(m))
    page = html.unescape(write_run_report(d).read_text())
    assert "odometry jumps taken as resets, not motion" in page
    assert "scan 100: 41.28 m, 57.35°; scan 200: 41.28 m, 57.35°; scan 300: 41.28 m, 57.35°; 2 more" in page
    assert json.dumps(m["odometry_jumps"]) in page and "{'scan'" not in page
    m.pop("odometry_jumps")
    (d / "metrics.json").write_text(json.dumps(m))
    assert "odometry jumps" not in write_run_report(d).read_text()


def test_thin_scans_are_named_in_the_summary(tmp_path: Path) -> None:
    """A run whose scans had too few returns to match (slam/thin_scans.py) says how many of its
    steps and where the longest stretch lies among its headline numbers; a run without says nothing."""
    d = make_run_dir(tmp_path / "run")
    m = json.loads((d / "metrics.json").read_text())
    m["thin_scans"] = {"steps": 1223, "share": 0.7078, "min_returns": 20, "longest_m": 81.64, "from_s": 230.6, "to_s": 392.6}
    (d / "metrics.json").write_text(json.dumps(m))
    page = html.unescape(write_run_report(d).read_text())
    assert "steps whose scans had fewer than 20 returns (on odometry alone)" in page
    assert "1223 (71 %); the longest stretch 82 m, 231-393 s into the run" in page
    m.pop("thin_scans")
    (d / "metrics.json").write_text(json.dumps(m))
    assert "fewer than 20 returns" not in write_run_report(d).read_text()
