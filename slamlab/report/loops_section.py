"""The run report's "Loop closures" section for a `filter=graph` run, read from its files:
loops.csv (every loop candidate the search found, accepted or not) and metrics.json's
"graph" section. Nothing is recomputed here.

The map shows each accepted closure as a green segment between the two places it joins
(the node's and the submap node's optimised positions; a corridor match, which says nothing
along the corridor, dashed), the rejected candidates as grey crosses where the match put the
robot, the optimised path, and the stretches the map-consistency verdict names likely broken,
circled and numbered as in that section (whose table says what the loop search did at each:
`span_closures`). Under it: how far the closures asked to move the robot (the largest
corrections are the loops that closed), the counts by status and the optimiser's time.
"""

from __future__ import annotations

import numpy as np

from slamlab.io.table import Table
from slamlab.report.consistency_section import SPAN_COLOUR, broken_spans, draw_spans
from slamlab.report.section import ExtraSection
from slamlab.report.figures import draw_map, fig_to_data_uri, prepare_map, subplots
from slamlab.report.mpl import Figure
from slamlab.report.rundir import LogOddsMap, RunDir, Trajectory

ACCEPTED_RGB = "#1a7f37"
REJECTED_RGB = "#8c959f"
LARGEST = 8  # rows of the table: the closures that moved the robot most


def loops_figure(m: LogOddsMap | None, loops: Table, path: Trajectory | None, max_px: int = 1000, width_in: float = 13.0,
                 spans: list[dict] | None = None) -> Figure:
    """The map with the accepted closures as segments and the rejected candidates as crosses
    (module doc), and the stretches the consistency verdict names likely broken (`spans`,
    metrics.json consistency.broken_spans) circled and numbered as in that section."""
    view = prepare_map(m, max_px, [path] if path is not None else []) if m is not None else None
    fig, ax = subplots(figsize=(width_in, width_in * 0.6))
    draw_map(ax, view)
    if path is not None:
        ax.plot(path.xy[:, 0], path.xy[:, 1], color="#0969da", lw=0.6, alpha=0.5, label="optimised path")
    status = loops["status"].astype(str)
    acc = status == "accepted"
    corridor = loops["sigma_along_m"] > 1.0 if "sigma_along_m" in loops else np.zeros(len(loops), dtype=bool)
    for mask, style, label in ((acc & ~corridor, "-", "accepted closure"), (acc & corridor, "--", "accepted, across a corridor only")):
        idx = np.flatnonzero(mask)
        for n, i in enumerate(idx):
            ax.plot([loops["final_x"][i], loops["anchor_x"][i]], [loops["final_y"][i], loops["anchor_y"][i]], style,
                    color=ACCEPTED_RGB, lw=0.8, alpha=0.8, label=label if n == 0 else None)
    rej = np.flatnonzero(~acc)
    if len(rej):
        ax.plot(loops["match_x"][rej], loops["match_y"][rej], "x", color=REJECTED_RGB, ms=4, label="rejected candidate (where it put the robot)")
    if spans:
        draw_spans(ax, spans)
        ax.plot([], [], color=SPAN_COLOUR, lw=2.0, label="likely broken (the consistency section's stretches)")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.legend(loc="upper right", fontsize=8, framealpha=0.85)
    return fig


def loops_section(run: RunDir) -> ExtraSection | None:
    """The section, or None for a run that wrote no loops.csv (every other filter)."""
    loops = run.load_loops()
    if loops is None:
        return None
    graph = run.metrics.get("graph") if isinstance(run.metrics.get("graph"), dict) else {}
    if len(loops) == 0:
        return ExtraSection(id="loops", title="Loop closures", note=_counts(graph) + " No loop candidate was found.")
    path = run.load_trajectory("slam")
    fig = loops_figure(run.load_map(), loops, path, spans=broken_spans(run))
    img = fig_to_data_uri(fig)
    acc = np.flatnonzero(loops["status"].astype(str) == "accepted")
    order = acc[np.argsort(-loops["moved_m"][acc], kind="stable")][:LARGEST]
    t0 = float(path.t[0]) if path is not None and len(path.t) else float(min(loops["t"].min(), loops["t_anchor"].min()))  # the run's start
    rows = [[f"{loops['t'][i] - t0:.0f}", f"{loops['t_anchor'][i] - t0:.0f}", f"{loops['moved_m'][i]:.2f}",
             f"{loops['residual_m'][i]:.3f}", f"{loops['refined'][i]:.2f}",
             "across a corridor" if loops["sigma_along_m"][i] > 1.0 else "full"] for i in order]
    note = (_counts(graph) + " Green: accepted closures joining the two places they tie (dashed: a corridor match,"
            " which ties only across the corridor and the heading); grey crosses: rejected candidates where they would"
            " have put the robot. The table lists the closures that asked to move the robot most: the loops that closed.")
    return ExtraSection(id="loops", title="Loop closures", images=[(img, "map with loop closures")], note=note,
                        columns=["at (s since start)", "ties to (s)", "moved the robot (m)", "left off at the end (m)", "match score", "pins"],
                        rows=rows)


def _counts(graph: dict) -> str:
    """One sentence of the metrics' counts and times."""
    if not graph:
        return ""
    by = graph.get("by_status", {})
    rejected = ", ".join(f"{v} {k}" for k, v in sorted(by.items()) if k != "accepted") or "none"
    return (f"{graph.get('nodes', 0)} nodes in {graph.get('submaps', 0)} submaps; {graph.get('searches', 0)} branch-and-bound searches"
            f" ({graph.get('search_bounds', 0):,} bounds) found {graph.get('candidates', 0)} candidates: {graph.get('accepted', 0)} accepted, rejected: {rejected}."
            f" Optimiser: {graph.get('update_s', 0.0):.2f} s incremental (ISAM2), {graph.get('optimisations', 0)} whole-graph"
            f" optimisations {graph.get('optimise_s', 0.0):.2f} s; search {graph.get('search_s', 0.0):.2f} s;"
            + (f" screen {graph['screened']} coarse searches {graph.get('screen_s', 0.0):.2f} s;" if graph.get("screened") else "")
            + f" largest correction {graph.get('largest_correction_m', 0.0):.2f} m; online map redrawn {graph.get('redraws', 0)} times."
            + (f" Every scan matched once more on the optimised nodes' map: {graph['final_match_s']:.2f} s." if graph.get("final_match_s") else ""))
