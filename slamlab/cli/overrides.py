"""Check `slamlab key=value ...` before Hydra sees it, so a typo gets one clear line:

    unknown key 'partciles' (did you mean 'particles'?)
    unknown choice 'systemtic' for resampler (did you mean 'systematic'?); choices: multinomial, residual, stratified, systematic
    config 'particles': Value 'abc' of type 'str' could not be converted to Integer

Hydra would answer the first with the advice to write `+partciles=50` (which then silently
runs with the default), the second with its config search path, and the third (a value of the
wrong type for its schema, `slamlab.config`) with a stack of merge messages. Only mistakes this
module is sure of are reported; anything else is left to Hydra's own messages.
"""

from __future__ import annotations

import difflib
import functools
from importlib import resources

# Options that point Hydra at another config (slamlab-verify's re-run): not our groups and keys.
FOREIGN_CONFIG_FLAGS = ("--config-path", "-cp", "--config-name", "-cn", "--config-dir", "-cd",
                        "--experimental-rerun", "--shell-completion", "-sc")
PRESET_GROUP = "experiment"


def config_groups() -> dict[str, list[str]]:
    """{group: sorted choices} of slamlab's own config groups (conf/<group>/<choice>.yaml)."""
    root = resources.files("slamlab.conf")
    return {
        d.name: sorted(f.name[: -len(".yaml")] for f in d.iterdir() if f.name.endswith(".yaml"))
        for d in root.iterdir()
        if d.is_dir() and d.name not in ("hydra", "__pycache__")
    }


def _suggest(word: str, candidates: list[str]) -> str:
    close = difflib.get_close_matches(word, candidates, n=1, cutoff=0.6)
    return f" (did you mean '{close[0]}'?)" if close else ""


def _dotted_keys(node: object, prefix: str = "") -> list[str]:
    """Every key path in a nested dict: ['particles', 'steps', 'steps.every', ...]."""
    out = []
    if isinstance(node, dict):
        for k, v in node.items():
            key = f"{prefix}{k}"
            out.append(key)
            out.extend(_dotted_keys(v, key + "."))
    return out


def _values(override) -> list[str]:
    if override.is_sweep_override():
        try:
            return list(override.sweep_string_iterator())
        except Exception:  # noqa: BLE001 - e.g. a range over a group: Hydra will say
            return []
    return [override.get_value_element_as_str()]


def check_overrides(argv: list[str]) -> str | None:
    """None if every `key=value` in `argv` names a known key or group choice, else the message."""
    if any(a.split("=", 1)[0] in FOREIGN_CONFIG_FLAGS for a in argv):
        return None
    args = [a for a in argv if "=" in a and not a.startswith("-")]
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException

    try:
        overrides = OverridesParser.create().parse_overrides(args)
    except HydraException:
        return None  # a syntax error: Hydra's message shows where
    groups = config_groups()
    keys, group_choices, values_set = [], [], []
    for o in overrides:
        name = o.key_or_group
        if name.startswith("hydra") or o.is_delete() or o.package is not None:
            continue
        if name in groups:
            values = _values(o)
            for v in values:
                if v not in groups[name]:
                    return (f"unknown choice '{v}' for {name}{_suggest(v, groups[name])}; "
                            f"choices: {', '.join(groups[name])}")
            if name == PRESET_GROUP and not (o.is_add() or o.is_force_add()):
                return f"presets are added with '+': +{PRESET_GROUP}={values[0] if values else 'NAME'}"
            if values:
                group_choices.append(f"{o.input_line.split('=', 1)[0]}={values[0]}")
        else:
            keys.append(name)
            values_set.append((name, o))  # deletions were skipped above
    if not keys:
        return None
    static = static_keys(group_choices)
    if static is not None and all(key in static for key in keys):
        # every key is there: no need to compose the config (Hydra does, to run); the
        # values' types are checked against the schemas, which needs no composing either
        return _type_mistake(group_choices, values_set)
    from hydra import compose, initialize_config_module
    from omegaconf import OmegaConf

    try:
        with initialize_config_module(config_module="slamlab.conf", version_base="1.3"):
            cfg = compose(config_name="config", overrides=group_choices)
    except HydraException:
        return None
    known = _dotted_keys(OmegaConf.to_container(cfg, resolve=False))
    for key in keys:
        if key not in known:
            return f"unknown key '{key}'{_suggest(key, known)}"
    return _type_mistake(group_choices, values_set)


def _type_mistake(group_choices: list[str], values_set: list[tuple[str, object]]) -> str | None:
    """A value its schema (`slamlab.config`) cannot take (`particles=abc`), as `config 'KEY':
    why`. Checked against the schema dataclasses directly (no second compose): a group key is
    wrong only if every schema of the group that has the key refuses the value; keys without a
    schema (e.g. a CARMEN dataset's) are left to the run."""
    import dataclasses

    from omegaconf import OmegaConf
    from omegaconf.errors import OmegaConfBaseException

    from slamlab.config import SCHEMAS
    from slamlab.config.store import AppConfig

    for name, override in values_set:
        group, _, rest = name.partition(".")
        if group in SCHEMAS and rest:
            field = rest.split(".", 1)[0]
            schemas = [sc for sc in SCHEMAS[group].values() if field in {f.name for f in dataclasses.fields(sc)}]
            key = rest
        else:
            schemas, key = [AppConfig], name
        if not schemas:
            continue
        try:
            values = list(override.sweep_iterator()) if override.is_sweep_override() else [override.value()]
        except Exception:  # noqa: BLE001 - e.g. a range over strings: Hydra will say
            continue
        for value in values:
            why = None
            for schema in schemas:
                try:
                    OmegaConf.update(OmegaConf.structured(schema), key, value, merge=True)
                    why = None
                    break
                except OmegaConfBaseException as exc:
                    why = why or str(exc).splitlines()[0]
            if why is not None:
                return f"config '{name}': {why}"
    return None


# ----------------------------------------------------------------------------- fast path
# Composing the config to learn its keys costs 0.2-0.25 s of CPU, and Hydra composes it
# again to run: a sixth of a one-scan run. The keys can be read from the YAML files the
# composition would merge: config.yaml, the chosen file of each group (the command line's
# choice, else the preset's `override /group: X`, else config.yaml's default) and the
# preset files (package _global_). Anything this reading is not sure of (another package
# header, a group file with its own defaults, an unknown defaults entry) answers None, and
# the config is composed as before; a key this reading does not find is checked by
# composing too, so every message comes from the composed config.


def static_keys(group_choices: list[str]) -> frozenset[str] | None:
    """The dotted keys of the config that `group_choices` (e.g. ["+experiment=lidar2d",
    "dataset=carmen"]) compose to, read from the YAML files; None when unsure. Remembered
    per process: `check_overrides` and `hydra_mode_unset` ask for the same choices."""
    return _static_keys(tuple(group_choices))


@functools.lru_cache(maxsize=16)
def _static_keys(group_choices: tuple[str, ...]) -> frozenset[str] | None:
    import yaml

    root = resources.files("slamlab.conf")
    try:
        base = _read_yaml(root / "config.yaml", yaml)
        if base is None:
            return None
        choices: dict[str, str] = {}
        keys: set[str] = set()
        for entry in base.get("defaults", []):
            if isinstance(entry, dict) and len(entry) == 1:
                (group, choice), = entry.items()
                if not group.startswith("override "):
                    choices[group] = choice
            elif entry == "slamlab_schema":  # the run-level keys' schema (slamlab.config.store)
                from slamlab.config.run import RunConfig

                keys |= _schema_keys(RunConfig)
            elif entry != "_self_":
                return None
        cli = dict(c.lstrip("+").split("=", 1) for c in group_choices)
        keys |= set(_dotted_keys({k: v for k, v in base.items() if k not in ("defaults", "hydra")})) | _hydra_mode(base)
        preset = cli.pop(PRESET_GROUP, None)
        if preset is not None:
            preset_keys = _preset(root, preset, choices, yaml, depth=0)
            if preset_keys is None:
                return None
            keys |= preset_keys
        choices.update(cli)
        for group, choice in choices.items():
            if group == PRESET_GROUP:
                continue
            data = _read_yaml(root / group / f"{choice}.yaml", yaml)
            if data is None:
                return None
            keys.add(group)
            if "defaults" in data:  # a file extending its schema: [/schema/<group>/<name>@_here_, _self_]
                schema = _extended_schema(group, data.pop("defaults"))
                if schema is None:
                    return None
                keys.update(f"{group}.{k}" for k in _schema_keys(schema))
            keys.update(f"{group}.{k}" for k in _dotted_keys(data))
        return frozenset(keys)
    except (OSError, ValueError, TypeError, AttributeError, yaml.YAMLError):
        return None


def _extended_schema(group: str, defaults: object) -> type | None:
    """The schema dataclass a group file extends, when its defaults list is exactly
    `[/schema/<group>/<name>@_here_, _self_]`; None otherwise (unsure)."""
    from slamlab.config import SCHEMAS

    if not isinstance(defaults, list) or len(defaults) != 2 or defaults[1] != "_self_":
        return None
    entry = defaults[0]
    prefix, suffix = f"/schema/{group}/", "@_here_"
    if not (isinstance(entry, str) and entry.startswith(prefix) and entry.endswith(suffix)):
        return None
    return SCHEMAS.get(group, {}).get(entry[len(prefix):-len(suffix)])


def _schema_keys(schema: type) -> set[str]:
    """The dotted keys of a schema dataclass, nested dataclasses included."""
    from omegaconf import OmegaConf

    return set(_dotted_keys(OmegaConf.to_container(OmegaConf.structured(schema), resolve=False)))


def _preset(root, name: str, choices: dict[str, str], yaml, depth: int) -> set[str] | None:
    """Keys a `# @package _global_` preset adds; its `override /group: X` entries (and those
    of the presets it includes) go into `choices`. None when unsure."""
    if depth > 5:
        return None
    path = root / PRESET_GROUP / f"{name}.yaml"
    text = path.read_text()
    if not text.startswith("# @package _global_"):
        return None
    data = _parse(text, yaml)
    keys: set[str] = set()
    for entry in data.get("defaults", []):
        if isinstance(entry, str) and entry != "_self_":  # another preset of the group
            inner = _preset(root, entry, choices, yaml, depth + 1)
            if inner is None:
                return None
            keys |= inner
        elif isinstance(entry, dict) and len(entry) == 1:
            (key, choice), = entry.items()
            if not key.startswith("override /") or "/" in key[len("override /"):]:
                return None
            choices[key[len("override /"):]] = choice
        elif entry != "_self_":
            return None
    keys.update(_dotted_keys({k: v for k, v in data.items() if k not in ("defaults", "hydra")}))
    return keys | _hydra_mode(data)


def _hydra_mode(data: dict) -> set[str]:
    """{"hydra.mode"} when a config file sets Hydra's run mode (a preset that is a sweep,
    e.g. experiment=ladder), else nothing: Hydra's own keys are not slamlab's, but this one
    decides whether Hydra runs a job or a sweep (`hydra_mode_unset`)."""
    hydra = data.get("hydra")
    return {"hydra.mode"} if isinstance(hydra, dict) and "mode" in hydra else set()


def hydra_mode_unset(argv: list[str]) -> bool:
    """True when no config file the command line composes sets `hydra.mode` and no override
    does (read from the YAML files as `static_keys` does); False when one does or when this
    reading is unsure (a config from elsewhere, a deletion, a sweep syntax other than a
    comma list). Hydra composes the whole config once only to learn that mode
    (`Hydra.get_mode`, 0.2-0.3 s of CPU, before it composes it again to run); when nothing
    sets it the answer is None, and the command line's `-m` alone decides."""
    groups = config_groups()
    choices: dict[str, list[str]] = {}
    for arg in argv:
        if arg.split("=", 1)[0] in FOREIGN_CONFIG_FLAGS:
            return False
        if arg.startswith("~"):
            return False  # a deletion: what is left is Hydra's to say
        if arg.startswith("-") or "=" not in arg:
            continue  # -m, --multirun, a positional Hydra would refuse
        key, value = arg.split("=", 1)
        name = key.lstrip("+")
        if "@" in name:
            return False
        if name == "hydra" or name.startswith("hydra.mode") or name.startswith("hydra/"):
            return False
        if name in groups:
            if not value or any(ch in value for ch in "[](){}$*'\"\\"):
                return False  # glob(), range(), quoting: Hydra's parser, not this one
            choices[f"+{name}" if key.startswith("+") else name] = value.split(",")
    first = {k: v[0] for k, v in choices.items()}
    combos = [first] + [{**first, key: value} for key, values in choices.items() for value in values[1:]]
    for combo in combos:  # every value of a swept group, the other groups at their first
        static = static_keys([f"{k}={v}" for k, v in combo.items()])
        if static is None or "hydra.mode" in static:
            return False
    return True


def _parse(text: str, yaml) -> object:
    """A YAML file's content, {} when empty; libyaml's parser when PyYAML has it (~10x faster
    than the pure-Python one: the override check reads up to a dozen files per command)."""
    return yaml.load(text, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader)) or {}


def _read_yaml(path, yaml) -> dict | None:
    """A config file's mapping; None when it carries a `# @package` header (its keys would
    land elsewhere) or is not a mapping."""
    text = path.read_text()
    if any(line.startswith("# @package") for line in text.splitlines()[:3]):
        return None
    data = _parse(text, yaml)
    return data if isinstance(data, dict) else None

