"""A misspelled key or group choice on the command line gets one line naming it and what was
meant, not Hydra's `+key=value` advice (which would run with the default) or its search path."""

from __future__ import annotations

import pytest

from slamlab.cli.overrides import check_overrides


@pytest.mark.parametrize("args, message", [
    (["partciles=50"], "unknown key 'partciles' (did you mean 'particles'?)"),
    (["+partciles=50"], "unknown key 'partciles' (did you mean 'particles'?)"),
    (["dataset=carmen", "dataset.pth=x.clf"], "unknown key 'dataset.pth' (did you mean 'dataset.path'?)"),
    (["steps.max_scan=10"], "unknown key 'steps.max_scan' (did you mean 'steps.max_scans'?)"),
    (["resampler=systemtic"], "unknown choice 'systemtic' for resampler (did you mean 'systematic'?); "
                              "choices: multinomial, residual, stratified, systematic"),
    (["-m", "ground=threshold,plan"], "unknown choice 'plan' for ground (did you mean 'plane'?); "
                                      "choices: image_plane, plane, threshold"),
    (["experiment=grading"], "presets are added with '+': +experiment=grading"),
])
def test_a_typo_is_one_line_naming_what_was_meant(args, message, tmp_path, slamlab_app):
    proc = slamlab_app([*args, f"hydra.run.dir={tmp_path / 'r'}"], cwd=tmp_path)
    assert proc.returncode == 2
    assert proc.stderr.strip() == f"slamlab: {message}"
    assert not (tmp_path / "r").exists()  # nothing ran, no folder made


@pytest.mark.parametrize("args", [
    ["particles=50", "seed=3", "steps.max_scans=100"],
    ["dataset=carmen", "dataset.path=x.clf", "dataset.relations=y"],
    ["+experiment=lidar2d", "dataset.path=x.clf"],
    ["-m", "filter=course,rbpf", "particles=10,20", "hydra/launcher=joblib"],
    ["ground=plane", "ground.distance_threshold_m=0.03", "texture=none"],
    ["++hydra.callbacks.sweep_report.enabled=false", "hydra.run.dir=x"],
    ["--config-path", "/elsewhere", "--config-name", "config", "anything=1"],  # verify's re-run
])
def test_valid_overrides_pass(args):
    assert check_overrides(args) is None
