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

    # Each field's docstring is its one line in `slamlab --help` (slamlab.cli.help).
    dataset: Any = None
    """the data: the built-in simulated THOR sequence, THOR .mat logs, CARMEN logs or ROS bags"""
    filter: Any = None
    """where the map lives: one map shared by all particles, a map per particle, ..."""
    motion: Any = None
    """how a particle moves between steps: the odometry increment plus sampled noise"""
    weighting: Any = None
    """how a scan's match score becomes the particle's new weight"""
    resampler: Any = None
    """how particles are drawn again when their weights grow uneven (N_eff below a threshold)"""
    matcher: Any = None
    """how each particle's scan is aligned to its map: grid correlation or likelihood field"""
    map: Any = None
    """the occupancy grid: cell size, log-odds of a hit and a pass, beam ranges"""
    ground: Any = None
    """which RGB-D pixels are floor, for the texture"""
    texture: Any = None
    """colouring the floor from RGB-D along the trajectory (texture=none: off)"""


def register() -> None:
    """Put the schemas in Hydra's ConfigStore (again: harmless)."""
    from hydra.core.config_store import ConfigStore

    cs = ConfigStore.instance()
    cs.store(name="slamlab_schema", node=AppConfig, provider="slamlab")
    for group, choices in SCHEMAS.items():
        for choice, schema in choices.items():
            cs.store(group=f"schema/{group}", name=choice, node=schema, provider="slamlab")


register()
