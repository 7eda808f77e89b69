"""Shared pieces of both reports: the Jinja2 environment, number formatting, atomic writes,
and the re-run command of a run."""

from __future__ import annotations

import functools
import hashlib
import math
import os
import shlex
from datetime import datetime
from pathlib import Path
from typing import Any

import jinja2
from markupsafe import Markup, escape

from slamlab.artifacts import write_text
from slamlab.paths import cache_dir

TEMPLATE_DIR = Path(__file__).resolve().parent / "templates"


# Settings the compiled templates depend on: they also name the folder of the compiled ones
_AUTOESCAPE = (("html",), True)  # escape .html templates (and strings): run names, errors, config values are user text
_BLOCKS = {"trim_blocks": True, "lstrip_blocks": True}


def make_environment(loader: jinja2.BaseLoader, bytecode_cache: jinja2.BytecodeCache | None) -> jinja2.Environment:
    """A Jinja2 environment with slamlab's settings (autoescape on; StrictUndefined, so a typo
    in a template fails the tests, not silently)."""
    return jinja2.Environment(
        loader=loader,
        bytecode_cache=bytecode_cache,
        autoescape=jinja2.select_autoescape(list(_AUTOESCAPE[0]), default=_AUTOESCAPE[1]),
        undefined=jinja2.StrictUndefined,
        **_BLOCKS,
    )


@functools.cache
def environment() -> jinja2.Environment:
    """The reports' environment. One per process: it keeps the compiled templates, so a
    sweep's run pages compile them once; across processes `compiled_templates` keeps them."""
    env = make_environment(jinja2.FileSystemLoader(str(TEMPLATE_DIR)), compiled_templates())
    env.filters["num"] = fmt_number
    env.filters["count"] = count_text  # {{ n|count("snapshot") }}: 1 snapshot, 100 snapshots
    env.filters["wbr"] = break_points  # {{ key|wbr }}: a long key may wrap after its dots, slashes, underscores
    return env


class _TemplateCache(jinja2.FileSystemBytecodeCache):
    """Jinja2's folder of compiled templates; a write that fails (a full disk) leaves the
    template uncached and the page rendered."""

    def dump_bytecode(self, bucket: jinja2.bccache.Bucket) -> None:
        try:
            super().dump_bytecode(bucket)
        except OSError:
            pass


def compiled_templates() -> jinja2.BytecodeCache | None:
    """Jinja2's cache of compiled templates under the cache folder (`paths.cache_dir()`), in
    a subfolder named for Jinja2's version and the settings above: Jinja2 finds a template's
    compiled code by its name and checks only its source, so code compiled under other
    settings must live elsewhere. Written atomically by Jinja2. A report process then skips
    compiling the page templates (~0.04 s of the ~1.7 s of CPU a one-scan run takes). None
    where the folder cannot be written: the templates are compiled as before."""
    key = hashlib.sha1(repr((jinja2.__version__, _AUTOESCAPE, sorted(_BLOCKS.items()))).encode()).hexdigest()[:12]
    folder = cache_dir() / "templates" / key
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    return _TemplateCache(str(folder)) if os.access(folder, os.W_OK) else None


def render(template: str, **context: Any) -> str:
    """Render a template from slamlab/report/templates."""
    return environment().get_template(template).render(**context)


def break_points(text: Any) -> Markup:
    """`text` escaped for HTML, with a line-break opportunity (<wbr>) after each '.', '/' and
    '_': a table header such as dataset.duration_s then wraps at its parts, never mid-word."""
    escaped = str(escape(str(text)))
    for ch in "./_":
        escaped = escaped.replace(ch, ch + "<wbr>")
    return Markup(escaped)


def count_text(n: Any, noun: str) -> str:
    """A count with its noun in the right number: 1 particle, 3 particles (nouns in -s, -x or
    -ch take -es)."""
    if n is None:
        return f"? {noun}s"
    plural = noun + ("es" if noun.endswith(("s", "x", "ch")) else "s")
    return f"{fmt_number(n)} {noun if n == 1 else plural}"


def fmt_number(v: Any, digits: int = 4) -> str:
    """Numbers for people: up to `digits` significant digits, ints as ints, NaN/None as a dash."""
    if v is None:
        return "–"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "–"
        if math.isinf(v):
            return "∞" if v > 0 else "-∞"
        if v == int(v) and abs(v) < 1e9:
            return str(int(v)) if abs(v) >= 1 or v == 0 else f"{v:g}"
        text = f"{v:.{digits}g}"
        if "e" in text and 1e-3 <= abs(v) < 1e7:
            # '2e+02' reads badly in a table: round to whole units instead.
            text = f"{v:.0f}"
        return text
    return str(v)


def atomic_write_text(path: Path, text: str) -> Path:
    """Write via a temp file beside `path`, then rename (slamlab.artifacts): readers never
    see a half-written page, and an interrupted build leaves the previous report intact."""
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text(path, text)
    return path


def now_text() -> str:
    return datetime.now().astimezone().strftime("%Y-%m-%d %H:%M:%S %Z")


def quote_override(item: str) -> str:
    """Quote one `key=value` override for a POSIX shell."""
    return shlex.quote(item)


def package_version() -> str:
    try:
        from importlib.metadata import version

        return version("slamlab")
    except Exception:  # noqa: BLE001 - not installed (source tree): say so, don't fail
        return "unknown"
