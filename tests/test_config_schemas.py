"""Structured configs (`slamlab.config`): every YAML in a component group is typed by its
schema, defaults have one source, saved (plain) configs build the same objects, and mistakes
name the key."""

from __future__ import annotations

import dataclasses
import inspect

import numpy as np
import pytest
from hydra import compose, initialize_config_module
from omegaconf import OmegaConf

from slamlab.assemble import assemble, build_components, typed_group
from slamlab.cli.overrides import config_groups
from slamlab.config import SCHEMAS, construct
from slamlab.config.slam import GridMatcherConfig, LikelihoodMatcherConfig
from slamlab.errors import ConfigError
from slamlab.slam.matcher import GridMatcher, LikelihoodFieldMatcher

def _same(a: object, b: object) -> bool:
    """Same class and attributes (arrays compared by value)."""
    va, vb = vars(a), vars(b)
    return type(a) is type(b) and va.keys() == vb.keys() and all(np.array_equal(va[k], vb[k]) for k in va)


TYPED_GROUPS = ("motion", "weighting", "resampler", "matcher", "map", "filter", "ground", "texture")


def _cfg(*overrides: str):
    with initialize_config_module(config_module="slamlab.conf", version_base="1.3"):
        return compose(config_name="config", overrides=list(overrides))


@pytest.mark.parametrize("group", TYPED_GROUPS)
def test_every_choice_is_typed_by_a_registered_schema(group):
    schemas = set(SCHEMAS[group].values())
    for choice in config_groups()[group]:
        node = _cfg(f"{group}={choice}")[group]
        assert OmegaConf.get_type(node) in schemas, (group, choice)


def test_component_defaults_are_the_schemas():
    # the drift issue 9 found: LikelihoodFieldMatcher's Python defaults vs the YAML, GridMatcher.beam_step 1 vs 4
    for cls, schema in ((LikelihoodFieldMatcher, LikelihoodMatcherConfig), (GridMatcher, GridMatcherConfig)):
        params = inspect.signature(cls.__init__).parameters
        for f in dataclasses.fields(schema):
            if f.name != "_target_":
                assert params[f.name].default == f.default, (cls.__name__, f.name)
    built = construct(typed_group(_cfg("matcher=likelihood"), "matcher"), LikelihoodFieldMatcher, "matcher")
    assert _same(built, LikelihoodFieldMatcher())


def test_a_saved_plain_config_builds_the_same_components():
    cfg = _cfg("+experiment=lidar2d", "dataset.path=x.clf")
    plain = OmegaConf.create(OmegaConf.to_yaml(cfg))  # as slamlab-verify reads .hydra/config.yaml back
    assert OmegaConf.get_type(plain.matcher) is dict
    a, b = assemble(cfg), assemble(plain)
    assert a.run == b.run and a.texture == b.texture and a.ground == b.ground
    for name in ("motion", "weighting", "resampler", "matcher", "filter"):
        assert _same(getattr(a.components, name), getattr(b.components, name)), name
    assert a.components.map == b.components.map


def test_yaml_overrides_and_texture_none():
    assert _cfg("weighting=logsumexp_t3").weighting.temperature == 3.0
    setup = assemble(_cfg("texture=none"))
    assert setup.texture.enabled is False and setup.ground is None


@pytest.mark.parametrize("node, key", [
    ({"matcher": {"_target_": "slamlab.slam.matcher.GridMatcher", "beam_stp": 2}}, "matcher.beam_stp"),
    ({"matcher": {"_target_": "slamlab.slam.matcher.GridMatcher", "beam_step": "many"}}, "matcher.beam_step"),
    ({"matcher": {"_target_": "slamlab.slam.matcher.GridMatcher", "beam_step": 0}}, "matcher.beam_step"),
    ({"matcher": {"_target_": "no.such.Matcher"}}, "matcher._target_"),
    ({"texture": {"stride": 0}}, "texture.stride"),
])
def test_plain_config_mistakes_name_the_key(node, key):
    group = next(iter(node))
    with pytest.raises(ConfigError) as e:
        typed_group(OmegaConf.create(node), group)
    assert e.value.key == key


def test_unknown_evaluated_detector_fails_before_the_run():
    with pytest.raises(ConfigError, match="texture.evaluate_detectors"):
        assemble(_cfg("texture.evaluate_detectors=[threshold,nope]"))


def test_a_target_without_schema_is_built_from_its_own_keys():
    # a user's own class: no schema, its YAML's keys go to the constructor as they are
    node = OmegaConf.create({"motion": {"_target_": "slamlab.slam.motion.Odometry4Motion", "alpha1": 0.2}})
    SCHEMAS_motion = dict(SCHEMAS["motion"])
    try:
        del SCHEMAS["motion"]["odometry4"]
        m = construct(typed_group(node, "motion"), object, "motion")
    finally:
        SCHEMAS["motion"].clear()
        SCHEMAS["motion"].update(SCHEMAS_motion)
    assert m.a1 == 0.2 and m.a2 == 0.01


def test_run_level_checks_keep_their_messages():
    with pytest.raises(ConfigError, match=r"config 'particles': must be an integer >= 1, got 0"):
        build_components(_cfg("particles=0"))
    with pytest.raises(ConfigError, match=r"config 'mode': must be one of slam, odometry, predict, got 'fast'"):
        build_components(_cfg("mode=fast"))
    with pytest.raises(ConfigError, match=r"config 'record.particles': must be auto, true or false"):
        build_components(_cfg("record.particles=sometimes"))
    with pytest.raises(ConfigError, match=r"config 'matcher.isolated': must be one of drop, stretch, got 'keep'"):
        build_components(_cfg("+experiment=lidar2d", "matcher.isolated=keep"))
    with pytest.raises(ConfigError, match=r"config 'matcher.isolated': stretch needs matcher.max_gap_m > 0"):
        build_components(_cfg("+experiment=lidar2d", "matcher.isolated=stretch", "matcher.max_gap_m=0"))
    with pytest.raises(ConfigError, match=r"config 'matcher.refine': must be one of climb, gauss_newton, got 'newton'"):
        build_components(_cfg("+experiment=lidar2d", "matcher.refine=newton"))
    with pytest.raises(ConfigError, match=r"config 'matcher.refine': gauss_newton does not support isolated=stretch"):
        build_components(_cfg("+experiment=lidar2d", "matcher.isolated=stretch", "matcher.refine=gauss_newton"))
