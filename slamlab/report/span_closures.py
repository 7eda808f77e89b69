"""Where the map-consistency verdict names a stretch likely broken, what the loop search of a
`filter=graph` run did on that pass (read from loops.csv; nothing is recomputed).

The verdict says when and where the scans contradict the map; the loop closures say which
passes the graph tied together. The candidates searched from the stretch's own nodes (its
first to its last scan, and `LOOP_DT_S` after it: a return's closures are accepted once
several matches agree, seconds later) tell the usual causes apart:
- none of them ties the pass to an earlier one: the place was mapped once (a stretch broken
  by a slipped match or by people), or this pass went back to a place mapped before and was
  never tied to it: a loop that did not close (closures to the pass itself only hold it
  together, not to the map made before). The path tells the two apart (`earlier_pass`): a
  first pass here has no earlier one to be tied to;
- closures tie it to an earlier pass and the final graph left them on their matches
  (centimetres): where they tie, the passes agree;
- a closure the final graph left far from its match (more than `FAR_OFF_M`): the graph and
  that match disagree, a wrong closure outvoted or a right one the graph could not honour.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from slamlab.eval.relations import LOOP_MIN_DT_S as LOOP_DT_S  # an earlier pass: its node this far (s) before the closure's
from slamlab.geometry import FloatArray
from slamlab.io.table import Table

FAR_OFF_M = 0.3  # an accepted closure the final graph left this far (m) from its match disagrees with the graph
NEAR_M = 10.0  # the path within this (m) of a stretch's poses was there: a room, or a stretch of corridor a scan sees whole


def closures_note() -> str:
    """The note under the broken stretches' table, for the "Loop closures on this pass" column:
    how to read its lines (with the windows `closures_at` and `earlier_pass` use)."""
    return ("Loop closures on this pass: the loop candidates searched from the stretch's own scans and for "
            f"{LOOP_DT_S:g} s after it (loops.csv; the \"Loop closures\" section circles the stretches too), after whether the path "
            f"had been there before (within {NEAR_M:g} m of the stretch's poses, before the visit it belongs to): a first pass has "
            "no earlier one to be tied to, so what contradicts the map there is not a loop left open (people, glass, a slipped "
            "match). A pass that went back to a place mapped before with no closure tying it to an earlier pass is a loop that "
            "did not close (closures to the pass itself hold it together, not to the older map). Closures to an earlier pass "
            "that the final graph left on their matches: where they tie, the passes agree. A closure left far off: the final "
            "graph disagrees with that match.")


def earlier_pass(t: FloatArray, xy: FloatArray, t1: float, t2: float, near_m: float = NEAR_M) -> float | None:
    """When the path (`t` (N,) s since the first scan, `xy` (N, 2) m) was last within `near_m`
    of the stretch t1..t2's poses before the visit the stretch belongs to (the path's run of
    poses within `near_m` of them that holds the stretch's first pose): the time of that
    earlier pass's last pose, or None for a first pass here."""
    t = np.asarray(t, dtype=np.float64)
    xy = np.asarray(xy, dtype=np.float64)
    inside = np.flatnonzero((t >= t1) & (t <= t2))
    if not len(inside):  # a stretch between two poses of the path: the one at its start
        inside = np.array([min(int(np.searchsorted(t, t1)), len(t) - 1)])
    d, _ = cKDTree(xy[inside]).query(xy, distance_upper_bound=near_m)
    near = np.isfinite(d)
    away = np.flatnonzero(~near[: inside[0]])  # this visit began after the path's last pose away from the stretch
    before = np.flatnonzero(near[: away[-1]]) if len(away) else away
    return float(t[before[-1]]) if len(before) else None


def closures_at(loops: Table, span: Mapping[str, Any], t0: float, path: tuple[FloatArray, FloatArray] | None = None) -> str:
    """One line on the loop candidates searched from the broken stretch `span` (metrics.json
    consistency.broken_spans: `t1_s`, `t2_s`, s since the run's first scan, whose time is
    `t0`; module doc), times written the same way. With the run's `path` (its poses' times in
    the log's clock and (N, 2) positions, m), it first says whether the pass went back to where
    the path had been (`earlier_pass`) or was the first one there. `loops` may be empty (a run
    that found no loop candidate)."""
    t1, t2 = float(span["t1_s"]), float(span["t2_s"])
    if not len(loops):  # the run found no loop candidate anywhere (loops.csv without rows or columns)
        loops = Table({name: np.zeros(0) for name in ("t", "t_anchor", "residual_m", "moved_m")} | {"status": np.zeros(0, dtype=str)})
    t, ta = loops["t"] - t0, loops["t_anchor"] - t0
    during = (t >= t1) & (t <= t2 + LOOP_DT_S)
    status = loops["status"].astype(str)
    accepted = during & (status == "accepted")
    earlier = accepted & (ta < t1) & (t - ta >= LOOP_DT_S)
    first = False  # a first pass here, and no closure to an earlier pass seen from farther away
    lead = []
    if path is not None and len(path[0]):
        back = earlier_pass(np.asarray(path[0]) - t0, path[1], t1, t2)
        first = back is None and not earlier.any()
        lead = [f"back where the path was at {back:.0f} s" if back is not None else
                f"a first pass here (the path had not come within {NEAR_M:g} m of it before): no loop to close" if first else
                f"the path had not come within {NEAR_M:g} m of it before"]
    if not during.any():
        return "; ".join(lead + ["no loop candidate was found from this pass" if lead else "none: no loop candidate was found from this pass"])
    parts = []
    if earlier.any():
        i = np.flatnonzero(earlier)
        far = int((loops["residual_m"][i] > FAR_OFF_M).sum())
        a, b = f"{float(ta[i].min()):.0f}", f"{float(ta[i].max()):.0f}"
        parts.append(f"{len(i)} accepted {'closure ties' if len(i) == 1 else 'closures tie'} this pass to earlier ones (at"
                     f" {a if a == b else f'{a}–{b}'} s; they moved the robot up to {float(loops['moved_m'][i].max()):.2f} m;"
                     f" the final graph left them at most {float(loops['residual_m'][i].max()):.2f} m off"
                     + (f", {far} over {FAR_OFF_M:g} m: it disagrees with {'that one' if far == 1 else 'those'})" if far else ")"))
    elif not first:
        parts.append("no accepted closure ties this pass to an earlier one")
    own = int((accepted & ~earlier).sum())
    if own:
        parts.append(f"{own} {'closure ties' if own == 1 else 'closures tie'} it to itself" if first
                     else f"{own} {'more ' if earlier.any() else ''}tie it to itself")
    rejected = during & (status != "accepted")
    if rejected.any():
        kinds, counts = np.unique(status[rejected], return_counts=True)
        parts.append("rejected: " + ", ".join(f"{c} {k}" for k, c in zip(kinds, counts)))
    return "; ".join(lead + parts)
