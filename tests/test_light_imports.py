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
