"""How the `slamlab` command ends (`cli.app.command`): a single run ends with `os._exit` once
its log and output are flushed, with the status Python's own exit would give; any Hydra flag
(a sweep however spelled) ends the normal way, through Python's teardown."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from cli_helpers import slamlab_cli

# `main` replaced by one that logs to a file, writes unflushed stdout, then ends as asked; an
# atexit hook says whether Python's teardown ran
SCRIPT = textwrap.dedent("""
    import atexit, logging, sys
    import slamlab.cli.app as app

    LOG, END = sys.argv[1], eval(sys.argv[2])

    def fake_main():
        handler = logging.FileHandler(LOG)
        logging.getLogger().addHandler(handler)
        logging.getLogger().setLevel(logging.INFO)
        logging.getLogger("slamlab").info("last line of the log")
        sys.stdout.write("unflushed output")
        if END != "return":
            raise SystemExit(END)

    atexit.register(lambda: print("teardown ran", file=sys.stderr, flush=True))
    app.main = fake_main
    sys.argv = ["slamlab", *sys.argv[3:]]
    app.command()
""")


def end_with(tmp_path: Path, end: object, *args: str) -> subprocess.CompletedProcess:
    log = tmp_path / "run.log"
    return subprocess.run([sys.executable, "-c", SCRIPT, str(log), repr(end), *args],
                          capture_output=True, text=True, timeout=120, cwd=tmp_path)


@pytest.mark.parametrize(("end", "status", "said"), [
    ("return", 0, ""), (None, 0, ""), (0, 0, ""), (3, 3, ""), (-1, 255, ""), (256, 0, ""),
    ("boom", 1, "boom"), (2.5, 1, "2.5"),
])  # fmt: skip
def test_a_single_run_ends_at_once_with_pythons_status_and_nothing_lost(tmp_path, end, status, said):
    r = end_with(tmp_path, end, "seed=1")
    assert r.returncode == status, r.stderr
    assert r.stdout == "unflushed output"
    assert (tmp_path / "run.log").read_text() == "last line of the log\n"
    assert "teardown ran" not in r.stderr  # os._exit: Python's teardown skipped
    assert said in r.stderr and "Traceback" not in r.stderr


@pytest.mark.parametrize("flag", [["-m"], ["--multirun"], ["--multi"], ["-mc", "job"], ["--config-dir", "x"]])
def test_any_hydra_flag_ends_the_normal_way(tmp_path, flag):
    r = end_with(tmp_path, 3, *flag, "seed=1")
    assert r.returncode == 3
    assert r.stdout == "unflushed output"
    assert "teardown ran" in r.stderr


def test_a_real_run_leaves_its_whole_log(tmp_path, sim_cache):
    run = tmp_path / "run"
    r = slamlab_cli(["steps.max_scans=20", "texture=none", "report=false", "progress=off", "dataset.duration_s=20",
                     f"hydra.run.dir={run}"], tmp_path, sim_cache, timeout=600)
    assert r.returncode == 0, r.stderr
    last = (run / "slamlab.log").read_text().splitlines()[-1]
    assert "outputs in" in last and str(run) in last
