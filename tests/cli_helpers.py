"""Run the real console commands in a subprocess, as a user would (`python -m` with this
checkout's code), with the test session's simulated-data cache; or, where a test checks only
exit status and messages, call their entry point in this process (`call_inprocess`)."""

from __future__ import annotations

import logging
import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest


def cli_env(cache: Path | None = None, extra: dict[str, str] | None = None) -> dict[str, str]:
    env = {**os.environ, "MPLBACKEND": "Agg", **(extra or {})}
    if cache is not None:
        env["SLAMLAB_CACHE_DIR"] = str(cache)
    return env


def slamlab_start(args: list[str], cwd: Path, cache: Path | None = None) -> subprocess.Popen:
    """`slamlab ARGS` started in the background (stdout/stderr as text pipes)."""
    return subprocess.Popen([sys.executable, "-m", "slamlab.cli.app", *args], cwd=cwd, env=cli_env(cache),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def slamlab_cli(args: list[str], cwd: Path, cache: Path | None = None, timeout: float = 900,
                env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    """`slamlab ARGS`, waited for (`env`: variables set on top of this process's)."""
    return subprocess.run([sys.executable, "-m", "slamlab.cli.app", *args], cwd=cwd, env=cli_env(cache, env),
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


def call_inprocess(main: Callable[[], None], prog: str, args: list[str], capsys: pytest.CaptureFixture,
                   monkeypatch: pytest.MonkeyPatch, cwd: Path | None = None,
                   cache: Path | None = None) -> subprocess.CompletedProcess:
    """A console command's entry point `main` called in this process with `sys.argv` =
    [prog, *args]: for tests that check only its exit status and messages (no start-up cost
    of a new interpreter). Returns what `subprocess.run` would (returncode, stdout, stderr).
    The logging handlers Hydra installs (console, the run's slamlab.log) are closed and the
    previous ones restored, so later tests log as before."""
    if cwd is not None:
        monkeypatch.chdir(cwd)
    if cache is not None:
        monkeypatch.setenv("SLAMLAB_CACHE_DIR", str(cache))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    monkeypatch.setattr(sys, "argv", [prog, *args])
    root = logging.getLogger()
    handlers, level = list(root.handlers), root.level
    capsys.readouterr()  # only this call's output
    code: int | str | None = 0
    try:
        main()
    except SystemExit as exc:
        code = exc.code
    finally:
        for h in root.handlers:
            if h not in handlers:
                h.close()
        root.handlers[:] = handlers
        root.setLevel(level)
    out = capsys.readouterr()
    returncode = code if isinstance(code, int) else (0 if code is None else 1)
    return subprocess.CompletedProcess([prog, *args], returncode, out.out, out.err)
