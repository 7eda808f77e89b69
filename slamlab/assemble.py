"""The application edge: the composed Hydra config -> typed objects, checked and built once.

    setup = assemble(cfg)            # RunSetup: run knobs, SLAM components, texture settings
    run_slam(sequence, setup.components)
    run_texture(..., setup.ground, setup.texture)

Each config group node becomes its schema's dataclass (`slamlab.config`): a node Hydra
composed from `conf/` is already typed by it; a node read back from a run's saved
`.hydra/config.yaml` (slamlab-verify) is plain and gets the schema its `_target_` names.
Unknown keys and wrong types become ConfigError naming the key, and so do the schemas' range
checks. Below this module no function takes a DictConfig.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

import slamlab.config.store  # noqa: F401  (the schemas the YAML files extend, for any compose)
from slamlab.config import construct, import_target, schema_for_target
from slamlab.config.run import RunConfig
from slamlab.config.slam import CourseFilterConfig
from slamlab.config.texture import TextureConfig
from slamlab.errors import ConfigError
from slamlab.slam.engine import Components
from slamlab.slam.filters import FilterKind
from slamlab.slam.grid import MapSettings
from slamlab.slam.matcher import Matcher
from slamlab.slam.motion import MotionModel
from slamlab.slam.resample import Resampler
from slamlab.slam.weighting import Weighting

RUN_KEYS = tuple(f.name for f in dataclasses.fields(RunConfig))


@dataclass(frozen=True)
class RunSetup:
    """One run's typed configuration: the run-level knobs, the SLAM engine's components, and
    the texture stage's settings (`ground`: the detector's schema object; detectors are built
    fresh for every texture run, as they may carry a seeded generator)."""

    run: RunConfig
    components: Components
    ground: Any
    texture: TextureConfig


def _typed_node(node: DictConfig, schema: type, key: str) -> Any:
    """`node` checked against `schema` (unknown keys, types, ranges) as a `schema` instance."""
    try:
        merged = OmegaConf.merge(OmegaConf.structured(schema), node)
        return OmegaConf.to_object(merged)
    except OmegaConfBaseException as exc:
        sub = getattr(exc, "full_key", None) or getattr(exc, "key", None)
        message = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise ConfigError(f"{key}.{sub}" if key and sub else (sub or key), message) from None


def typed_group(cfg: DictConfig, group: str) -> Any:
    """The config group `group` of `cfg` as its schema's object (a user's own `_target_`
    without a schema: a plain object holding the node's values, built by `construct`)."""
    node = OmegaConf.select(cfg, group) if isinstance(cfg, DictConfig) else None
    if node is None:
        raise ConfigError(group, f"missing: choose one of the files in conf/{group}/")
    if not isinstance(node, DictConfig):
        raise ConfigError(group, f"must be a config node, got {node!r}")
    schema = OmegaConf.get_type(node)
    if not dataclasses.is_dataclass(schema):
        schema = schema_for_target(group, node.get("_target_"))
    if schema is not None:
        return _typed_node(node, schema, group)
    target = node.get("_target_")
    if target is None:
        raise ConfigError(f"{group}._target_", f"missing: choose one of the files in conf/{group}/")
    import_target(str(target), f"{group}._target_")  # a clear error for a missing class
    values = OmegaConf.to_container(node, resolve=True)
    fields = [(str(k), Any, dataclasses.field(default=v)) for k, v in values.items() if k != "_target_"]  # type: ignore[union-attr]
    plain = dataclasses.make_dataclass(f"{group}_config", [("_target_", str, dataclasses.field(default=str(target))), *fields])
    return plain()


def run_settings(cfg: DictConfig) -> RunConfig:
    """The run-level keys (`particles`, `seed`, `mode`, `steps.*`, `record.*`, ...) as a
    checked RunConfig."""
    present = {k: cfg[k] for k in RUN_KEYS if k in cfg}
    return _typed_node(OmegaConf.create(present), RunConfig, "")


def build_components(cfg: DictConfig, run: RunConfig | None = None) -> Components:
    """Check every value the engine uses and build its components, once; ConfigError names
    the key (e.g. `particles`, `resampler.threshold`) before any work is done."""
    run = run or run_settings(cfg)
    # configs saved before the filter group existed ran the course filter
    has_filter = isinstance(cfg, DictConfig) and OmegaConf.select(cfg, "filter") is not None
    s = run.steps
    return Components(
        particles=run.particles,
        seed=run.seed,
        mode=run.mode,
        every=s.every,
        min_distance_m=s.min_distance_m,
        min_angle_rad=s.min_angle_rad,
        skip_static_start=s.skip_static_start,
        max_scans=s.max_scans,
        max_steps=s.max_steps,
        between=s.between,
        odom_jump_m=s.odom_jump_m,
        odom_jump_rad=s.odom_jump_rad,
        motion=construct(typed_group(cfg, "motion"), MotionModel, "motion"),
        weighting=construct(typed_group(cfg, "weighting"), Weighting, "weighting"),
        resampler=construct(typed_group(cfg, "resampler"), Resampler, "resampler"),
        matcher=construct(typed_group(cfg, "matcher"), Matcher, "matcher"),
        map=construct(typed_group(cfg, "map"), MapSettings, "map"),
        filter=construct(typed_group(cfg, "filter") if has_filter else CourseFilterConfig(), FilterKind, "filter"),
        record_particles=run.record_particles,
        record_replay=run.record.replay,
    )


def assemble(cfg: DictConfig) -> RunSetup:
    """Everything a run needs from its config, typed and checked (ConfigError names the key)."""
    run = run_settings(cfg)
    components = build_components(cfg, run)
    texture = typed_group(cfg, "texture") if OmegaConf.select(cfg, "texture") is not None else TextureConfig(enabled=False)
    ground = typed_group(cfg, "ground") if texture.enabled else None
    if texture.enabled:
        from slamlab.texture.pipeline import evaluated_detector

        for name in texture.evaluate_detectors:  # a misspelt name fails now, not after SLAM
            evaluated_detector(name)
    return RunSetup(run=run, components=components, ground=ground, texture=texture)
