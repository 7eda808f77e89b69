"""The run report's map-consistency section (issue 45): the verdict in one line at the top,
the map with where its scans contradict it and the broken stretches circled, and the share
over time, all read from the run's files (metrics.json, consistency_map.npz, consistency.csv)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from report_fixtures import make_run_dir
from slamlab import artifacts
from slamlab.assemble import build_components
from slamlab.eval.consistency import consistency_metrics
from slamlab.io.atomic import json_ready
from slamlab.io.rundir import RunDirectory, RunFile
from slamlab.report.consistency_section import curve_figure, overlay_figure
from slamlab.report.extra_sections import SECTIONS, ExtraSection
from slamlab.report.rundir import load_run
from slamlab.report.run_report import write_run_report
from slamlab.slam.engine import run_slam
from slamlab.slam.mapping import map_from_trajectory
from test_slam_engine import _cfg, _room_sequence


def _run_with_verdict(root: Path, broken: bool) -> tuple[Path, object]:
    """A run folder whose map, path and consistency files come from the room sequence: its
    own map, or (broken) the map of a path moved 0.4 m and 5 degrees from half-way."""
    seq = _room_sequence(80)
    settings = build_components(_cfg("mode=odometry")).map
    res = run_slam(seq, build_components(_cfg("mode=odometry")))
    poses, grid = res.trajectory, res.log_odds
    if broken:
        poses = poses.copy()
        poses[40:] += np.array([0.4, 0.0, np.radians(5.0)])
        grid = map_from_trajectory(seq, poses, settings)
    cons = consistency_metrics(seq, poses, grid, settings)
    run = make_run_dir(root, groundtruth=False)
    files = RunDirectory(run)
    artifacts.write_map(run, grid)
    files.write_trajectory("slam", res.times, poses)
    artifacts.write_consistency(run, cons.series)
    files.write_consistency_map(cons.overlay)
    metrics = json.loads((run / RunFile.METRICS).read_text())
    metrics["consistency"] = json_ready(cons.summary)
    (run / RunFile.METRICS).write_text(json.dumps(metrics))
    return run, cons


def test_a_consistent_run_says_so_in_one_line_at_the_top(tmp_path: Path) -> None:
    run, cons = _run_with_verdict(tmp_path / "good", broken=False)
    page = write_run_report(run).read_text()
    top = page[page.index('id="summary"'):page.index('id="map"')]
    assert '<p class="verdict good" id="verdict-line"><b>Map consistency:</b> Consistent: no stretch' in top
    assert 'id="consistency"' in page and 'alt="where the scans contradict the map"' in page
    assert 'id="broken-spans"' not in page  # nothing to list
    assert "beams contradicting the map over time" in page
    loaded = load_run(run)
    fig = overlay_figure(loaded.load_map(), loaded.files.read_arrays(RunFile.CONSISTENCY_MAP), [], None)
    events = fig.axes[0].get_images()[-1].get_array()  # RGBA bytes (`figures.rgba_bytes`)
    assert (events[..., 3] > 0.9 * 255).sum() == 0  # nothing strong: a consistent map's few contradictions stay pale


def test_a_broken_run_names_where_and_when_and_circles_it_on_the_map(tmp_path: Path) -> None:
    run, cons = _run_with_verdict(tmp_path / "bad", broken=True)
    page = write_run_report(run).read_text()
    span = cons.spans[0]
    line = f"Likely broken near ({span.x_m:.1f}, {span.y_m:.1f}) m, between {span.t1_s:.0f} s and {span.t2_s:.0f} s"
    assert '<p class="verdict bad" id="verdict-line"><b>Map consistency:</b> ' + line in page
    assert 'id="broken-spans"' in page and f"({span.x_m:.1f}, {span.y_m:.1f}) m, within {span.radius_m:.1f} m" in page
    # the figures' data: the first broken stretch circled where the verdict says, the
    # contradicting cells drawn over the map, the stretches shaded on the curve
    loaded = load_run(run)
    spans = loaded.metrics["consistency"]["broken_spans"]
    layers = loaded.files.read_arrays(RunFile.CONSISTENCY_MAP)
    fig = overlay_figure(loaded.load_map(), layers, spans, loaded.load_trajectory("slam"))
    ax = fig.axes[0]
    circles = [ln for ln in ax.get_lines() if len(ln.get_xdata()) == 90]
    assert len(circles) == len(spans)
    cx, cy = np.mean(circles[0].get_xdata()), np.mean(circles[0].get_ydata())
    assert abs(cx - span.x_m) < 0.1 and abs(cy - span.y_m) < 0.1
    events = ax.get_images()[-1].get_array()  # RGBA bytes (`figures.rgba_bytes`)
    assert (events[..., 3] > 0.9 * 255).sum() > 20  # the broken stretch's contradicting cells, drawn strong
    curve = curve_figure(loaded.files.read_columns(RunFile.CONSISTENCY), 0.4, spans)
    shaded = [p for p in curve.axes[0].patches]
    assert len(shaded) == len(spans)
    assert any(abs(line.get_ydata()[0] - 0.4) < 1e-12 for line in curve.axes[0].get_lines() if len(line.get_ydata()) == 2)


def test_an_extra_section_is_drawn_from_its_own_files(tmp_path: Path, monkeypatch) -> None:
    """The place left for sections only some runs have (a pose graph's loop closures): a
    function of the run that returns its section, or None."""
    run = make_run_dir(tmp_path / "r")
    (run / "closures.txt").write_text("3 closures")

    def closures(r):
        f = r.file("closures.txt")
        return None if f is None else ExtraSection("closures", "Loop closures", note=f.read_text(),
                                                   columns=["from", "to"], rows=[["12 s", "340 s"]])

    def failing(r):
        raise ValueError("a broken file")

    monkeypatch.setattr("slamlab.report.extra_sections.SECTIONS", [failing, closures])
    page = write_run_report(run).read_text()
    assert '<section id="closures">' in page and "3 closures" in page and "340 s" in page
    assert '<a href="#closures">Loop closures</a>' in page
    from slamlab.report.loops_section import loops_section

    assert SECTIONS == [loops_section]  # the one built in: a graph run's loop closures


def test_an_overlay_handed_over_as_bytes_draws_the_same_pixels():
    """`figures.rgba_bytes`: float RGBA given to imshow as the bytes matplotlib would make of
    it draws the same figure (nearest sampling), with smaller temporaries while it is saved."""
    import numpy as np

    from slamlab.report.figures import fig_to_data_uri, rgba_bytes, subplots

    rng = np.random.default_rng(1)
    layer = np.zeros((120, 90, 4))
    hit = rng.random((120, 90)) > 0.9
    layer[hit, :3] = (0.84, 0.15, 0.16)
    layer[hit, 3] = rng.choice([0.3, 0.95], hit.sum())

    def draw(image):
        fig, ax = subplots(figsize=(5.0, 6.0))
        ax.imshow(image, origin="lower", extent=(0.0, 9.0, 0.0, 12.0), interpolation="nearest")
        return fig_to_data_uri(fig)

    assert draw(rgba_bytes(layer)) == draw(layer)


def test_a_graph_runs_broken_stretch_says_what_the_loop_search_did_there_and_is_circled_on_the_closures_map(tmp_path: Path) -> None:
    """The two sections meet: the broken stretches' table says which loop closures tie the
    stretch's pass to an earlier one (loops.csv), and the "Loop closures" map circles the same
    stretches."""
    from slamlab.artifacts import write_table
    from slamlab.io.table import Table
    from slamlab.report.loops_section import loops_section

    run, cons = _run_with_verdict(tmp_path / "bad", broken=True)
    span = cons.spans[0]
    t0 = float(load_run(run).load_trajectory("slam").t[0])
    # one closure from the stretch tying it to a pass 60 s before, one rejected candidate long after it
    t_at = t0 + span.t1_s + 1.0
    write_table(run / RunFile.LOOPS, Table({
        "t": np.array([t_at, t_at + span.t2_s - span.t1_s + 60.0]), "node": np.array([70, 75]), "submap": np.array([0, 0]), "anchor": np.array([10, 12]),
        "t_anchor": np.array([t_at - 60.0, t0]), "status": np.array(["accepted", "ambiguous"]), "score": np.array([0.9, 0.8]),
        "refined": np.array([0.9, 0.8]), "second": np.zeros(2), "window_m": np.ones(2), "tied_m": np.full(2, 40.0),
        "node_x": np.array([span.x_m, 90.0]), "node_y": np.array([span.y_m, 90.0]), "match_x": np.array([span.x_m, 90.0]),
        "match_y": np.array([span.y_m, 90.0]), "moved_m": np.array([0.4, 0.0]), "final_x": np.array([span.x_m, 90.0]),
        "final_y": np.array([span.y_m, 90.0]), "anchor_x": np.array([span.x_m, 90.0]), "anchor_y": np.array([span.y_m, 90.0]),
        "residual_m": np.array([0.05, 0.0]), "sigma_along_m": np.array([0.03, 0.03]),
    }))
    page = write_run_report(run).read_text()
    table = page[page.index('id="broken-spans"'):page.index("</table>", page.index('id="broken-spans"'))]
    assert "loop closures on this pass" in table
    # and the line at the top says it of the worst stretch, the one the verdict names
    top = page[page.index('id="verdict-line"'):page.index("</p>", page.index('id="verdict-line"'))]
    # (a stretch at the run's start: the path had not been there before, but a closure ties it to an earlier pass)
    assert "Loop closures on that pass: the path had not come within 10 m of it before; 1 accepted closure ties this pass to earlier ones" in top
    assert f"1 accepted closure ties this pass to earlier ones (at {span.t1_s - 59.0:.0f} s; they moved the robot up to 0.40 m" in table
    assert "ambiguous" not in table  # the rejected candidate was searched long after the stretch
    # the note under the table states the windows the lines were read with, as the code holds them
    from slamlab.report import span_closures
    import html

    note = html.unescape(page[page.index("</table>", page.index('id="broken-spans"')):])
    assert f"within {span_closures.NEAR_M:g} m of the stretch's poses" in note and f"for {span_closures.LOOP_DT_S:g} s after it" in note
    section = loops_section(load_run(run))
    assert section is not None
    from slamlab.report.loops_section import loops_figure

    loaded = load_run(run)
    spans = loaded.metrics["consistency"]["broken_spans"]
    fig = loops_figure(loaded.load_map(), loaded.files.read_columns(RunFile.LOOPS), None, spans=spans)
    circles = [ln for ln in fig.axes[0].get_lines() if len(ln.get_xdata()) == 90]
    assert len(circles) == len(spans) and abs(np.mean(circles[0].get_xdata()) - span.x_m) < 0.1
