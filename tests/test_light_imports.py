"""Starting `slamlab` stays light: heavy libraries are imported where they are used
(issue 10: a one-scan run's fixed cost). Each costs 0.3-0.8 s of CPU and tens of MB."""

from __future__ import annotations

import subprocess
import sys

import pytest

HEAVY = ("pandas", "pyarrow", "matplotlib", "scipy", "open3d", "jinja2", "numba")


@pytest.mark.parametrize("module", ["slamlab.cli.app", "slamlab.pipeline", "slamlab.datasets.carmen"])
def test_importing_does_not_pull_heavy_libraries(module):
    code = f"import sys, {module}\nprint(' '.join(sorted({{m.split('.')[0] for m in sys.modules}} & set({HEAVY!r}))))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "", f"import {module} pulled in: {out.stdout.strip()}"


def _run_in_a_child(argv: list[str]) -> list[str]:
    """`slamlab argv` in a fresh interpreter; the lines it prints after the run: which of
    pandas, pyarrow, matplotlib and jinja2 it loaded, and whether scipy.linalg."""
    code = (
        "import sys\nfrom slamlab.cli.app import main\n"
        f"sys.argv = {['slamlab', *argv]!r}\n"
        "try:\n    main()\nexcept SystemExit as e:\n    assert not e.code, e.code\n"
        "print('LOADED:', *sorted({m.split('.')[0] for m in sys.modules} & {'pandas', 'pyarrow', 'matplotlib', 'jinja2'}))\n"
        "print('scipy.linalg:', 'scipy.linalg' in sys.modules)"  # numba's BLAS probe, skipped by the CLI
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return out.stdout.splitlines()


@pytest.mark.slow
def test_a_run_without_its_report_leaves_the_table_and_plot_libraries_out(tmp_path, sim_cache):
    # pandas loads pyarrow when it is installed: together ~80 MB and 0.3 s a process. A run
    # writes its tables itself (slamlab.io.table).
    lines = _run_in_a_child(["dataset.duration_s=20", "particles=10", "report=false", f"dataset.cache_dir={sim_cache}",
                             f"hydra.run.dir={tmp_path / 'run'}", "progress=off"])
    assert (tmp_path / "run" / "steps.csv").is_file() and (tmp_path / "run" / "consistency.csv").is_file()
    assert "scipy.linalg: False" in lines
    loaded = [line for line in lines if line.startswith("LOADED:")]
    assert loaded == ["LOADED:"], f"the run loaded: {loaded}"


@pytest.mark.slow
def test_a_run_with_its_report_still_leaves_pandas_out(tmp_path, sim_cache):
    # the run report reads the run's tables as NumPy columns (io.table.read_csv) and smooths
    # them itself: pandas (0.2 s, ~25 MB) is for the sweep report alone
    lines = _run_in_a_child(["dataset.duration_s=20", "particles=10", f"dataset.cache_dir={sim_cache}",
                             f"hydra.run.dir={tmp_path / 'run'}", "progress=off"])
    page = (tmp_path / "run" / "report.html").read_text()
    assert 'id="filter"' in page and "Error over time" in page  # the sections that read steps.csv and the errors
    loaded = [line for line in lines if line.startswith("LOADED:")]
    assert loaded == ["LOADED: jinja2 matplotlib"], f"the run loaded: {loaded}"


@pytest.mark.slow
def test_the_cli_keeps_numbas_probes_from_loading_scipy_and_cffi_and_both_still_work():
    # numba's first kernel load imports scipy.linalg only to ask whether BLAS exists (0.2 s,
    # 13 MB) and builds a cffi.FFI() only to support cffi functions in kernels (0.035 s); the
    # CLI hides those two modules while numba asks. A slamlab kernel then runs without SciPy
    # or cffi, a kernel that needs BLAS still gets it when it compiles, and cffi still imports.
    code = """
import sys
import numpy as np
import numba
from slamlab.cli.app import _skip_numba_probes
from slamlab.slam.raycast import raycast_update

_skip_numba_probes()
lo = np.zeros((8, 8), np.float32)
flip = np.array([8, -1, 8, -1], np.int64)
raycast_update(lo, 1, 1, np.array([1], np.int64), np.array([6], np.int64), 0.9, -0.4, -5.0, 5.0, 0.0, flip)
print("row:", *lo[1, :7].round(2))
print("scipy after a slamlab kernel:", "scipy.linalg" in sys.modules)
print("cffi after a slamlab kernel:", "cffi" in sys.modules)


@numba.njit
def solve(a, b):
    return np.linalg.solve(a, b) + np.dot(a, b)


a = np.array([[2.0, 1.0], [1.0, 3.0]])
b = np.array([1.0, 2.0])
print("blas kernel right:", bool(np.allclose(solve(a, b), np.linalg.solve(a, b) + a @ b)))
import cffi  # installed with the dev extras (Ray's google-auth brings it): still usable

print("cffi usable:", cffi.FFI().sizeof("int") == 4)
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr[-2000:]
    lines = out.stdout.splitlines()
    assert lines[0] == "row: 0.0 -0.4 -0.4 -0.4 -0.4 -0.4 0.9"  # the beam's free cells, then its end
    assert lines[1:] == ["scipy after a slamlab kernel: False", "cffi after a slamlab kernel: False",
                         "blas kernel right: True", "cffi usable: True"]


def test_a_numba_without_a_probe_module_still_runs_the_cli(monkeypatch):
    # another numba version may keep its probes elsewhere: the CLI then skips nothing, raises
    # nothing, and leaves no hidden module behind (an import of it would fail for good)
    import importlib

    from slamlab.cli import app

    real = importlib.import_module

    def without_probes(name, *args):
        if name in ("numba.np.arraymath", "numba.core.typing.cffi_utils"):
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return real(name, *args)

    # as in a fresh process: neither probe run, neither library loaded (restored afterwards)
    for name in ("numba.np.arraymath", "numba.core.typing.cffi_utils", "scipy.linalg.cython_blas", "cffi"):
        monkeypatch.delitem(sys.modules, name, raising=False)
    monkeypatch.setattr(app.importlib, "import_module", without_probes)
    app._skip_numba_probes()
    assert "scipy.linalg.cython_blas" not in sys.modules and "cffi" not in sys.modules

    def broken(name, *args):  # a probe that fails for another reason is not hidden
        raise ModuleNotFoundError("No module named 'llvmlite'", name="llvmlite")

    monkeypatch.setattr(app.importlib, "import_module", broken)
    with pytest.raises(ModuleNotFoundError, match="llvmlite"):
        app._skip_numba_probes()

    def without_package(name, *args):  # a numba without the probe's package: passed over too
        raise ModuleNotFoundError("No module named 'numba.np'", name=name.rsplit(".", 1)[0])

    monkeypatch.setattr(app.importlib, "import_module", without_package)
    app._skip_numba_probes()
    assert "scipy.linalg.cython_blas" not in sys.modules and "cffi" not in sys.modules


@pytest.mark.slow
def test_report_matplotlib_skips_the_docstring_tables_of_its_import_only():
    # slamlab.report.mpl imports matplotlib with `kwdoc` (each Artist's property table for its
    # set() docstring, 0.1-0.2 s CPU) giving nothing, then puts it back: matplotlib's own
    # classes miss the table, a class made later has it, and drawing is unaffected
    code = """
import matplotlib.artist
from slamlab.report.mpl import Figure, Line2D
from matplotlib.backends.backend_agg import FigureCanvasAgg

print("restored:", matplotlib.artist.kwdoc.__module__ == "matplotlib.artist" and matplotlib.artist.kwdoc.__name__ == "kwdoc")
print("Line2D table:", "antialiased" in (Line2D.set.__doc__ or ""))


class Later(Line2D):
    pass


print("later table:", "antialiased" in (Later.set.__doc__ or ""))
fig = Figure(figsize=(2, 2))
fig.subplots().plot([0, 1], [0, 1])
canvas = FigureCanvasAgg(fig)
canvas.draw()
print("drawn:", canvas.buffer_rgba().shape)
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.splitlines() == ["restored: True", "Line2D table: False", "later table: True", "drawn: (200, 200, 4)"]
