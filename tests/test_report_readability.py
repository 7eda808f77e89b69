"""What a reader sees in the report figures (issue 45): scales that show the run's own
numbers, labels that fit, notes where a scale could mislead. Each test reads the figure's
data (axes limits, texts, drawn lines), not only that an image was made."""

from __future__ import annotations

import numpy as np

from slamlab.io.table import Table
from slamlab.report.error_figures import ate_over_time_figure, relation_error_over_time_figure
from slamlab.report.rundir import Trajectory


def _relations(slam_m: np.ndarray, odo_m: np.ndarray, slam_deg: np.ndarray, odo_deg: np.ndarray) -> Table:
    t1 = np.linspace(1.0e9, 1.0e9 + 2650.0, len(slam_m))
    return Table({"t1": t1, "t2": t1 + 5.0, "length_m": np.ones(len(t1)), "slam_trans_m": slam_m, "slam_rot_deg": slam_deg,
                  "odometry_trans_m": odo_m, "odometry_rot_deg": odo_deg})


def _texts(fig) -> str:
    return " ".join(t.get_text() for ax in fig.axes for t in ax.texts)


def test_odometry_tens_of_metres_off_does_not_flatten_slams_error_to_zero():
    """Intel lidar2d: odometry up to 70 m and 180 degrees, SLAM 0.02 m: both panels are scaled
    to SLAM's errors, start at 0, and say how far the odometry goes."""
    rng = np.random.default_rng(0)
    n = 400
    slam = rng.uniform(0.005, 0.04, n)
    fig = relation_error_over_time_figure(_relations(slam, np.linspace(0.1, 70.0, n), rng.uniform(0.1, 1.5, n),
                                                     np.linspace(1.0, 180.0, n)))
    trans, rot = fig.axes[:2]
    lo, hi = trans.get_ylim()
    assert lo == 0.0 and np.percentile(slam, 99) <= hi < 0.1  # SLAM's 2-4 cm fill the panel
    assert 0.0 == rot.get_ylim()[0] and rot.get_ylim()[1] < 3.0
    note = _texts(fig)
    assert "off the top" in note and "70 m" in note and "180°" in note


def test_comparable_odometry_keeps_both_on_one_scale():
    rng = np.random.default_rng(1)
    n = 200
    fig = relation_error_over_time_figure(_relations(rng.uniform(0.01, 0.05, n), rng.uniform(0.02, 0.1, n),
                                                     rng.uniform(0.1, 1.0, n), rng.uniform(0.2, 2.0, n)))
    trans = fig.axes[0]
    assert trans.get_ylim()[0] == 0.0 and trans.get_ylim()[1] >= 0.09  # the odometry's top is inside
    assert "off the top" not in _texts(fig)


def test_ate_panel_scaled_to_slam_when_the_odometry_drifts_far():
    t = np.arange(1000) * 0.1
    truth = Trajectory(t=t, xy=np.stack([t, np.zeros_like(t)], 1), yaw=np.zeros_like(t))
    slam = Trajectory(t=t, xy=truth.xy + [0.0, 0.03], yaw=np.full_like(t, 0.01))
    odo = Trajectory(t=t, xy=truth.xy + np.stack([np.zeros_like(t), t * 0.5], 1), yaw=t * 0.02)
    fig = ate_over_time_figure(truth, {"odometry": odo, "slam": slam})
    pos = fig.axes[0]
    assert pos.get_ylim() == (0.0, 0.03 * 1.25) or abs(pos.get_ylim()[1] - 0.0375) < 1e-9
    assert "up to 50 m" in _texts(fig)


def _panels_figure(values: list[str], n_panels: int = 5, base: float = 0.02):
    """A metric-vs-parameter figure over categorical `values`, two lines (another parameter)."""
    from slamlab.report.figures import Series
    from slamlab.report.sweep_figures import metric_panels_figure

    x = np.arange(len(values), dtype=float)
    series = [Series(f"particles={p}", x, base + 0.0001 * x + 0.0002 * i, np.zeros_like(x), x, base + 0.0001 * x)
              for i, p in enumerate((30, 100))]
    return metric_panels_figure("dataset.path", [(f"metric {k}", series) for k in range(n_panels)], values)


def _inside_and_apart(fig) -> None:
    """Every tick label, axis title and the legend lie inside the figure, and no axis title
    overlaps a tick label of its own axes."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)  # the figures are made without pyplot: render them as savefig does
    canvas.draw()
    r = canvas.get_renderer()
    box = fig.bbox
    for ax in fig.axes:
        if not ax.get_visible() or not ax.axison:
            continue
        ticks = [t.get_window_extent(r) for t in ax.get_xticklabels() if t.get_text()]
        title = ax.xaxis.label.get_window_extent(r)
        for b in [*ticks, title, ax.yaxis.label.get_window_extent(r)]:
            assert box.x0 - 1 <= b.x0 and b.x1 <= box.x1 + 1 and box.y0 - 1 <= b.y0 and b.y1 <= box.y1 + 1, b
        assert not any(t.overlaps(title) for t in ticks), "an axis title crossed by its tick labels"
    for legend in fig.legends:
        lb = legend.get_window_extent(r)
        assert all(not lb.overlaps(ax.get_window_extent(r)) for ax in fig.axes if ax.axison)


def test_long_categorical_values_are_shortened_and_clear_of_the_axis_title():
    """A sweep over dataset.path: each tick is the log's file name, every label and title
    inside the figure, none crossing another (issue 45: rotated labels cut off, and crossing
    the axis title 'experiment' in the ladder sweep)."""
    paths = ["/work/shared/data/carmen/intel.clf.bz2", "/work/shared/data/carmen/aces.clf.bz2",
             "/work/shared/data/carmen/fr-clinic_robotlaser.clf.bz2"]
    fig = _panels_figure(paths)
    ticks = [t.get_text() for t in fig.axes[0].get_xticklabels()]
    assert ticks == ["intel.clf.bz2", "aces.clf.bz2", "fr-clinic_robotla…"]
    _inside_and_apart(fig)
    ladder = ["ladder_first_scan", "ladder_dead_reckoning", "ladder_predict", "ladder_few_particles", "ladder_full"]
    _inside_and_apart(_panels_figure(ladder))


def test_metric_panels_start_at_zero():
    """A 0.015 degree difference between configurations of about 0.7 degrees must not fill the panel."""
    fig = _panels_figure(["systematic", "residual"], n_panels=3, base=0.7)
    for ax in fig.axes:
        if ax.axison:
            assert ax.get_ylim()[0] == 0.0 and ax.get_ylim()[1] >= 0.7


def test_when_most_steps_resample_the_strip_marks_those_that_did_not():
    from slamlab.report.figures import neff_figure

    n = 200
    resampled = np.ones(n, bool)
    resampled[::20] = False  # 95 % resample
    steps = Table({"t": np.arange(n) * 0.5, "neff": np.full(n, 10.0), "resampled": resampled})
    fig = neff_figure(steps, 30, 15.0)
    strip = fig.axes[1]
    ticks = np.concatenate([c.get_positions() for c in strip.collections])
    assert np.allclose(np.sort(ticks), np.arange(0, n, 20) * 0.5)  # the 10 steps that did not
    assert strip.get_ylabel() == "not resampled"
    assert "resampled at 190 of 200 steps (95 %); ticks: the steps that did not" in _texts(fig)
    few = resampled.copy()
    few[:] = False
    few[[3, 50]] = True
    fig = neff_figure(Table({"t": steps["t"], "neff": steps["neff"], "resampled": few}), 30, 15.0)
    assert np.allclose(np.sort(np.concatenate([c.get_positions() for c in fig.axes[1].collections])), [1.5, 25.0])


def test_the_first_steps_compile_time_does_not_set_the_step_time_axis():
    """Issue 45: the step-time plot was set by the first step's 2.96 s JIT compile, unsaid."""
    from slamlab.report.figures import weight_and_time_figure

    rng = np.random.default_rng(2)
    st = rng.uniform(0.004, 0.006, 300)
    st[0] = 2.96
    steps = Table({"t": np.arange(300) * 0.5, "best_weight": np.full(300, 0.1), "step_time_s": st})
    fig = weight_and_time_figure(steps)
    times = fig.axes[1]
    assert times.get_ylim()[1] < 100.0  # ms: the 2,960 ms step is not on it
    line = times.get_lines()[0]
    assert len(line.get_xdata()) == 299 and line.get_xdata()[0] == 0.5
    assert "first step 2960 ms" in _texts(fig)
    assert f"median {np.median(st[1:]) * 1000:.1f} ms" in [t.get_text() for t in times.get_legend().get_texts()]
    assert "slowest 6 ms" in [t.get_text() for t in times.get_legend().get_texts()]  # not the first step's


def test_counts_of_one_are_singular(tmp_path):
    """Issue 45: "1 particles", "1 snapshots"."""
    from report_fixtures import make_run_dir
    from slamlab.report import build_sweep_report, write_run_report
    from slamlab.report.html import count_text, environment

    assert [count_text(n, "snapshot") for n in (1, 100)] == ["1 snapshot", "100 snapshots"]
    assert environment().from_string("{{ 1|count('particle') }} / {{ 3|count('match') }}").render() == "1 particle / 3 matches"
    run = make_run_dir(tmp_path / "one", overrides=["particles=1"], n_steps=40)
    page = write_run_report(run).read_text()
    assert "1 particles" not in page and "1 particle" in page
    assert "Comparison of 1 run<" in build_sweep_report([run], tmp_path / "out").read_text()


def test_the_texture_images_to_compare_come_out_the_same_size(tmp_path):
    """Issue 45: the odometry texture (its own textured area) was a different size from the
    SLAM and true textures. Cut to one window, they are the same size, cell under cell."""
    from PIL import Image

    from report_fixtures import make_run_dir
    from slamlab.report.figures import png_size
    from slamlab.report.rundir import load_run
    from slamlab.report.run_report import texture_gallery

    run = make_run_dir(tmp_path / "r", n_steps=40)
    for name, (x0, y0, x1, y1) in (("texture.png", (281, 219, 598, 464)), ("texture_truth.png", (281, 219, 598, 464)),
                                   ("texture_odometry.png", (281, 212, 601, 461))):
        rgba = np.zeros((800, 800, 4), np.uint8)
        rgba[y0:y1, x0:x1] = (120, 80, 40, 255)
        Image.fromarray(rgba).save(run / name)
    shown = texture_gallery(load_run(run))
    sizes = {png_size(t["uri"]) for t in shown}
    assert len(shown) == 3 and sizes == {(601 - 281 + 24, 464 - 212 + 24)}  # the union, with its 12 px margin
    assert len({t["width"] for t in shown}) == 1


def test_long_legend_labels_stay_inside_the_figure():
    """Lines named by other parameters' values (dataset paths in a mixed report): the legend
    wraps to fewer labels a row and stays inside the figure."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from slamlab.report.figures import Series
    from slamlab.report.sweep_figures import metric_panels_figure

    x = np.arange(2, dtype=float)
    labels = [f"experiment=lidar2d path={n}.clf.bz2 texture=default particles=30 duration_s=–" for n in ("intel", "aces", "fr-clinic")]
    series = [Series(label, x, x + i, np.zeros(2), x, x + i) for i, label in enumerate(labels)]
    fig = metric_panels_figure("particles", [("metric", series)] * 3)
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    box = fig.legends[0].get_window_extent(canvas.get_renderer())
    assert fig.bbox.x0 <= box.x0 and box.x1 <= fig.bbox.x1


def test_a_path_parameter_is_shown_by_its_file_name_with_the_whole_path_in_its_tooltip(tmp_path):
    from report_fixtures import make_run_dir
    from slamlab.report import build_sweep_report

    runs = [make_run_dir(tmp_path / n, overrides=[f"dataset.path=/work/shared/data/carmen/{n}.clf.bz2"], n_steps=30)
            for n in ("intel", "aces")]
    page = build_sweep_report(runs, tmp_path / "out").read_text()
    assert '<td class="param" title="/work/shared/data/carmen/intel.clf.bz2">intel.<wbr>clf.<wbr>bz2</td>' in page
    assert "path=intel.clf.bz2" in page and "path=/work" not in page
