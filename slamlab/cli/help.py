"""`slamlab --help`: one line per config group and per top-level key, made from the schemas.

Hydra's own help listed every group twice (each with its `schema/*` twin, which users never
pick) and the whole default config, 157 lines without a word on what anything does. This one
is short, and written from the code so that it cannot fall behind it:

- a group's choices are the YAML files in `slamlab/conf/<group>/` (the default starred, from
  config.yaml's defaults list); its line is the docstring of its field in the top-level schema
  (`slamlab.config.store.AppConfig`);
- a top-level key's line is the docstring of its field in `slamlab.config.run.RunConfig`, with
  its default.

`slamlab --hydra-help` still prints Hydra's own options; `slamlab --cfg job` the resolved config.
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import textwrap
from importlib import resources

from slamlab.cli.overrides import PRESET_GROUP, config_groups

HEADER = """slamlab: particle-filter SLAM with texture mapping. One run, or a sweep with -m.
  slamlab                                   run on the built-in simulated THOR sequence
  slamlab dataset=carmen dataset.path=LOG   run on a CARMEN log (LOG.relations scores it)
  slamlab +experiment=lidar2d dataset.path=LOG   the robust preset for any 2D lidar log
  slamlab -m particles=50,100,150           a sweep; a comparison report ends it
  slamlab GROUP=CHOICE KEY=VALUE ...        pick a choice of a group, set any key"""
FOOTER = """Each group's own keys (e.g. matcher.beam_step) and their values: slamlab GROUP=CHOICE --cfg job.
Outputs: outputs/DATE/TIME/ (docs/RUN_DIRECTORY.md). Docs: README.md. Hydra's options: slamlab --hydra-help."""
PRESETS_DOC = "frozen presets, added with '+': the 2D lidar preset, the simulated worlds, the ladder, ..."
WIDTH = 100  # the choices are wrapped to this many columns


def field_docs(cls: type) -> dict[str, str]:
    """{field: its docstring} for a dataclass whose fields are followed by a string literal
    (the attribute-docstring convention); fields without one are left out. Inherited fields
    are read from the class that declares them."""
    out: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if not dataclasses.is_dataclass(klass) or klass is object:
            continue
        try:
            tree = ast.parse(textwrap.dedent(inspect.getsource(klass)))
        except (OSError, TypeError, SyntaxError):
            continue
        body = tree.body[0].body if tree.body and isinstance(tree.body[0], ast.ClassDef) else []
        for stmt, after in zip(body, body[1:]):
            if (isinstance(stmt, ast.AnnAssign) and isinstance(stmt.target, ast.Name) and isinstance(after, ast.Expr)
                    and isinstance(after.value, ast.Constant) and isinstance(after.value.value, str)):
                out[stmt.target.id] = " ".join(after.value.value.split())
    return out


def default_choices() -> dict[str, str]:
    """{group: default choice} from config.yaml's defaults list."""
    import yaml

    text = resources.files("slamlab.conf").joinpath("config.yaml").read_text(encoding="utf-8")
    out = {}
    for item in yaml.safe_load(text).get("defaults", []):
        if isinstance(item, dict):
            for k, v in item.items():
                if isinstance(v, str) and not str(k).startswith(("override", "hydra")):
                    out[str(k)] = v
    return out


def help_text() -> str:
    """The whole of `slamlab --help`."""
    from slamlab.config.run import RunConfig
    from slamlab.config.store import AppConfig

    groups = config_groups()
    defaults = default_choices()
    group_docs = field_docs(AppConfig)
    key_docs = field_docs(RunConfig)
    lines = [HEADER, "", "Config groups: GROUP=CHOICE (* the default)"]
    order = [g for g in group_docs if g in groups] + sorted(g for g in groups if g not in group_docs and g != PRESET_GROUP)
    rows = [(g, group_docs.get(g, ""), " | ".join(c + ("*" if defaults.get(g) == c else "") for c in groups[g])) for g in order]
    if PRESET_GROUP in groups:
        rows.append((PRESET_GROUP, PRESETS_DOC, "+experiment=" + " | ".join(groups[PRESET_GROUP])))
    name_w = max(len(r[0]) for r in rows)
    for name, doc, choices in rows:
        lines.append(f"  {name:<{name_w}}  {doc}")
        lines.extend(textwrap.wrap(choices, WIDTH, initial_indent=" " * (name_w + 4), subsequent_indent=" " * (name_w + 6),
                                   break_on_hyphens=False))
    lines += ["", "Top-level keys: KEY=VALUE (default)"]
    defaults_of = {f.name: f.default for f in dataclasses.fields(RunConfig)}
    keys = []
    for name, doc in key_docs.items():
        d = defaults_of.get(name, dataclasses.MISSING)
        nested = d is dataclasses.MISSING
        keys.append((f"{name}.*" if nested else name, "" if nested else _value_text(d), doc))
    kw = max(len(k[0]) for k in keys)
    vw = max(len(k[1]) for k in keys)
    lines += [f"  {n:<{kw}}  {v:<{vw}}  {doc}" for n, v, doc in keys]
    lines += ["", FOOTER]
    return "\n".join(lines)


def _value_text(v: object) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    return "null" if v is None else str(v)
