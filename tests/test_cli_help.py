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
