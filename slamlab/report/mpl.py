"""matplotlib as the report figures use it: headless, and imported without its docstring tables.

Every figure module of `slamlab.report` takes matplotlib's names from here, so matplotlib is
imported once, this way, whichever report module comes first.

- Headless: the Agg backend (reports are built by callbacks and in CI; never open a window).
- At import, matplotlib builds for every Artist class the table of its properties that the
  class's `set()` docstring lists (`matplotlib.artist.kwdoc`, called for ~120 classes while
  `matplotlib.figure` loads): 0.1-0.2 s CPU of every report, a tenth of a one-scan run. No
  report reads a docstring, so `kwdoc` gives an empty table while these imports run and is
  restored after them: Artist classes made later (by other code in the process) get their
  tables. What is left out is documentation only: `help()` on a matplotlib artist in a
  slamlab process lists fewer properties; every figure is drawn the same, to the byte.
"""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import matplotlib.artist as _artist  # noqa: E402

_kwdoc = _artist.kwdoc
_artist.kwdoc = lambda artist: ""
try:
    from matplotlib import colormaps, rcParams  # noqa: E402
    from matplotlib.collections import LineCollection  # noqa: E402
    from matplotlib.figure import Figure  # noqa: E402
    from matplotlib.image import AxesImage  # noqa: E402
    from matplotlib.lines import Line2D  # noqa: E402
    from matplotlib.text import Text  # noqa: E402
    from matplotlib.transforms import Affine2D, Bbox  # noqa: E402
finally:
    _artist.kwdoc = _kwdoc

__all__ = ["Affine2D", "AxesImage", "Bbox", "Figure", "Line2D", "LineCollection", "Text", "colormaps", "rcParams"]
