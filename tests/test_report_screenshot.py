"""Both reports open in headless Chromium (no network), render to a screenshot that is not
blank, and show what they should: their sections, decoded images, the run's error and the
sweep's failed run.
Skips when Chromium is not installed (apt-get install -y chromium), unless
SLAMLAB_REQUIRE_BROWSER=1 (set by .ci/run, which installs it): then it fails."""

from __future__ import annotations

import importlib.util
import json
import os
from pathlib import Path

import numpy as np
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


def _not_blank(png: Path) -> None:
    """A rendered page, not an empty or single-colour one: many colours, much ink."""
    from PIL import Image

    img = np.asarray(Image.open(png).convert("RGB"))
    assert len(np.unique(img.reshape(-1, 3), axis=0)) > 100
    assert np.mean(np.any(img < 200, axis=2)) > 0.02  # more than 2 % of pixels are not near-white


def test_reports_render_in_chromium(tmp_path: Path) -> None:
    root = tmp_path / "sweep"
    runs = make_sweep(root, particles_seed_grid([5, 10], [0]), ["particles=5,10"], failures={1: "metrics"}, n_steps=60)
    run_page, sweep_page = write_run_report(runs[0]), build_sweep_report([root], root)
    for page, name in ((run_page, "run.png"), (sweep_page, "sweep.png")):
        png = shots.screenshot(page, tmp_path / name, 1200, 1600)
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        _not_blank(png)

    # what a reader sees, asked from inside Chromium once every image has loaded
    run = shots.page_facts(run_page, 1200)
    assert run["broken"] == [] and run["images"] >= 4
    assert {"summary", "map", "errors", "filter", "metrics"} <= set(run["sections"])
    assert run["section_images"]["map"] == 1 and run["section_images"]["errors"] == 1
    rmse = json.loads((runs[0] / "metrics.json").read_text())["trajectory"]["rmse_m"]
    assert f"{rmse:.4f}" in run["text"] and "ATE RMSE (m)" in run["text"]

    sweep = shots.page_facts(sweep_page, 1200)
    assert sweep["broken"] == [] and sweep["images"] >= 4
    assert sweep["sections"][0] == "verdict" and {"runs", "failed", "maps"} <= set(sweep["sections"])
    assert {"run", "status", "particles", "ATE RMSE (m)"} <= set(sweep["headers"])
    assert "2 runs (1 ok, 1 failed or incomplete)" in sweep["text"]


TABLE_JS = """function () {
  var t = document.getElementById('runs-table'), box = t.parentNode, all = document.getElementById('all-columns');
  var seen = function () { return Array.prototype.filter.call(t.querySelectorAll('thead th'), function (h) {
    return h.offsetWidth > 0; }).map(function (h) { return h.textContent.trim(); }); };
  var first = {table: t.scrollWidth, box: box.clientWidth, headers: seen()};
  all.click();
  first.all = seen();
  return first;
}"""


def test_the_every_run_table_fits_a_1400_px_window(tmp_path: Path) -> None:
    """Issue 45: the sweep's table showed ~12 of its 22 columns at 1400 px (time, memory and
    N_eff needed scrolling). At 1400 px it fits without scrolling, with the time, memory and
    N_eff columns in view; "all columns" shows the rest."""
    root = tmp_path / "sweep"
    make_sweep(root, particles_seed_grid([5, 10, 20, 50], [0, 1, 2], ["dataset.duration_s=10"]),
               ["particles=5,10,20,50", "seed=0,1,2", "dataset.duration_s=10"], failures={4: "metrics"}, texture=True)
    facts = shots.page_facts(build_sweep_report([root], root), 1400, TABLE_JS)
    assert facts["table"] <= facts["box"], f"the table is {facts['table']} px wide in a {facts['box']} px box"
    assert {"wall time (s)", "CPU time (s)", "peak memory (MB)", "N_eff mean", "ATE RMSE (m)",
            "beams contradicting map"} <= {h.replace("\u00ad", "") for h in facts["headers"]}  # soft hyphens aside
    assert len(facts["all"]) > len(facts["headers"]) >= 15
    assert "N_eff min" in facts["all"] and "N_eff min" not in facts["headers"]


def _fabricated_replay(run: Path, particles: int = 20, snaps: int = 12) -> None:
    """replay.npz in a fabricated run (docs/RUN_DIRECTORY.md's layout): the room map at every
    snapshot, particles around the path, a few scan points; and N_eff at N all along, so its
    curve runs along the top of its strip."""
    import pandas as pd

    from slamlab.io.rundir import RunDirectory

    steps = pd.read_csv(run / "steps.csv")
    steps["neff"] = float(particles)
    steps.to_csv(run / "steps.csv", index=False)
    k = np.linspace(0, len(steps) - 1, snaps).round().astype(int)
    rng = np.random.default_rng(0)
    room = np.full((80, 120), 255, np.uint8)
    room[[0, -1], :] = 0
    room[:, [0, -1]] = 0
    xy = np.column_stack([np.linspace(0.5, 9.5, snaps), np.full(snaps, 0.5)])
    RunDirectory(run).write_replay(
        step=k, scan_index=k * 2, t=np.asarray(steps["t"])[k], best=np.zeros(snaps, np.int64),
        poses=np.concatenate([xy[:, None, :] + rng.normal(0, 0.1, (snaps, particles, 2)), np.zeros((snaps, particles, 1))], 2).astype(np.float32),
        scan_xy=np.repeat(xy, 5, axis=0).astype(np.float32), scan_count=np.full(snaps, 5),
        map_pixels=np.concatenate([room.ravel()] * snaps), map_shape=np.tile([80, 120], (snaps, 1)),
        map_extent=np.tile([-1.0, 11.0, -1.0, 7.0], (snaps, 1)))


REPLAY_JS = """function () {
  var n = document.getElementById('replay-neff'), c = n.getContext('2d');
  var band = c.getImageData(0, 0, n.width, 16).data, blue = 0;
  for (var i = 0; i < band.length; i += 4) if (band[i] < 80 && band[i + 1] > 90 && band[i + 1] < 150 && band[i + 2] > 150) blue++;
  var m = document.getElementById('replay-canvas'), mc = m.getContext('2d');
  var bar = mc.getImageData(12, m.height - 15, 40, 4).data, dark = 0;
  for (var j = 0; j < bar.length; j += 4) if (bar[j] < 40 && bar[j + 1] < 40 && bar[j + 2] < 40) dark++;
  var data = JSON.parse(document.getElementById('replay-data').textContent);
  return {blue_in_label_band: blue, dark_bar_pixels: dark, scale: data.scale, w: data.w, window: data.window};
}"""


def test_the_replay_has_a_scale_bar_and_its_neff_label_clear_of_the_curve(tmp_path: Path) -> None:
    """Issue 45: the replay's maps had no scale, and the N_eff strip's label was crossed by its
    curve (a curve at N ran through it)."""
    from report_fixtures import make_run_dir

    run = make_run_dir(tmp_path / "r", overrides=["particles=20"], n_steps=80)
    _fabricated_replay(run)
    facts = shots.page_facts(write_run_report(run), 1400, REPLAY_JS)
    assert facts["blue_in_label_band"] == 0
    scale = facts["scale"]
    assert scale["m"] in (1.0, 2.0, 5.0, 10.0) and 60 <= scale["px"] <= 200
    x0, x1 = facts["window"][:2]
    assert abs(scale["px"] - scale["m"] * facts["w"] / (x1 - x0)) < 0.01  # its length is its metres
    assert facts["dark_bar_pixels"] >= 100  # drawn: a 4-pixel black bar under its label
