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
