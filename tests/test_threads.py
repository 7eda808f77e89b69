"""numba's threads: slamlab loads the `tbb` wheel's library so the parallel kernels run on
TBB (slamlab/__init__.py), a layer the user names still wins, and the RBPF's results are
the same bytes on TBB and on OpenMP. Each case is a fresh process: numba picks its threading
layer once per process, at the first parallel kernel. Also: the command-line programs keep
OpenBLAS to one thread (slamlab/cli/__init__.py)."""

import os
import platform
import subprocess
import sys
from pathlib import Path

import pytest

TESTS = Path(__file__).parent

# the RBPF on test_slam_engine's room (12 particles: the likelihood matcher's parallel search
# and the tiled map update), then the layer numba ran it on and the sha256 of the trajectory,
# the online path and the map
_ROOM_RUN = """
import hashlib, sys
sys.path.insert(0, {tests!r})
import slamlab
import numba
from slamlab.assemble import build_components
from slamlab.slam.engine import run_slam
from test_slam_engine import _cfg, _room_sequence
res = run_slam(_room_sequence(), build_components(_cfg("filter=rbpf", "particles=12", "seed=3", "matcher=likelihood")))
sha = hashlib.sha256(res.trajectory.tobytes() + res.causal.tobytes() + res.log_odds.data.tobytes()).hexdigest()
print(numba.threading_layer(), numba.get_num_threads(), sha)
"""


def _room(layer: str | None) -> tuple[str, int, str]:
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_THREADING_LAYER", "NUMBA_NUM_THREADS")}
    env["NUMBA_NUM_THREADS"] = "2"  # two threads even on a one-core runner: the schedule is what differs
    if layer is not None:
        env["NUMBA_THREADING_LAYER"] = layer
    proc = subprocess.run([sys.executable, "-c", _ROOM_RUN.format(tests=str(TESTS))], env=env, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-3000:]
    used, threads, sha = proc.stdout.split()[-3:]
    return used, int(threads), sha


@pytest.mark.slow
@pytest.mark.skipif(not (sys.platform == "linux" and platform.machine() == "x86_64"),
                    reason="the tbb wheel is a dependency on Linux x86-64 only (pyproject.toml)")
def test_rbpf_runs_on_tbb_by_default_and_gives_the_bytes_it_gives_on_openmp():
    default = _room(None)
    openmp = _room("omp")
    assert default[:2] == ("tbb", 2), "slamlab should have loaded the tbb wheel's libtbb for numba"
    assert openmp[:2] == ("omp", 2), "NUMBA_THREADING_LAYER, the user's choice, should win"
    assert default[2] == openmp[2]


def _openblas_threads_seen_by(code: str, user_value: str | None) -> str:
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    if user_value is not None:
        env["OPENBLAS_NUM_THREADS"] = user_value
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout.split()[-1]


def test_the_programs_keep_openblas_to_one_thread_unless_the_user_chose():
    # the setting only works if NumPy (which starts OpenBLAS's threads) loads after it
    code = ("import os, sys; import slamlab.cli; assert 'numpy' not in sys.modules, 'numpy loaded first'; "
            "import slamlab.cli.app; print(os.environ.get('OPENBLAS_NUM_THREADS'))")
    assert _openblas_threads_seen_by(code, None) == "1"
    assert _openblas_threads_seen_by(code, "3") == "3"
    # a library import of slamlab leaves the user's process alone
    assert _openblas_threads_seen_by("import os, slamlab.slam.engine; print(os.environ.get('OPENBLAS_NUM_THREADS'))", None) == "None"
