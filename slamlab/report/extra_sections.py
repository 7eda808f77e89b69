"""Per-run sections that only some runs have, drawn after the map consistency section.

A section is a function of the loaded run (`RunDir`) that returns an `ExtraSection`, or None
when the run has nothing for it (the files it reads are absent). Add yours to `SECTIONS`;
run.html draws each with a link in the page's navigation. It reads the run's files through
`RunDir` (`run.files.read_arrays`, `run.load_map()`, ...) and never imports the engine: a
report never recomputes SLAM (pyproject.toml's import contracts).

The one built in: a graph run's loop closures (`loops_section`, from loops.csv).
"""

from __future__ import annotations

import logging
from collections.abc import Callable

from slamlab.report.loops_section import loops_section
from slamlab.report.rundir import RunDir
from slamlab.report.section import ExtraSection

log = logging.getLogger(__name__)


# In page order. Each entry: RunDir -> ExtraSection | None.
SECTIONS: list[Callable[[RunDir], ExtraSection | None]] = [loops_section]


def extra_sections(run: RunDir) -> list[ExtraSection]:
    """Every section of SECTIONS this run has; one that fails is logged and left out (a
    broken optional file costs its section, never the page)."""
    out = []
    for make in SECTIONS:
        try:
            section = make(run)
        except Exception as exc:  # noqa: BLE001 - the page goes on without it
            log.warning("run report: section %s failed: %s", getattr(make, "__name__", make), exc)
            continue
        if section is not None:
            out.append(section)
    return out
