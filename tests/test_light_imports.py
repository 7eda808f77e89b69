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


@pytest.mark.slow
def test_a_run_without_its_report_leaves_the_table_and_plot_libraries_out(tmp_path, sim_cache):
    # pandas loads pyarrow when it is installed: together ~80 MB and 0.3 s a process. A run
    # writes its tables itself (slamlab.io.table) and only the report reads them with pandas.
    argv = ["slamlab", "dataset.duration_s=20", "particles=10", "report=false", f"dataset.cache_dir={sim_cache}",
            f"hydra.run.dir={tmp_path / 'run'}", "progress=off"]
    code = (
        "import sys\nfrom slamlab.cli.app import main\n"
        f"sys.argv = {argv!r}\n"
        "try:\n    main()\nexcept SystemExit as e:\n    assert not e.code, e.code\n"
        "print('LOADED:', *sorted({m.split('.')[0] for m in sys.modules} & {'pandas', 'pyarrow', 'matplotlib', 'jinja2'}))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert (tmp_path / "run" / "steps.csv").is_file() and (tmp_path / "run" / "consistency.csv").is_file()
    loaded = [line for line in out.stdout.splitlines() if line.startswith("LOADED:")]
    assert loaded == ["LOADED:"], f"the run loaded: {loaded}"
