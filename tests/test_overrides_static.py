"""The override check's fast path (cli.overrides.static_keys) reads the config's keys from the
YAML files instead of composing the config: it must find exactly the keys Hydra composes,
for every preset and group choice, or answer None (then the check composes as before)."""

from __future__ import annotations

import pytest
from hydra import compose, initialize_config_module
from omegaconf import OmegaConf

from slamlab.cli.overrides import PRESET_GROUP, _dotted_keys, check_overrides, config_groups, hydra_mode_unset, multirun_flag, static_keys

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


@pytest.mark.parametrize(("argv", "sweep"), [
    (["-m", "particles=1,2"], True), (["--multirun", "seed=1"], True), (["--multi", "seed=1"], True), (["--m"], True),
    (["-mc", "job"], True), (["-cn", "config", "-m"], True), (["hydra.run.dir=out", "seed=-m"], False), (["seed=1"], False),
    (["-c", "nonesuch"], False), (["--c"], False), (["-m", "--version"], False),  # refused or answered by Hydra's parser: no sweep
])  # fmt: skip
def test_a_sweep_flag_is_read_as_hydras_parser_reads_it(argv, sweep, capsys):
    assert multirun_flag(argv) is sweep
    assert capsys.readouterr() == ("", "")  # a yes-or-no question: Hydra itself says what is wrong, once


def test_a_sweep_by_any_flag_spelling_claims_no_run_folder(tmp_path):
    from slamlab.cli import app
    from slamlab.io.rundir import RunFile

    folder = tmp_path / "r"
    assert app._claim_given_run_dir(["--multi", f"hydra.run.dir={folder}"]) is None
    assert not folder.exists()
    claimed = app._claim_given_run_dir([f"hydra.run.dir={folder}"])  # a single run claims it
    assert claimed == (folder, True) and (folder / RunFile.CLAIM).exists()
    app._release_unused_claim(claimed)
    assert not folder.exists()
