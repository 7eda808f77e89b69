"""Run the real console commands in a subprocess, as a user would (`python -m` with this
checkout's code), with the test session's simulated-data cache."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path


def cli_env(cache: Path | None = None) -> dict[str, str]:
    env = {**os.environ, "MPLBACKEND": "Agg"}
    if cache is not None:
        env["SLAMLAB_CACHE_DIR"] = str(cache)
    return env


def slamlab_start(args: list[str], cwd: Path, cache: Path | None = None) -> subprocess.Popen:
    """`slamlab ARGS` started in the background (stdout/stderr as text pipes)."""
    return subprocess.Popen([sys.executable, "-m", "slamlab.cli.app", *args], cwd=cwd, env=cli_env(cache),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def slamlab_cli(args: list[str], cwd: Path, cache: Path | None = None, timeout: float = 900) -> subprocess.CompletedProcess:
    """`slamlab ARGS`, waited for."""
    return subprocess.run([sys.executable, "-m", "slamlab.cli.app", *args], cwd=cwd, env=cli_env(cache),
                          capture_output=True, text=True, timeout=timeout)


def verify_cli(args: list[str], cache: Path | None = None, timeout: float = 900) -> subprocess.CompletedProcess:
    """`slamlab-verify ARGS`, waited for."""
    return subprocess.run([sys.executable, "-m", "slamlab.cli.verify", *args], env=cli_env(cache),
                          capture_output=True, text=True, timeout=timeout)


def sweep_cli(sweep_dir: Path, args: list[str], cache: Path | None = None, timeout: float = 900) -> subprocess.CompletedProcess:
    """`slamlab -m ARGS` with the package's own config folder into `sweep_dir` (made by the
    caller's tmp factory; its parent is the working directory), waited for."""
    import slamlab

    conf = Path(slamlab.__file__).resolve().parent / "conf"
    return slamlab_cli(["-cp", str(conf), "-m", *args, f"hydra.sweep.dir={sweep_dir}"], cwd=sweep_dir.parent,
                       cache=cache, timeout=timeout)
