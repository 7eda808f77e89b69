"""Open3D without its web visualiser's import.

`import open3d` runs the `open3d.visualization` package's code, which imports Plotly and
Dash for `draw_plotly` (and with them requests, pydantic, werkzeug, IPython's pieces, ...):
with open3d 0.20 here 1.3 s and 77 MB resident for the whole import, against 0.6 s and 38 MB
without that subpackage. Every run that writes the floor's point cloud paid it, though slamlab
draws nothing with Open3D (it down-samples and writes the cloud: `open3d.geometry`,
`open3d.utility`, `open3d.io`, all compiled, in `open3d.pybind`).

`import_open3d` imports the package with a placeholder standing in for
`open3d.visualization` during the import, then takes the placeholder away, so a later
`import open3d.visualization` in the same process loads the real subpackage. Inside a
Jupyter kernel (IPython loaded), where Open3D's own import enables its web visualiser
through that subpackage, and when Open3D is already loaded, the import is left as it is.
"""

from __future__ import annotations

import sys
import types

VISUALIZATION = "open3d.visualization"


def import_open3d() -> types.ModuleType:
    """The `open3d` module, imported without its web visualiser where that is safe (see the module doc)."""
    if "open3d" in sys.modules or "IPython" in sys.modules:
        import open3d

        return open3d
    placeholder = types.ModuleType(VISUALIZATION)
    sys.modules[VISUALIZATION] = placeholder
    try:
        import open3d
    finally:
        if sys.modules.get(VISUALIZATION) is placeholder:
            del sys.modules[VISUALIZATION]
    if getattr(open3d, "visualization", None) is placeholder:
        del open3d.visualization
    return open3d
