"""How a run was made: which preset (`+experiment=NAME`) and which command-line overrides,
and whether it is a faithful run of a frozen preset.

Course staff grade with `slamlab-verify --preset grading RUN_DIR`: a run passes only if it
was made with `+experiment=grading` and changed nothing but where the data and the outputs
live (`PATH_KEYS`), and its saved config equals the preset composed today with those paths.
Reading the overrides alone could be fooled by editing `.hydra/overrides.yaml`; the config
comparison cannot, since the re-run is made from the saved config.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import yaml
from omegaconf import OmegaConf

from slamlab.config.run import RunConfig
from slamlab.io.rundir import RunFile
from slamlab.run_compare import first_nested_difference, value_at

PRESET_GROUP = "experiment"
# Keys that say where inputs and outputs live, or how the run is displayed: they change no result.
PATH_KEYS = frozenset({
    "dataset.path", "dataset.root", "dataset.relations", "dataset.calibration_dir", "dataset.cache_dir",
    "dataset.lidar_file", "dataset.joint_file", "hydra.run.dir", "hydra.sweep.dir", "progress", "report",
})


@dataclass(frozen=True, slots=True)
class RunOrigin:
    """The preset a run was made with (None: no preset) and its other overrides (`key=value`)."""

    preset: str | None
    overrides: list[str]

    def describe(self) -> str:
        """One line for people, e.g. `preset grading; overrides: particles=10`."""
        preset = f"preset {self.preset}" if self.preset else "no preset"
        return f"{preset}; overrides: {' '.join(self.overrides) if self.overrides else 'none'}"


def _key(override: str) -> str:
    """`+experiment=grading` -> `experiment`; `~a.b` -> `a.b`."""
    return override.split("=", 1)[0].lstrip("+~")


def read_origin(run_dir: Path) -> RunOrigin:
    """The preset and overrides saved by Hydra in `RUN_DIR/.hydra/overrides.yaml`."""
    path = Path(run_dir) / RunFile.HYDRA_OVERRIDES
    overrides = [str(o) for o in (yaml.safe_load(path.read_text()) or [])] if path.exists() else []
    presets = [o.split("=", 1)[1] for o in overrides if _key(o) == PRESET_GROUP and "=" in o]
    rest = [o for o in overrides if _key(o) != PRESET_GROUP]
    return RunOrigin(presets[-1] if presets else None, rest)


def compose_preset(name: str, overrides: list[str]):
    """The preset's config as today's config files compose it, with the given overrides."""
    from hydra import compose, initialize_config_module

    with initialize_config_module(config_module="slamlab.conf", version_base="1.3"):
        return compose(config_name="config", overrides=[f"+{PRESET_GROUP}={name}", *overrides])


def _fill_missing(saved: dict, defaults: dict) -> None:
    """Add to `saved` (in place) every key of `defaults` it lacks, nested dicts key by key."""
    for key, value in defaults.items():
        if key not in saved:
            saved[key] = value
        elif isinstance(value, dict) and isinstance(saved[key], dict):
            _fill_missing(saved[key], value)


def preset_violation(run_dir: Path, preset: str) -> str | None:
    """None if `run_dir` is a faithful run of `+experiment=PRESET`, else why it is not (one line)."""
    origin = read_origin(run_dir)
    if origin.preset != preset:
        made = f"+{PRESET_GROUP}={origin.preset}" if origin.preset else "no preset"
        return f"the run was not made with +{PRESET_GROUP}={preset} (it used {made})"
    extra = [o for o in origin.overrides if _key(o) not in PATH_KEYS]
    if extra:
        return f"the run changed the {preset} preset: {' '.join(extra)} (only data and output paths may change)"
    from hydra.errors import HydraException

    try:
        frozen = compose_preset(preset, origin.overrides)
    except HydraException as exc:
        return f"preset {preset!r} cannot be composed: {str(exc).splitlines()[0]}"
    saved = OmegaConf.to_container(OmegaConf.load(Path(run_dir) / RunFile.HYDRA_CONFIG), resolve=False)
    # a run-level key added since the run was made (e.g. steps.odom_jump_m) is re-run at its schema default, which
    # `run_settings` fills in: the saved config holds it at that value
    _fill_missing(saved, OmegaConf.to_container(OmegaConf.structured(RunConfig), resolve=False))
    wanted = OmegaConf.to_container(frozen, resolve=False)
    diff = first_nested_difference(saved, wanted, lambda _, key: key in PATH_KEYS)
    if diff is None:
        return None
    key, what = diff
    if what == "value":
        why = f"'{key}' is {value_at(saved, key)!r} in the run, {value_at(wanted, key)!r} in the preset"
    else:
        why = f"'{key}' is in {'the run' if what == 'only a' else 'the preset'} only"
    return f"the run's saved config differs from the {preset} preset: {why}"
