"""`slamlab --help` (issue 45): one line per config group and top-level key, each explained
from the schemas' docstrings, without Hydra's `schema/*` twins."""

from __future__ import annotations

import dataclasses

from slamlab.cli.help import field_docs, help_text
from slamlab.cli.overrides import config_groups
from slamlab.config.run import RunConfig
from slamlab.config.store import AppConfig


def test_help_explains_every_group_and_top_level_key_in_one_line(slamlab_app):
    out = slamlab_app(["--help"])
    assert out.returncode == 0 and out.stderr == ""
    text = out.stdout
    assert "schema/" not in text
    lines = text.splitlines()
    assert len(lines) < 60  # Hydra's listed 157
    group_docs = field_docs(AppConfig)
    for group, choices in config_groups().items():
        if group == "experiment":
            assert any(line.startswith("  experiment  frozen presets") for line in lines)
            assert all(c in text for c in choices)
            continue
        # the group's line: its name and its schema field's docstring, then its choices
        doc = group_docs[group]
        i = next(i for i, line in enumerate(lines) if line.split() and line.split()[0] == group)
        assert lines[i].endswith(doc), lines[i]
        assert all(c in lines[i + 1] for c in choices)
    for key, doc in field_docs(RunConfig).items():
        assert any(line.split() and line.split()[0] in (key, f"{key}.*") and line.endswith(doc) for line in lines), key
    assert "  filter      where the map lives" in text and "course*" in text  # the default starred
    assert "particles  100" in text


def test_every_group_and_run_key_has_a_docstring():
    """A new group or key without a docstring would get an empty line in --help."""
    docs = field_docs(AppConfig)
    for f in dataclasses.fields(AppConfig):
        assert docs.get(f.name), f"AppConfig.{f.name} has no docstring"
    assert set(field_docs(RunConfig)) == {f.name for f in dataclasses.fields(RunConfig)}
    assert all(len(line) <= 110 for line in help_text().splitlines())


# ---- issue 45: a config error leaves no failed run folder behind --------------------------------
def test_a_mistake_found_before_the_run_leaves_no_folder(slamlab_app, tmp_path):
    """particles=0 or a missing file: one line, exit 2, and no run folder in outputs/ (a sweep
    keeps its failed jobs' folders for its report: tests/test_cli_runs.py)."""
    out = slamlab_app(["particles=0", f"hydra.run.dir={tmp_path / 'given'}"], cwd=tmp_path)
    assert out.returncode == 2 and "config 'particles': must be an integer >= 1, got 0" in out.stderr
    assert "Traceback" not in out.stderr and "details in" not in out.stderr
    assert not (tmp_path / "given").exists()
    out = slamlab_app(["dataset=carmen", f"dataset.path={tmp_path / 'no' / 'such.clf'}"], cwd=tmp_path)
    assert out.returncode == 2 and "such.clf: file not found" in out.stderr
    assert not any(p.is_dir() for p in (tmp_path / "outputs").glob("*/*"))  # no outputs/DATE/TIME
    mine = tmp_path / "mine"
    mine.mkdir()  # a folder the user made: emptied of the run's files, kept
    out = slamlab_app(["particles=0", f"hydra.run.dir={mine}"], cwd=tmp_path)
    assert out.returncode == 2 and mine.is_dir() and list(mine.iterdir()) == []
