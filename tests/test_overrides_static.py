"""The override check's fast path (cli.overrides.static_keys) reads the config's keys from the
YAML files instead of composing the config: it must find exactly the keys Hydra composes,
for every preset and group choice, or answer None (then the check composes as before)."""

from __future__ import annotations

import pytest
from hydra import compose, initialize_config_module
from omegaconf import OmegaConf

from slamlab.cli.overrides import PRESET_GROUP, _dotted_keys, check_overrides, config_groups, hydra_mode_unset, static_keys

GROUPS = config_groups()
CASES = (
    [[]]
    + [[f"+{PRESET_GROUP}={p}"] for p in GROUPS[PRESET_GROUP]]
    + [[f"{g}={c}"] for g, cs in GROUPS.items() if g != PRESET_GROUP for c in cs]
    + [[f"+{PRESET_GROUP}=lidar2d", "dataset=rosbag"], [f"+{PRESET_GROUP}=intel", "filter=course", "matcher=grid"],
       [f"+{PRESET_GROUP}=grading", "texture=none"]]
)  # fmt: skip


def composed_keys(choices: list[str]) -> set[str]:
    with initialize_config_module(config_module="slamlab.conf", version_base="1.3"):
        cfg = compose(config_name="config", overrides=choices)
    return {k for k in _dotted_keys(OmegaConf.to_container(cfg, resolve=False)) if not k.startswith("hydra")}


@pytest.mark.parametrize("choices", CASES, ids=lambda c: " ".join(c) or "defaults")
def test_static_keys_are_the_composed_keys(choices):
    static = static_keys(choices)
    # the shipped files are all readable (None, "unsure", would only make the check slower)
    assert static is not None
    assert {k for k in static if k != "hydra.mode"} == composed_keys(choices)


@pytest.mark.parametrize("choices", CASES, ids=lambda c: " ".join(c) or "defaults")
def test_static_keys_know_which_presets_set_hydras_mode(choices):
    # Hydra's run mode (a job or a sweep) comes from the config when a file sets it: the
    # fast path must see exactly those files (experiment=ladder), or a sweep preset would run once
    with initialize_config_module(config_module="slamlab.conf", version_base="1.3"):
        cfg = compose(config_name="config", overrides=choices, return_hydra_config=True)
    assert ("hydra.mode" in static_keys(choices)) == (cfg.hydra.mode is not None)


@pytest.mark.parametrize(
    "argv, unset",
    [
        (["+experiment=lidar2d", "dataset.path=/x.clf", "steps.max_scans=1"], True),
        (["+experiment=intel"], True),  # includes lidar2d, which sets no mode
        (["-m", "particles=10,30", "filter=course,rbpf"], True),
        ([], True),
        (["+experiment=ladder"], False),  # a sweep preset: hydra.mode=MULTIRUN
        (["-m", "+experiment=lidar2d,ladder"], False),  # any value of a swept group counts
        (["hydra.mode=MULTIRUN"], False),
        (["--config-path", "/run/.hydra", "--config-name", "config"], False),  # a saved config: not ours to read
        (["+experiment=glob(*)"], False),  # Hydra's sweep syntax: unsure
        (["~matcher"], False),
    ],
)
def test_hydras_mode_compose_is_skipped_only_when_no_config_sets_the_mode(argv, unset):
    assert hydra_mode_unset(argv) is unset


def test_the_lidar2d_command_line_is_checked_without_composing(monkeypatch):
    import hydra

    def no_compose(*a, **k):
        raise AssertionError("composed")

    monkeypatch.setattr(hydra, "compose", no_compose)
    argv = ["+experiment=lidar2d", "dataset.path=/data/intel.clf.bz2", "steps.max_scans=1", "progress=off",
            "hydra.run.dir=/tmp/x"]  # fmt: skip
    assert check_overrides(argv) is None


def test_unknown_keys_still_get_the_composed_message():
    assert check_overrides(["partciles=50"]) == "unknown key 'partciles' (did you mean 'particles'?)"
    # in a carmen file but not in the default dataset (sim): only composing knows
    msg = check_overrides(["dataset.on_bad_line=skip"])
    assert msg is not None and msg.startswith("unknown key 'dataset.on_bad_line'")
    assert check_overrides(["+experiment=lidar2d", "dataset.on_bad_line=skip"]) is None


def _run_config(overrides: list[str]):
    with initialize_config_module(config_module="slamlab.conf", version_base="1.3"):
        return compose(config_name="config", overrides=overrides, return_hydra_config=True)


def test_a_single_run_claims_the_folder_hydra_will_write_into(tmp_path):
    import os

    from slamlab.cli import app, run_claim
    from slamlab.io.rundir import RunFile

    # an interpolated name resolves as Hydra resolves it: no early reading of the command line could
    cfg = _run_config([f"hydra.run.dir={tmp_path}/seed${{seed}}", "seed=3"])
    run_claim.ClaimRunDirCallback().on_run_start(config=cfg)
    folder = tmp_path / "seed3"
    assert (folder / RunFile.CLAIM).read_text() == str(os.getpid())
    assert cfg.hydra.run.dir == str(folder)
    app._release_unused_claim()  # the run never started: the folder it made is given back
    assert not folder.exists()


def test_the_default_folder_is_named_once(tmp_path, monkeypatch):
    from slamlab.cli import app, run_claim
    from slamlab.io.rundir import RunFile

    monkeypatch.chdir(tmp_path)
    cfg = _run_config([])
    assert "${now:" in OmegaConf.to_container(cfg.hydra.run)["dir"]  # microseconds: each reading names another folder
    run_claim.ClaimRunDirCallback().on_run_start(config=cfg)
    named = OmegaConf.to_container(cfg.hydra.run)["dir"]  # what Hydra's run_job reads after the callback
    assert "${" not in named and (tmp_path / named / RunFile.CLAIM).exists()
    app._release_unused_claim()


def test_a_folder_another_run_holds_is_refused_before_hydra_writes_into_it(tmp_path, capsys):
    from slamlab.cli import run_claim
    from slamlab.io.rundir import RunFile

    folder = tmp_path / "r"
    folder.mkdir()
    (folder / RunFile.CLAIM).write_text("1")  # held by another process (pid 1)
    with pytest.raises(SystemExit) as stop:
        run_claim.ClaimRunDirCallback().on_run_start(config=_run_config([f"hydra.run.dir={folder}"]))
    assert stop.value.code == 2
    assert "already holds a run" in capsys.readouterr().err
    assert not run_claim.CLAIMED and (folder / RunFile.CLAIM).read_text() == "1"
