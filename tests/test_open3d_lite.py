"""`texture.open3d_lite.import_open3d`: Open3D's point-cloud parts without the Plotly / Dash
import of its web visualiser, and the real `open3d.visualization` still there for whoever
imports it afterwards. Each case runs in a fresh interpreter: the import is once a process."""

from __future__ import annotations

import subprocess
import sys
import textwrap


def _run(code: str) -> str:
    proc = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout.strip()


def test_the_cloud_is_made_and_written_without_plotly_or_dash(tmp_path):
    out = _run(f"""
        import sys
        import numpy as np
        from slamlab.texture.open3d_lite import import_open3d
        o3d = import_open3d()
        pcd = o3d.geometry.PointCloud()
        pcd.points = o3d.utility.Vector3dVector(np.random.default_rng(0).random((2000, 3)))
        pcd = pcd.voxel_down_sample(0.1)
        assert o3d.io.write_point_cloud({str(tmp_path / 'c.ply')!r}, pcd)
        back = o3d.io.read_point_cloud({str(tmp_path / 'c.ply')!r})
        print(len(pcd.points), len(back.points), 'dash' in sys.modules, 'plotly' in sys.modules)
    """)
    n, m, dash, plotly = out.split()
    assert int(n) == int(m) and 500 < int(n) < 2000  # down-sampled on a 0.1 m grid, written, read back
    assert (dash, plotly) == ("False", "False")


def test_the_real_visualization_package_is_imported_on_request_afterwards():
    out = _run("""
        from slamlab.texture.open3d_lite import import_open3d
        o3d = import_open3d()
        assert not hasattr(o3d, "visualization")
        import open3d.visualization
        print(hasattr(open3d.visualization, "draw_plotly"), o3d.visualization is open3d.visualization)
    """)
    assert out == "True True"


def test_an_open3d_already_loaded_is_taken_as_it_is():
    out = _run("""
        import open3d
        from slamlab.texture.open3d_lite import import_open3d
        print(import_open3d() is open3d, hasattr(open3d.visualization, "draw_plotly"))
    """)
    assert out == "True True"
