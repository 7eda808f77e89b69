"""Shared fixtures. Real-data tests read `SLAMLAB_DATA_DIR` (default: ../shared/data beside
the checkout); they skip when it is absent, unless SLAMLAB_REQUIRE_DATA=1 (set by .ci/run),
in which case they fail."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from slamlab.paths import data_dir


@pytest.fixture(scope="session")
def shared_data() -> Path:
    d = data_dir()
    if d is None or not d.is_dir():
        msg = "shared data not found: set SLAMLAB_DATA_DIR to the folder holding carmen/ and thor/"
        if os.environ.get("SLAMLAB_REQUIRE_DATA") == "1":
            pytest.fail(msg)
        pytest.skip(msg)
    return d


@pytest.fixture(scope="session")
def sim_cache(tmp_path_factory) -> Path:
    """A cache folder shared by the whole test session (simulated sequences are reused)."""
    return tmp_path_factory.mktemp("slamlab-cache")


@pytest.fixture
def slamlab_app(capsys, monkeypatch):
    """`slamlab ARGS` called in this process, returning what `subprocess.run` would
    (`cli_helpers.call_inprocess`): for tests of exit statuses and messages only."""
    from cli_helpers import call_inprocess
    from slamlab.cli.app import main

    def run(args: list[str], cwd: Path | None = None, cache: Path | None = None):
        return call_inprocess(main, "slamlab", args, capsys, monkeypatch, cwd=cwd, cache=cache)

    return run
