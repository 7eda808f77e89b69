"""A graph run's report draws its loop closures from loops.csv: accepted ones as segments
between the places they tie, rejected candidates as crosses, the counts from metrics.json."""

from __future__ import annotations

import json

import numpy as np

from slamlab.artifacts import write_table
from slamlab.io.rundir import RunFile
from slamlab.io.table import Table
from slamlab.report.loops_section import loops_figure, loops_section
from slamlab.report.rundir import load_run


def _loops(**changed: np.ndarray) -> Table:
    """Three candidates (two accepted, one ambiguous); `changed`: columns given other values."""
    return Table({**{
        "t": np.array([100.0, 110.0, 120.0]), "node": np.array([10, 11, 12]), "submap": np.array([0, 0, 1]),
        "anchor": np.array([0, 1, 2]), "t_anchor": np.array([10.0, 11.0, 12.0]),
        "status": np.array(["accepted", "ambiguous", "accepted"]), "score": np.array([0.9, 0.8, 0.7]),
        "refined": np.array([0.85, 0.8, 0.66]), "second": np.zeros(3), "window_m": np.ones(3), "tied_m": np.full(3, 40.0),
        "node_x": np.array([1.0, 2.0, 3.0]), "node_y": np.zeros(3), "match_x": np.array([1.5, 7.0, 3.2]), "match_y": np.zeros(3),
        "moved_m": np.array([0.5, 5.0, 0.2]), "final_x": np.array([1.4, 2.0, 3.1]), "final_y": np.array([0.1, 0.0, 0.2]),
        "anchor_x": np.array([-4.0, -3.0, -2.0]), "anchor_y": np.array([0.0, 1.0, 2.0]), "residual_m": np.array([0.01, 4.0, 0.02]),
        "sigma_along_m": np.array([0.03, 0.03, 10.0]),
    }, **changed})


def test_the_closures_are_drawn_where_they_tie_and_rejected_ones_where_they_pointed():
    fig = loops_figure(None, _loops(), None)
    lines = {ln.get_label(): ln for ln in fig.axes[0].get_lines()}
    full = lines["accepted closure"]
    assert list(full.get_xdata()) == [1.4, -4.0] and list(full.get_ydata()) == [0.1, 0.0]  # node to submap node
    corridor = lines["accepted, across a corridor only"]
    assert corridor.get_linestyle() == "--" and list(corridor.get_xdata()) == [3.1, -2.0]
    crosses = lines["rejected candidate (where it put the robot)"]
    assert list(crosses.get_xdata()) == [7.0]


def test_a_graph_runs_report_has_the_section_and_other_runs_do_not(tmp_path):
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / RunFile.METRICS).write_text(json.dumps({"status": "ok", "filter": "graph", "graph": {
        "nodes": 13, "submaps": 2, "searches": 9, "candidates": 3, "accepted": 2, "by_status": {"accepted": 2, "ambiguous": 1},
        "update_s": 0.1, "optimisations": 1, "optimise_s": 0.2, "search_s": 0.3, "largest_correction_m": 0.5, "redraws": 0}}))
    assert loops_section(load_run(run_dir)) is None  # no loops.csv: not a graph run
    write_table(run_dir / RunFile.LOOPS, _loops())
    section = loops_section(load_run(run_dir))
    assert section is not None and section.images
    assert "3 candidates: 2 accepted, rejected: 1 ambiguous" in section.note
    # the table: accepted closures, the one that moved the robot most first
    assert [r[2] for r in section.rows] == ["0.50", "0.20"] and section.rows[1][5] == "across a corridor"


def test_a_graph_runs_page_shows_no_particles(tmp_path):
    """One trajectory, no particles: the page's title, cards and filter section say so instead
    of drawing a flat N_eff of 1 and a best weight of 1 (a particle run keeps them)."""
    from report_fixtures import make_run_dir

    from slamlab.report.run_report import render_run_report

    particle_run = make_run_dir(tmp_path / "rbpf")
    graph_run = make_run_dir(tmp_path / "graph")
    metrics = json.loads((graph_run / RunFile.METRICS).read_text())
    metrics.update(filter="graph", particles=1, resample_count=0, neff_mean=1.0,
                   graph={"nodes": 300, "submaps": 30, "searches": 100, "candidates": 3, "accepted": 2})
    (graph_run / RunFile.METRICS).write_text(json.dumps(metrics))
    page = render_run_report(load_run(graph_run))
    assert "one trajectory" in page and "1 particle" not in page
    assert 'alt="N_eff over time"' not in page and "mean N_eff" not in page and ">resamples<" not in page
    assert 'alt="step time over time"' in page and "Filter over time" in page
    other = render_run_report(load_run(particle_run))
    assert 'alt="N_eff over time"' in other and "Particle filter over time" in other
    assert "mean N_eff" in other and ">resamples<" in other


def test_a_graph_run_has_no_particle_numbers_in_a_sweep_table():
    from slamlab.report.columns import get_metric

    graph = {"filter": "graph", "neff_mean": 1.0, "resample_count": 0, "runtime_s": 3.0, "graph": {"nodes": 10}}
    particles = {"filter": "rbpf", "neff_mean": 23.5, "resample_count": 2, "runtime_s": 3.0}
    assert np.isnan(get_metric(graph, "neff_mean")) and np.isnan(get_metric(graph, "resample_count"))
    assert get_metric(graph, "runtime_s") == 3.0
    assert get_metric(particles, "neff_mean") == 23.5 and get_metric(particles, "resample_count") == 2.0


def test_a_broken_stretch_says_whether_its_pass_was_tied_to_an_earlier_one():
    """`span_closures.closures_at`: the candidates searched from the stretch's own scans (and
    30 s after), the accepted ones tying it to a pass before it apart from those tying it to itself."""
    from slamlab.report.span_closures import closures_at

    loops = _loops()  # searched at 100, 110 and 120 s: accepted to 10 s, ambiguous, accepted to 12 s
    span = {"t1_s": 95.0, "t2_s": 105.0}  # with 30 s after it: all three
    assert closures_at(loops, span, 0.0) == ("2 accepted closures tie this pass to earlier ones (at 10–12 s; they moved the robot"
                                             " up to 0.50 m; the final graph left them at most 0.02 m off); rejected: 1 ambiguous")
    assert closures_at(loops, {"t1_s": 200.0, "t2_s": 210.0}, 0.0) == "none: no loop candidate was found from this pass"
    # times since the run's first scan (here 5 s into the log's clock)
    assert closures_at(loops, {"t1_s": 90.0, "t2_s": 100.0}, 5.0).startswith("2 accepted closures tie this pass to earlier ones (at 5–7 s;")
    # the third ties to 115 s (5 s before it: the pass itself), the first is left 0.8 m from its match
    loops = _loops(t_anchor=np.array([10.0, 11.0, 115.0]), residual_m=np.array([0.8, 4.0, 0.02]))
    assert closures_at(loops, span, 0.0) == ("1 accepted closure ties this pass to earlier ones (at 10 s; they moved the robot up"
                                             " to 0.50 m; the final graph left them at most 0.80 m off, 1 over 0.3 m: it disagrees"
                                             " with that one); 1 more tie it to itself; rejected: 1 ambiguous")
    # a closure to a node inside the stretch ties the pass to itself, however long ago in the stretch
    loops = _loops(t_anchor=np.array([10.0, 11.0, 60.0]), status=np.array(["refuted", "ambiguous", "accepted"]))
    assert closures_at(loops, {"t1_s": 50.0, "t2_s": 110.0}, 0.0) == ("no accepted closure ties this pass to an earlier one; 1 tie it"
                                                                       " to itself; rejected: 1 ambiguous, 1 refuted")


def test_a_broken_stretch_says_whether_the_path_had_been_there_before():
    """`span_closures.earlier_pass`: the last time the path was within 10 m of the stretch's
    poses before the visit the stretch belongs to, or None for a first pass; `closures_at`
    leads with it."""
    from slamlab.report.span_closures import closures_at, earlier_pass

    # a 1 m/s walk east along y = 0 for 100 s, north for 50 s, back west along y = 50 for 100 s, then south down x = 0
    t = np.arange(0.0, 300.0)
    xy = np.concatenate([np.column_stack([t[:100], np.zeros(100)]), np.column_stack([np.full(50, 100.0), np.arange(50.0)]),
                         np.column_stack([100.0 - np.arange(100.0), np.full(100, 50.0)]), np.column_stack([np.zeros(50), 50.0 - np.arange(50.0)])])
    # going south down x = 0 it comes back within 10 m of where it was at 9 s (x = 9, y = 0) when it reaches y = 10
    assert earlier_pass(t, xy, 295.0, 299.0) == 9.0
    # the walk back along y = 50 passes 50 m from the first leg: a first pass; the stretch's own approach does not count
    assert earlier_pass(t, xy, 200.0, 210.0) is None
    # the stretch at the corner (100, 50): the path came up the east side from (100, 40) on, the same visit
    assert earlier_pass(t, xy, 150.0, 151.0) is None
    loops = _loops()  # searched at 100, 110 and 120 s: accepted to 10 s, ambiguous, accepted to 12 s
    assert closures_at(loops, {"t1_s": 200.0, "t2_s": 210.0}, 0.0, (t, xy)) == (
        "a first pass here (the path had not come within 10 m of it before): no loop to close; no loop candidate was found from this pass")
    # a revisit names when the path was there; a first pass with closures of its own counts them as closures
    assert closures_at(loops, {"t1_s": 295.0, "t2_s": 299.0}, 0.0, (t, xy)).startswith("back where the path was at 9 s; ")
    # a run whose loop search found nothing at all (loops.csv without rows): the same lead
    from slamlab.io.table import Table

    assert closures_at(Table({}), {"t1_s": 295.0, "t2_s": 299.0}, 0.0, (t, xy)) == (
        "back where the path was at 9 s; no loop candidate was found from this pass")
    assert closures_at(Table({}), {"t1_s": 200.0, "t2_s": 210.0}, 0.0, None) == "none: no loop candidate was found from this pass"
    own = _loops(t_anchor=np.array([100.0, 101.0, 102.0]), status=np.array(["accepted", "ambiguous", "accepted"]))
    assert closures_at(own, {"t1_s": 95.0, "t2_s": 105.0}, 0.0, (t, xy)) == (
        "a first pass here (the path had not come within 10 m of it before): no loop to close; 2 closures tie it to itself;"
        " rejected: 1 ambiguous")
