"""Both reports from a real `slamlab -m` sweep on simulated data (small: 6 s of data, no RGB-D).

The sweep report is written by SweepReportCallback inside the real app (added with a
`++hydra.callbacks...` override, so this works whether or not conf/config.yaml enables it),
then rebuilt by `slamlab-report`; both are checked against the runs' metrics.json."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from slamlab.cli.report import main as report_main
from slamlab.report.columns import METRICS, get_metric
from cli_helpers import sweep_cli

pytestmark = pytest.mark.slow



@pytest.fixture(scope="module")
def real_sweep(tmp_path_factory, sim_cache: Path) -> Path:
    sweep = tmp_path_factory.mktemp("real") / "sweep"
    proc = sweep_cli(sweep, ["particles=5,10", "seed=0,1", "dataset.duration_s=6", "dataset.rgbd=false", "texture=none",
                             "progress=off", "++hydra.callbacks.sweep_report._target_=slamlab.report.callback.SweepReportCallback"],
                     cache=sim_cache, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return sweep


def test_real_run_reports(real_sweep: Path) -> None:
    for i in range(4):
        run = real_sweep / str(i)
        page = (run / "report.html").read_text()  # written by the app (report: true)
        metrics = json.loads((run / "metrics.json").read_text())
        assert metrics["status"] == "ok"
        assert page.count("data:image/png;base64,") >= 3
        assert "ground truth" in page and 'id="filter"' in page
        assert f"particles={metrics['particles']}" in page


def test_real_sweep_report(real_sweep: Path, tmp_path: Path) -> None:
    by_callback = real_sweep / "report.html"
    assert by_callback.is_file(), "SweepReportCallback did not write the sweep report"
    out = tmp_path / "again.html"
    assert report_main([str(real_sweep), "-o", str(out)]) == 0
    for page in (by_callback.read_text(), out.read_text()):
        rows = dict(re.findall(r'<tr class="(\w+)" data-run="([^"]+)">', page)[i][::-1] for i in range(4))
        assert rows == {str(i): "ok" for i in range(4)}
        assert "versus particles" in page and "Mean and spread across seeds" in page
        for i in range(4):
            metrics = json.loads((real_sweep / str(i) / "metrics.json").read_text())
            body = re.search(rf'data-run="{i}">(.*?)</tr>', page, re.S).group(1)
            for spec in METRICS:
                v = get_metric(metrics, spec.key)
                if spec.table and v == v and not (spec.hide_when_zero and v == 0):
                    assert f'data-v="{v!r}"' in body, (i, spec.key)
