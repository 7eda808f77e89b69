"""Both reports open in headless Chromium (no network) and render to a screenshot.
Skips when Chromium is not installed (apt-get install -y chromium), unless
SLAMLAB_REQUIRE_BROWSER=1 (set by .ci/run, which installs it): then it fails."""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import pytest

from report_fixtures import make_sweep, particles_seed_grid
from slamlab.report import build_sweep_report, write_run_report

_spec = importlib.util.spec_from_file_location(
    "screenshot_reports", Path(__file__).resolve().parents[1] / "benchmarks" / "screenshot_reports.py")
shots = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(shots)

pytestmark = [
    pytest.mark.slow,
    pytest.mark.browser,
    pytest.mark.skipif(
        shots.find_browser() is None and os.environ.get("SLAMLAB_REQUIRE_BROWSER") != "1",
        reason="Chromium not installed",
    ),
]


def test_reports_render_in_chromium(tmp_path: Path) -> None:
    root = tmp_path / "sweep"
    runs = make_sweep(root, particles_seed_grid([5, 10], [0]), ["particles=5,10"], failures={1: "metrics"}, n_steps=60)
    run_png = shots.screenshot(write_run_report(runs[0]), tmp_path / "run.png", 1200, 1600)
    sweep_png = shots.screenshot(build_sweep_report([root], root), tmp_path / "sweep.png", 1200, 1600)
    for png in (run_png, sweep_png):
        data = png.read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20_000  # a real page, not a blank one
