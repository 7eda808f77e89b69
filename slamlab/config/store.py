"""Register every schema in Hydra's ConfigStore (imported by `slamlab.conf`, so composing
slamlab's config package registers them; `register()` is idempotent).

- `schema/<group>/<choice>`: the dataclass of one group choice; `conf/<group>/<choice>.yaml`
  extends it (`defaults: [/schema/<group>/<choice>@_here_, _self_]`) and only overrides;
- `slamlab_schema`: the run-level keys, and a slot per config group, extended by config.yaml.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from slamlab.config import SCHEMAS
from slamlab.config.run import RunConfig


@dataclass
class AppConfig(RunConfig):
    """The composed config's top level: the run-level keys and one node per config group
    (typed by the group's own schema)."""

    dataset: Any = None
    filter: Any = None
    motion: Any = None
    weighting: Any = None
    resampler: Any = None
    matcher: Any = None
    map: Any = None
    ground: Any = None
    texture: Any = None


def register() -> None:
    """Put the schemas in Hydra's ConfigStore (again: harmless)."""
    from hydra.core.config_store import ConfigStore

    cs = ConfigStore.instance()
    cs.store(name="slamlab_schema", node=AppConfig, provider="slamlab")
    for group, choices in SCHEMAS.items():
        for choice, schema in choices.items():
            cs.store(group=f"schema/{group}", name=choice, node=schema, provider="slamlab")


register()
