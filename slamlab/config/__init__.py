"""Typed configuration: one dataclass per config group choice, the single source of its keys,
defaults, types and value ranges.

- `checks`: the range checks (ConfigError naming the full key, e.g. `resampler.threshold`);
- `slam`, `texture`, `sim`, `run`: the schemas of the SLAM components, the texture stage, the
  simulated dataset and the run-level keys;
- `SCHEMAS`: {group: {choice: schema}}, what `store.register` puts in Hydra's ConfigStore
  (`schema/<group>/<choice>`), which the YAML files in `slamlab/conf/` extend;
- `construct`: build the object a schema's `_target_` names from it.

A bottom layer: it imports no component (their classes are named by `_target_` strings), and
Hydra only in `store`.
"""

from __future__ import annotations

import dataclasses
import importlib
from typing import Any, TypeVar

from slamlab.config.datasets import CarmenDatasetConfig, RosbagDatasetConfig, ThorDatasetConfig
from slamlab.config.run import RecordConfig, RunConfig, StepsConfig
from slamlab.config.sim import SimDatasetConfig, SimParams
from slamlab.config.slam import (
    CourseFilterConfig,
    CourseMotionConfig,
    GraphFilterConfig,
    GridMatcherConfig,
    LikelihoodMatcherConfig,
    LinearExpWeightingConfig,
    LinearWeightingConfig,
    LogSumExpWeightingConfig,
    MapConfig,
    MultinomialResamplerConfig,
    Odometry4MotionConfig,
    RbpfFilterConfig,
    ResidualResamplerConfig,
    StratifiedResamplerConfig,
    SystematicResamplerConfig,
)
from slamlab.config.texture import ImagePlaneGroundConfig, PlaneGroundConfig, TextureConfig, ThresholdGroundConfig
from slamlab.errors import ConfigError

# {group: {choice: schema}}: `conf/<group>/<choice>.yaml` extends `schema/<group>/<choice>`
# (weighting/logsumexp_t3.yaml extends logsumexp and overrides the temperature).
SCHEMAS: dict[str, dict[str, type]] = {
    "motion": {"course": CourseMotionConfig, "odometry4": Odometry4MotionConfig},
    "weighting": {"linear": LinearWeightingConfig, "linear_exp": LinearExpWeightingConfig, "logsumexp": LogSumExpWeightingConfig},
    "resampler": {"systematic": SystematicResamplerConfig, "stratified": StratifiedResamplerConfig,
                  "multinomial": MultinomialResamplerConfig, "residual": ResidualResamplerConfig},
    "matcher": {"grid": GridMatcherConfig, "likelihood": LikelihoodMatcherConfig},
    "map": {"default": MapConfig},
    "filter": {"course": CourseFilterConfig, "rbpf": RbpfFilterConfig, "graph": GraphFilterConfig},
    "ground": {"threshold": ThresholdGroundConfig, "plane": PlaneGroundConfig, "image_plane": ImagePlaneGroundConfig},
    "texture": {"default": TextureConfig},
    "dataset": {"sim": SimDatasetConfig, "carmen": CarmenDatasetConfig, "thor": ThorDatasetConfig, "rosbag": RosbagDatasetConfig},
}


def schema_for_target(group: str, target: str | None) -> type | None:
    """The schema of `group` whose `_target_` is `target` (texture: its only schema), or None
    (a user's own class: it is built from its config node as it is)."""
    choices = SCHEMAS.get(group, {})
    if target is None:
        return next(iter(choices.values())) if len(choices) == 1 and not _has_target(next(iter(choices.values()))) else None
    for schema in choices.values():
        if _has_target(schema) and schema._target_ == target:  # type: ignore[attr-defined]
            return schema
    return None


def _has_target(schema: type) -> bool:
    return any(f.name == "_target_" for f in dataclasses.fields(schema))


T = TypeVar("T")


def import_target(path: str, key: str) -> Any:
    """The class or function `module.name` names; ConfigError(`key`) if there is none."""
    module, _, name = str(path).rpartition(".")
    try:
        return getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError, ValueError) as exc:
        raise ConfigError(key, f"cannot build {path!r}: {exc}") from None


def construct(config: Any, base: type[T], group: str) -> T:
    """Build the `base` instance that `config._target_` names, with the config's other fields
    as keyword arguments (a schema that is itself the settings object, like `MapConfig`, is
    returned as it is). ConfigError(`group._target_`) if the target is missing or not a `base`."""
    target = getattr(config, "_target_", None)
    cls = import_target(target, f"{group}._target_") if target else None
    if cls is None:
        raise ConfigError(f"{group}._target_", f"missing: choose one of the files in conf/{group}/")
    if isinstance(cls, type) and isinstance(config, cls):
        obj: Any = config
    else:
        kwargs = {f.name: getattr(config, f.name) for f in dataclasses.fields(config) if f.name != "_target_"}
        try:
            obj = cls(**kwargs)
        except TypeError as exc:  # a `_target_` whose arguments are not this schema's keys
            raise ConfigError(f"{group}._target_", f"cannot build {target!r}: {exc}") from None
    if not isinstance(obj, base):
        raise ConfigError(f"{group}._target_", f"{target!r} is not a {base.__name__}")
    return obj


__all__ = [
    "SCHEMAS", "schema_for_target", "construct", "import_target",
    "RunConfig", "StepsConfig", "RecordConfig", "SimParams", "SimDatasetConfig", "TextureConfig",
]
