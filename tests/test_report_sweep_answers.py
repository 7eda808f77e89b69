"""What the sweep report concludes (issue 14): the verdict and its ties, plots with one line
per value of a second parameter, texture metrics, wall versus CPU time, and reports over
odd mixes of runs (killed, interrupted, from other sweeps, without ground truth) that
raise no warning and drop no section."""

from __future__ import annotations

import html
import json
import logging
import math
import os
import re
import warnings
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from report_fixtures import make_run_dir, make_sweep, particles_seed_grid
from slamlab.cli.report import main as report_main
from slamlab.report import build_sweep_report
from slamlab.report.rundir import load_run
from slamlab.report.sweep_report import _x_axis, headline_keys, param_series, runs_dataframe, swept_parameters
from slamlab.report.sweep_stats import overlapping_runs, runtime_check, sweep_verdict


def _table(rows: list[tuple[int, int, float]]) -> pd.DataFrame:
    """A runs table of (particles, seed, ATE RMSE) rows, every run successful."""
    return pd.DataFrame([{"status": "ok", "particles": p, "seed": s, "trajectory.rmse_m": v} for p, s, v in rows])


def test_verdict_calls_differences_within_the_seed_spread_ties() -> None:
    # The case: 100 vs 150 particles at 0.03756 vs 0.03757 m is a tie, 50 is worse.
    df = _table([(50, 0, 0.0600), (50, 1, 0.0620), (100, 0, 0.03750), (100, 1, 0.03762),
                 (150, 0, 0.03751), (150, 1, 0.03763)])
    v = sweep_verdict(df, ["particles"], "trajectory.rmse_m")
    assert [(s.stat.label, s.verdict) for s in v.standings] == [
        ("particles=100", "best"), ("particles=150", "tie"), ("particles=50", "worse")]
    assert v.standings[0].stat.n == 2
    assert math.isclose(v.standings[0].stat.mean, 0.03756)
    assert math.isclose(v.standings[1].diff, 0.00001, abs_tol=1e-12)
    assert v.spread_known
    assert "Best ATE RMSE (m): particles=100" in v.summary and "Tied with it" in v.summary
    assert "particles=150" in v.summary and "particles=50" not in v.summary


def test_verdict_with_one_seed_says_the_spread_is_unknown() -> None:
    # issue 45: 150 particles was "worse?" for 8e-6 m; a difference under 1 % of the best is a
    # tie whatever the spread, a larger one stays "worse?" (ranked by a single run)
    df = _table([(50, 0, 0.060), (100, 0, 0.037560), (150, 0, 0.037568), (200, 0, 0.0385)])
    v = sweep_verdict(df, ["particles"], "trajectory.rmse_m")
    assert not v.spread_known
    assert [(s.stat.label, s.verdict) for s in v.standings] == [
        ("particles=100", "best"), ("particles=150", "tie"), ("particles=200", "worse?"), ("particles=50", "worse?")]
    assert all(math.isnan(s.spread) for s in v.standings)
    assert "spread is unknown" in v.summary and "Within 1% of it, a tie whatever the spread: particles=150." in v.summary


def test_verdict_prefers_higher_for_max_metrics_and_skips_failed_runs() -> None:
    df = pd.DataFrame([
        {"status": "ok", "particles": 5, "map.agreement": 0.90},
        {"status": "ok", "particles": 10, "map.agreement": 0.95},
        {"status": "failed", "particles": 20, "map.agreement": 0.99},  # never counted
    ])
    v = sweep_verdict(df, ["particles"], "map.agreement")
    assert [s.stat.label for s in v.standings] == ["particles=10", "particles=5"]


def _two_parameter_sweep(root: Path, **kwargs) -> list[Path]:
    jobs = [[f"particles={p}", f"resampler={r}", f"seed={s}"]
            for p in (5, 20) for r in ("systematic", "residual") for s in (0, 1)]
    return make_sweep(root, jobs, ["particles=5,20", "resampler=systematic,residual", "seed=0,1"], **kwargs)


def test_two_parameters_give_one_line_per_value_of_the_other(tmp_path: Path) -> None:
    paths = _two_parameter_sweep(tmp_path / "sw", texture=True, n_steps=40)
    runs = [load_run(p) for p in paths]
    swept, values, _ = swept_parameters(runs)
    assert swept == ["particles", "resampler", "seed"]
    df = runs_dataframe(runs, [p.name for p in paths], swept, values)
    ok = df.assign(_x=_x_axis(df["particles"].tolist())[0])
    series = param_series(ok, "particles", ["resampler"], "trajectory.rmse_m")
    assert [s.label for s in series] == ["resampler=systematic", "resampler=residual"]
    for s in series:
        resampler = s.label.split("=")[1]
        runs_of = df[df["resampler"] == resampler]
        assert list(s.x) == [5.0, 20.0]
        assert list(s.mean) == pytest.approx(runs_of.groupby("particles")["trajectory.rmse_m"].mean().tolist())
        assert list(s.std) == pytest.approx(runs_of.groupby("particles")["trajectory.rmse_m"].std().tolist())
        assert len(s.points_y) == 4  # 2 particle counts x 2 seeds
    # Categorical axis: resampler names as ticks in the order the sweep listed them
    # (systematic,residual), one line per particle count.
    xs, cats = _x_axis(df["resampler"].tolist())
    assert cats == ["systematic", "residual"]
    by_res = param_series(df.assign(_x=xs), "resampler", ["particles"], "trajectory.rmse_m")
    assert [s.label for s in by_res] == ["particles=5", "particles=20"]
    # Every headline question has its metric here: accuracy, rotation, CPU time, memory, texture.
    assert headline_keys(df) == ["trajectory.rmse_m", "trajectory.rot_rmse_deg", "cpu_time_s", "peak_memory_mb",
                                 "texture.colour_error"]
    page = build_sweep_report([tmp_path / "sw"], tmp_path / "sw").read_text()
    assert "versus particles, one line per resampler" in page
    assert "versus resampler, one line per particles" in page


def test_texture_metrics_in_table_and_csv(tmp_path: Path) -> None:
    root = tmp_path / "sw"
    make_sweep(root, particles_seed_grid([5, 20], [0]), ["particles=5,20"], texture=True, n_steps=40)
    page = build_sweep_report([root], root).read_text()
    head = re.search(r'id="runs-table">\s*<thead><tr>(.*?)</tr>', page, re.S).group(1)
    headers = re.findall(r">([^<>]+)</th>", head)
    assert "texture colour err" in headers and "texture err (odometry)" in headers
    assert headers.index("CPU time (s)") == headers.index("wall time (s)") + 1  # beside each other
    csv = pd.read_csv(root / "runs.csv", dtype={"run": str}).set_index("run")
    for job in ("0", "1"):
        tex = json.loads((root / job / "metrics.json").read_text())["texture"]
        assert csv.loc[job, "texture.colour_error"] == tex["colour_error"]
        assert csv.loc[job, "texture.odometry.colour_error"] == tex["odometry"]["colour_error"]
        assert csv.loc[job, "texture.covered_area_m2"] == tex["covered_area_m2"]
        assert f'data-v="{tex["colour_error"]!r}"' in page


def _set_span(run: Path, start: float, end: float) -> None:
    os.utime(run / ".hydra" / "config.yaml", (start, start))
    os.utime(run / "metrics.json", (end, end))


def test_wall_time_flagged_when_runs_overlap_or_wait_for_cores(tmp_path: Path) -> None:
    root = tmp_path / "sw"
    paths = make_sweep(root, particles_seed_grid([5, 10, 20], [0]), ["particles=5,10,20"], n_steps=40)
    for i, p in enumerate(paths):  # one after the other
        _set_span(p, 1000.0 + 100 * i, 1050.0 + 100 * i)
    runs = [load_run(p) for p in paths]
    swept, values, _ = swept_parameters(runs)
    df = runs_dataframe(runs, ["0", "1", "2"], swept, values)
    check = runtime_check(df, runs)
    assert overlapping_runs(runs) == 0 and check.comparable and "wall times compare" in check.note

    _set_span(paths[1], 1020.0, 1080.0)  # started while run 0 was running
    assert overlapping_runs(runs) == 2
    check = runtime_check(df, runs)
    assert not check.comparable and "2 of 3 runs ran at the same time" in check.note
    assert "compare CPU time" in check.note

    _set_span(paths[1], 1100.0, 1150.0)
    loaded = df.assign(cpu_time_s=df["runtime_s"] / 2.4)  # waited for the cores: wall = 2.4 x CPU
    check = runtime_check(loaded, runs)
    assert not check.comparable and "2.4" in check.note and "3 of 3 runs" in check.note

    no_cpu = df.assign(cpu_time_s=float("nan"))  # runs from before metrics had cpu_time_s
    assert "do not record CPU time" in runtime_check(no_cpu, runs).note

    page = build_sweep_report([root], root).read_text()
    assert 'id="runtime-note"' in page


@pytest.mark.slow
def test_report_over_killed_interrupted_and_mixed_runs_warns_nothing(tmp_path: Path, caplog, capsys) -> None:
    """slamlab-report over runs of two different sweeps, a killed one (no metrics), an
    interrupted one and a lone run without ground truth: no numpy warnings, no section
    dropped (every `_safe` failure is logged as a warning), captions match what is drawn."""
    a = tmp_path / "a"
    make_sweep(a, particles_seed_grid([5, 10], [0, 1]), ["particles=5,10", "seed=0,1"], failures={1: "log"}, n_steps=50)
    (a / "2" / "metrics.json").write_text(json.dumps({"status": "interrupted", "error": "KeyboardInterrupt"}))
    b = tmp_path / "b"
    make_sweep(b, [["resampler=residual"], ["resampler=stratified"]], ["resampler=residual,stratified"], n_steps=50)
    lone = make_run_dir(tmp_path / "lone", overrides=[], n_steps=50, groundtruth=False)
    out = tmp_path / "out"
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any RuntimeWarning fails the report build
        with caplog.at_level(logging.WARNING, logger="slamlab.report"):
            assert report_main([str(a), str(b), str(lone), "-o", str(out)]) == 0
    assert [r.getMessage() for r in caplog.records if "failed" in r.getMessage()] == []
    assert "expected str instance" not in capsys.readouterr().err
    page = (out / "report.html").read_text()
    for section in ("verdict", "runs", "failed", "params", "errors", "maps", "neff", "config"):
        assert f'<section id="{section}"' in page, section
    assert "incomplete" in page and "interrupted" in page
    # A run without a swept key sits in its own "–" group instead of breaking the grouping.
    assert "resampler=–" in page or "particles=–" in page


def test_captions_say_no_ground_truth_when_there_is_none(tmp_path: Path) -> None:
    root = tmp_path / "sw"
    make_sweep(root, particles_seed_grid([5, 10], [0]), ["particles=5,10"], groundtruth=False, n_steps=50)
    page = build_sweep_report([root], root).read_text()
    overlay = re.search(r'alt="trajectories of all runs on one map">\s*<p class="note">(.*?)</p>', page, re.S).group(1)
    assert "ground truth" not in overlay.replace("no ground truth", "")
    assert "no ground truth" in overlay and "dashed red: odometry" in overlay
    assert "No run has ground truth or relations" in page
    assert "thin black" not in page


def test_relation_error_over_time_from_the_runs_relations_file(tmp_path: Path) -> None:
    """A CARMEN-style run: no ground truth, its relations.csv written as the pipeline writes
    it. Each relation's error is the mismatch between the estimated and the recorded motion,
    placed at the time of its later scan."""
    from slamlab.artifacts import write_table, write_tum
    from slamlab.frames import Relations
    from slamlab.pipeline import relation_table
    from slamlab.report.error_series import RELATIONS, error_series

    run = make_run_dir(tmp_path / "run", overrides=[], n_steps=20, groundtruth=False)
    t = 100.0 + np.arange(6, dtype=float)
    poses = np.column_stack([np.arange(6, dtype=float), np.zeros(6), np.zeros(6)])  # 1 m steps along x
    write_tum(run / "trajectory.tum", t, poses)
    # Recorded motions: 1 m (exact), 1.2 m (the estimate is 0.2 m short), 2 m over two steps.
    rel = Relations(np.array([101.0, 102.0, 103.0]), np.array([102.0, 103.0, 105.0]),
                    np.array([[1.0, 0, 0], [1.2, 0, 0], [2.0, 0, 0]]), "mini.relations")
    seq = SimpleNamespace(relations=rel)
    result = SimpleNamespace(times=t, trajectory=poses, odometry=poses)
    write_table(run / "relations.csv", relation_table(seq, result))  # type: ignore[arg-type]
    es = error_series(load_run(run))
    assert es is not None and es.kind == RELATIONS
    assert es.t.tolist() == [2.0, 3.0, 5.0]  # later scan of each relation, s after the first pose
    assert es.error_m == pytest.approx([0.0, 0.2, 0.0], abs=1e-9)


def test_verdict_table_rows_and_cheapest_of_the_ties() -> None:
    from slamlab.report.sweep_report import _verdict_section

    df = _table([(50, 0, 0.10), (50, 1, 0.12), (100, 0, 0.105), (100, 1, 0.125), (150, 0, 0.16), (150, 1, 0.16)])
    df["cpu_time_s"] = [1.0, 1.2, 2.0, 2.2, 3.0, 3.0]
    df["runtime_s"] = df["cpu_time_s"] * 3
    section = _verdict_section(df, ["particles"], [])
    rows = {r["label"]: r for r in section["rows"]}
    assert [r["verdict"] for r in section["rows"]] == ["best", "tie", "worse"]
    assert rows["particles=150"]["diff"] == "0.05 (+45.5 % of best)"  # 0.16 - 0.11, relative to the best's 0.11
    assert rows["particles=50"]["cost"] == "1.1" and rows["particles=100"]["cost"] == "2.1"  # CPU, not wall
    assert "cheapest is particles=50 (CPU time (s): 1.1" in section["cheapest"]


def test_verdict_over_seeds_of_one_configuration_names_no_winner() -> None:
    df = _table([(100, 0, 0.05), (100, 1, 0.07)])
    v = sweep_verdict(df, [], "trajectory.rmse_m")
    assert len(v.standings) == 1
    assert v.summary == "One configuration (all runs): ATE RMSE (m) 0.06 ± 0.014 over 2 seeds; nothing to compare."


# ---- issue 45: slamlab-report over mixed runs -------------------------------------------------
def test_a_run_of_the_defaults_is_labelled_with_what_it_used(tmp_path: Path) -> None:
    """A run without `particles=` ran the default 100: it is the same configuration as an
    explicit particles=100, not "particles=–" tying with it."""
    default = make_run_dir(tmp_path / "default", overrides=[], n_steps=40)
    hundred = make_run_dir(tmp_path / "p100", overrides=["particles=100"], n_steps=40)
    fifty = make_run_dir(tmp_path / "p50", overrides=["particles=50"], n_steps=40)
    runs = [load_run(p) for p in (default, hundred, fifty)]
    swept, values, _ = swept_parameters(runs)
    assert swept == ["particles"] and values["particles"] == [100, 100, 50]
    page = build_sweep_report([default, hundred, fifty], tmp_path / "out").read_text()
    assert "particles=–" not in page
    verdict = page[page.index('<section id="verdict">'):page.index("</section>", page.index('<section id="verdict">'))]
    assert re.search(r"<td class=\"text\">particles=100</td><td>2</td>", verdict)  # both runs of 100, as seeds of one


def test_runs_scored_another_way_get_their_own_verdict(tmp_path: Path) -> None:
    """A simulated run (ATE) beside a log run (relations): two verdicts, none left out."""
    sim = make_run_dir(tmp_path / "sim", overrides=["particles=50"], n_steps=40)
    log = make_run_dir(tmp_path / "log", overrides=["particles=30", "dataset.path=/data/intel.clf.bz2"], n_steps=40,
                       groundtruth=False)
    m = json.loads((log / "metrics.json").read_text())
    m["dataset"] = "intel"
    m["relations"] = {"count": 100, "trans_abs_mean_m": 0.021, "rot_abs_mean_deg": 0.3}
    (log / "metrics.json").write_text(json.dumps(m))
    lone = make_run_dir(tmp_path / "lone", overrides=["particles=10"], n_steps=40, groundtruth=False)
    m = json.loads((lone / "metrics.json").read_text())
    m.pop("consistency")
    (lone / "metrics.json").write_text(json.dumps(m))
    page = build_sweep_report([sim, log, lone], tmp_path / "out").read_text()
    assert "Runs scored against ground truth (ATE): 1 of 3" in page
    assert "Runs scored against benchmark relations: 1 of 3" in page
    assert "Not ranked (no ground truth, relations or consistency score): run lone." in page


def test_neff_of_runs_of_very_different_lengths_is_drawn_against_the_share_of_each_run(tmp_path: Path) -> None:
    import pandas as pd

    short = make_run_dir(tmp_path / "short", overrides=["particles=50"], n_steps=40)
    long = make_run_dir(tmp_path / "long", overrides=["particles=30"], n_steps=40)
    steps = pd.read_csv(long / "steps.csv")
    steps["t"] = np.linspace(0.0, 2650.0, len(steps))
    steps.to_csv(long / "steps.csv", index=False)
    steps = pd.read_csv(short / "steps.csv")
    steps["t"] = np.linspace(0.0, 85.0, len(steps))
    steps.to_csv(short / "steps.csv", index=False)
    runs = [load_run(short), load_run(long)]
    from slamlab.report import sweep_report

    captured = {}
    real = sweep_report.figures.neff_overlay
    sweep_report.figures.neff_overlay = lambda curves, ylabel, xlabel: captured.update(curves=curves, xlabel=xlabel) or real(curves, ylabel, xlabel)
    try:
        img, note = sweep_report._neff(runs, [0, 1], ["short", "long"], ["short", "long"])
    finally:
        sweep_report.figures.neff_overlay = real
    assert img is not None and "share of each run" in note and "85 to 2650 s" in note
    assert captured["xlabel"] == "share of the run (%)"
    for _, t, _ in captured["curves"]:
        assert t[0] == 0.0 and t[-1] == pytest.approx(100.0)


def test_a_graph_run_is_left_out_of_the_neff_overlay_and_named_in_its_note(tmp_path: Path) -> None:
    rbpf = make_run_dir(tmp_path / "rbpf", overrides=["particles=30"], n_steps=40)
    graph = make_run_dir(tmp_path / "graph", overrides=["particles=30"], n_steps=40)
    m = json.loads((graph / "metrics.json").read_text())
    m["graph"] = {"nodes": 40, "accepted": 3}  # what a filter=graph run writes beside its flat N_eff of 1
    (graph / "metrics.json").write_text(json.dumps(m))
    runs = [load_run(rbpf), load_run(graph)]
    from slamlab.report import sweep_report

    captured = {}
    real = sweep_report.figures.neff_overlay
    sweep_report.figures.neff_overlay = lambda curves, ylabel, xlabel: captured.update(curves=curves) or real(curves, ylabel, xlabel)
    try:
        img, note = sweep_report._neff(runs, [0, 1], ["rbpf run", "graph run"], ["rbpf", "graph"])
    finally:
        sweep_report.figures.neff_overlay = real
    assert img is not None and [c[0] for c in captured["curves"]] == ["rbpf run"]
    assert "Not drawn: graph run (one trajectory" in note


def test_the_ladder_sweep_ranks_no_step_against_another(tmp_path: Path) -> None:
    steps = ["ladder_first_scan", "ladder_dead_reckoning", "ladder_predict", "ladder_few_particles", "ladder_full"]
    root = tmp_path / "ladder"
    make_sweep(root, [["+experiment=ladder", f"experiment={s}"] for s in steps], ["+experiment=ladder"], n_steps=40)
    page = build_sweep_report([root], root).read_text()
    assert "The ladder's steps" in page and "not ranked against the others" in page
    assert "Best ATE" not in page and 'class="best"' not in page and 'class="v-best"' not in page


def test_an_interrupted_runs_partial_results_are_drawn_and_not_ranked(tmp_path: Path) -> None:
    """Issue 45: slamlab-report on an interrupted run said "No run wrote a map" and "No run has
    ground truth" beside a table showing its ATE."""
    run = make_run_dir(tmp_path / "int", overrides=["particles=30"], n_steps=40)
    m = json.loads((run / "metrics.json").read_text())
    m.update(status="interrupted", partial=True, error="interrupted at scan 40/300; partial results in int",
             interrupted_at_scan=40, scans_total=300)
    (run / "metrics.json").write_text(json.dumps(m))
    page = build_sweep_report([run], tmp_path / "out").read_text()
    assert "No run wrote a map" not in page and "No run has ground truth" not in page
    assert 'alt="map of int (interrupted)"' in page  # its map, marked
    assert 'alt="error over time of every run"' in page and 'alt="N_eff curves of all runs"' in page
    assert '<section id="verdict">' not in page  # nothing finished: nothing ranked
    both = build_sweep_report([run, make_run_dir(tmp_path / "ok", overrides=["particles=50"], n_steps=40)],
                              tmp_path / "out2").read_text()
    assert "1 failed or incomplete run not counted" in both and 'alt="map of int: particles=30 (interrupted)"' in both


def test_the_table_says_whose_peak_memory_it_shows(tmp_path: Path) -> None:
    from slamlab.pipeline import SCOPE_REUSED

    root = tmp_path / "sw"
    paths = make_sweep(root, particles_seed_grid([5, 10, 20], [0]), ["particles=5,10,20"], n_steps=30)
    page = html.unescape(build_sweep_report([root], root).read_text())
    assert "each run's own peak resident memory" in page
    m = json.loads((paths[2] / "metrics.json").read_text())
    m["peak_memory_scope"] = SCOPE_REUSED
    (paths[2] / "metrics.json").write_text(json.dumps(m))
    page = html.unescape(build_sweep_report([root], root).read_text())
    assert "2 of 3 runs show their own peak" in page and "Run 2 ran in a process that had run others before" in page
