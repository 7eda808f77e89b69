"""Where the map-consistency verdict names a stretch likely broken, what the loop search of a
`filter=graph` run did there (read from loops.csv; nothing is recomputed).

The verdict says where the scans contradict the map; the loop closures say which passes the
graph tied together. Side by side they tell the usual causes apart:
- no closure ties two passes there: the place was mapped once (a stretch broken by a slipped
  match or by people), or mapped twice and never recognised: a loop that did not close;
- closures tie passes there and the final graph left them on their matches (centimetres):
  where they tie, the passes agree; a wall drawn twice there comes from the passes or the
  stretches none ties;
- a closure the final graph left far from its match (more than `FAR_OFF_M`): the graph and that
  match disagree, a wrong closure outvoted or a right one the graph could not honour.
A candidate counts for a stretch when the node it was searched from or the node it ties to
lies, optimised, within the stretch's circle (`x_m`, `y_m`, `radius_m`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from slamlab.eval.relations import LOOP_MIN_DT_S as LOOP_DT_S  # a closure ties two passes when its nodes are this far apart (s)
from slamlab.io.table import Table

FAR_OFF_M = 0.3  # an accepted closure the final graph left this far (m) from its match disagrees with the graph


def closures_at(loops: Table, span: Mapping[str, Any], t0: float) -> str:
    """One line on the loop candidates at the broken stretch `span` (metrics.json
    consistency.broken_spans: centre `x_m`, `y_m` and `radius_m`, m), times written in s since
    `t0` (the run's first scan, as the stretch's own times; module doc)."""
    x, y, r = float(span["x_m"]), float(span["y_m"]), float(span["radius_m"])
    near = (np.hypot(loops["final_x"] - x, loops["final_y"] - y) <= r) | (np.hypot(loops["anchor_x"] - x, loops["anchor_y"] - y) <= r)
    if not near.any():
        return "none: no loop candidate was found here"
    status = loops["status"].astype(str)
    accepted = near & (status == "accepted")
    ties = accepted & (np.abs(loops["t"] - loops["t_anchor"]) >= LOOP_DT_S)
    parts = []
    if ties.any():
        i = np.flatnonzero(ties)
        far = int((loops["residual_m"][i] > FAR_OFF_M).sum())
        parts.append(f"{len(i)} accepted {'closure ties' if len(i) == 1 else 'closures tie'} passes here (between {float(loops['t_anchor'][i].min() - t0):.0f} s and"
                     f" {float(loops['t'][i].max() - t0):.0f} s; they moved the robot up to {float(loops['moved_m'][i].max()):.2f} m;"
                     f" the final graph left them at most {float(loops['residual_m'][i].max()):.2f} m off"
                     + (f", {far} over {FAR_OFF_M:g} m: it disagrees with {'that one' if far == 1 else 'those'})" if far else ")"))
    else:
        parts.append("no accepted closure ties two passes here")
    local = int((accepted & ~ties).sum())
    if local:
        parts.append(f"{local} more accepted between nodes under {LOOP_DT_S:.0f} s apart")
    rejected = near & (status != "accepted")
    if rejected.any():
        kinds, counts = np.unique(status[rejected], return_counts=True)
        parts.append("rejected: " + ", ".join(f"{c} {k}" for k, c in zip(kinds, counts)))
    return "; ".join(parts)
