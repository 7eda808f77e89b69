"""The comparison report over many runs: a sweep directory, several sweeps, or any runs.

`build_sweep_report` finds run directories, tabulates them with pandas (swept values as
columns, metrics, best values marked), opens with a verdict (the best configuration on the
headline metric, ties within the seed-to-seed spread; sweep_stats.py), and draws
headline-metric-versus-parameter plots, error over time, maps, overlaid trajectories and
N_eff curves (sweep_figures.py, figures.py). A run that failed is listed with its error and
never stops the report from being written.
"""

from __future__ import annotations

import logging
import math
import os
import shlex
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import pandas as pd
import yaml

from slamlab.errors import SlamlabError
from slamlab.report import figures, sweep_figures
from slamlab.report.columns import ACCURACY_KEYS, HEADLINE_GROUPS, METRIC_BY_KEY, METRICS, get_metric
from slamlab.report.error_series import ATE, error_series
from slamlab.report.html import atomic_write_text, count_text, fmt_number, now_text, package_version, render
from slamlab.io.rundir import RunDirectory, RunFile, SweepFile, read_yaml
from slamlab.report.rundir import (
    STATUS_FAILED,
    STATUS_OK,
    RunDir,
    find_run_dirs,
    flatten,
    load_run,
)
from slamlab.report.run_report import data_fingerprint
from slamlab.report.sweep_stats import (
    SEED_KEY,
    config_groups,
    config_label,
    config_stats,
    is_number,
    memory_note,
    short_value,
    runtime_check,
    sweep_verdict,
    value_text,
)

log = logging.getLogger(__name__)
T = TypeVar("T")

MAX_SERIES = 8  # lines per metric-vs-parameter panel; more is unreadable


@dataclass(slots=True)
class Cell:
    """One table cell: shown text, CSS class, a numeric sort key and an optional link."""

    text: str
    cls: str = ""
    sort: str | None = None
    href: str | None = None
    title: str | None = None  # the whole value when `text` shortens it (a path by its file name)


@dataclass(slots=True)
class Column:
    label: str
    text: bool = False
    title: str = ""
    detail: bool = False  # behind the table's "all columns" switch


@dataclass(slots=True)
class Row:
    label: str
    status: str
    cells: list[Cell] = field(default_factory=list)


@dataclass(slots=True)
class Table:
    columns: list[Column]
    rows: list[Row]


def _safe(what: str, fn: Callable[[], T]) -> T | None:
    """Run one optional piece of the report; a broken artifact costs its figure, not the page."""
    try:
        return fn()
    except Exception as exc:  # noqa: BLE001 - reported in the log, section omitted
        log.warning("sweep report: %s failed: %s", what, exc)
        return None


def _load_safely(path: Path) -> RunDir:
    """load_run, but an unreadable run becomes a failed run carrying the reason."""
    try:
        return load_run(path)
    except SlamlabError as exc:
        files = RunDirectory(path)
        config = files.read_config()
        return RunDir(path=path, status=STATUS_FAILED, error=f"unreadable run directory: {exc}", metrics={},
                      manifest={}, config=config if isinstance(config, dict) else {},
                      overrides=files.read_overrides())


def _parse_value(v: Any) -> Any:
    """Override text to a Python value ("50" -> 50) so parameters sort and plot as numbers."""
    if not isinstance(v, str):
        return v
    try:
        return yaml.safe_load(v)
    except yaml.YAMLError:
        return v


def run_labels(runs: Sequence[RunDir]) -> list[str]:
    """Short unique names: job numbers within one sweep, else paths relative to the common
    ancestor (e.g. `10-00-00/3`)."""
    paths = [r.path for r in runs]
    if len(paths) == 1:
        return [paths[0].name]
    if len({p.parent for p in paths}) == 1:
        return [p.name for p in paths]
    common = Path(os.path.commonpath([str(p) for p in paths]))
    return [str(p.relative_to(common)) for p in paths]


# Overrides that change how a run shows itself, never its results: not parameters of a comparison.
NOT_RESULTS = frozenset({"progress", "report", "hydra.run.dir", "hydra.sweep.dir"})


def swept_parameters(runs: Sequence[RunDir]) -> tuple[list[str], dict[str, list[Any]], list[str]]:
    """(swept keys, values per key per run, common overrides).

    Swept = override keys whose values differ between runs. When runs were started with
    identical overrides but still differ in config (e.g. different defaults), the differing
    config keys are used instead, so the table always says what changed."""
    per_run = [r.overrides_dict() for r in runs]
    keys: list[str] = []
    for d in per_run:
        for k in d:
            if k not in keys:
                keys.append(k)
    # a run that did not override a key used its default: the group's choice or the config's
    # value (a run of the defaults ran 100 particles, not "particles=-")
    values = {k: [_parse_value(d[k]) if k in d else r.setting(k) for r, d in zip(runs, per_run)] for k in keys}
    swept = [k for k in keys if len({value_text(v) for v in values[k]}) > 1 and k not in NOT_RESULTS]
    common = [f"{k}={per_run[0][k]}" for k in keys if k not in swept and k not in NOT_RESULTS and all(k in d for d in per_run)]
    values = {k: values[k] for k in swept}
    if not swept and len(runs) > 1:
        diff = config_differences(runs)
        for k in list(diff)[:6]:
            swept.append(k)
            values[k] = diff[k]
    return swept, values, common


def config_differences(runs: Sequence[RunDir]) -> dict[str, list[Any]]:
    """Flattened config keys whose values differ between runs -> value per run (None = absent)."""
    flats = [flatten(r.config) for r in runs if r.config]
    if len(flats) < 2:
        return {}
    keys: list[str] = []
    for f in flats:
        for k in f:
            if k not in keys:
                keys.append(k)
    out: dict[str, list[Any]] = {}
    all_flats = [flatten(r.config) for r in runs]
    for k in keys:
        vals = [f.get(k) for f in all_flats]
        if len({yaml.safe_dump(v) for v in vals}) > 1:
            out[k] = vals
    return out


def runs_dataframe(runs: Sequence[RunDir], labels: Sequence[str], swept: Sequence[str],
                   values: dict[str, list[Any]]) -> pd.DataFrame:
    """One row per run: label, status, swept values, every known metric (NaN when absent),
    error and path. This is the data behind the HTML table and runs.csv."""
    rows = []
    for i, r in enumerate(runs):
        row: dict[str, Any] = {"run": labels[i], "status": r.status}
        for k in swept:
            row[k] = values[k][i]
        for spec in METRICS:
            row[spec.key] = get_metric(r.metrics, spec.key)
        row["particles_metric"] = r.particles
        row["error"] = r.error if r.status != STATUS_OK else None
        row["path"] = str(r.path)
        rows.append(row)
    return pd.DataFrame(rows)


def _best_mask(df: pd.DataFrame, key: str) -> pd.Series:
    """Cells holding the best value of a metric among ok runs (ties all marked)."""
    spec = METRIC_BY_KEY[key]
    ok = df["status"] == STATUS_OK
    col = df[key].where(ok)
    if spec.better is None or col.notna().sum() < 2 or col.nunique() < 2:
        return pd.Series(False, index=df.index)
    best = col.min() if spec.better == "min" else col.max()
    return np.isclose(col, best, rtol=1e-12, atol=0.0) & ok


def is_partial(run: RunDir) -> bool:
    """An interrupted run that wrote its results so far (metrics.json `partial`)."""
    return run.status == "interrupted" and bool(run.metrics.get("partial"))


def _rel_href(target: Path, out_dir: Path) -> str:
    return Path(os.path.relpath(target, out_dir)).as_posix()


LADDER_NOTE = ("These runs are the steps of the preparation ladder (+experiment=ladder): each step is checked by its"
               " own picture in its report (the run names link to them), not ranked against the others, so no"
               " configuration is called best here.")


def is_ladder(swept: Sequence[str], values: dict[str, list[Any]]) -> bool:
    """A sweep over the ladder's steps (`+experiment=ladder`): stages of one exercise, not rivals."""
    steps = [v for v in values.get("experiment", []) if v is not None]
    return "experiment" in swept and bool(steps) and all(str(v).startswith("ladder_") for v in steps)


def html_table(df: pd.DataFrame, runs: Sequence[RunDir], swept: Sequence[str], out_dir: Path,
               mark_best: bool = True) -> tuple[Table, list[str]]:
    """The every-run table with links, sort keys and best marks (`mark_best`); returns it and
    the metric keys shown."""
    metric_keys = [m.key for m in METRICS if m.table and df[m.key].notna().any()
                   and not (m.hide_when_zero and (df[m.key].fillna(0) == 0).all())]
    has_err = any(not r.ok for r in runs)
    cols = [Column("run", True, "run directory (links to its report)"), Column("status", True)]
    cols += [Column(k, False, "swept parameter") for k in swept]
    # The error sits next to the parameters so a failed row is readable without scrolling.
    if has_err:
        cols.append(Column("error", True, "full text under 'Failed or incomplete runs'"))
    cols += [Column(METRIC_BY_KEY[k].label, False, k, METRIC_BY_KEY[k].detail) for k in metric_keys]
    best = {k: _best_mask(df, k) if mark_best else pd.Series(False, index=df.index) for k in metric_keys}
    rows: list[Row] = []
    for i, r in enumerate(runs):
        rec = df.iloc[i]
        report = r.path / RunFile.REPORT
        cells = [Cell(str(rec["run"]), "text", None, _rel_href(report, out_dir) if report.is_file() else None),
                 Cell(r.status, "text")]
        for k in swept:
            v = rec[k]
            num = isinstance(v, (int, float)) and not isinstance(v, bool)
            full, short = value_text(v), short_value(v)
            cells.append(Cell(short, "param", repr(float(v)) if num else None, title=full if short != full else None))
        if has_err:
            err = r.error if not r.ok and r.error else ""
            cells.append(Cell(err if len(err) <= 60 else err[:57] + "...", "err"))
        for k in metric_keys:
            v = float(rec[k])
            cls = "best" if bool(best[k].iloc[i]) else ""
            if METRIC_BY_KEY[k].detail:
                cls = (cls + " detail").strip()
            cells.append(Cell(fmt_number(v), cls, "" if math.isnan(v) else repr(v)))
        rows.append(Row(str(rec["run"]), r.status, cells))
    return Table(cols, rows), metric_keys


def headline_keys(df: pd.DataFrame) -> list[str]:
    """The headline metrics these runs have: per HEADLINE_GROUPS question, the first key
    with a value in a successful run (accuracy, rotation, runtime, memory, texture)."""
    ok = df[df["status"] == STATUS_OK]
    out = []
    for group in HEADLINE_GROUPS:
        key = next((k for k in group if k in ok and ok[k].notna().any()), None)
        if key is not None:
            out.append(key)
    return out


def seed_aggregate(df: pd.DataFrame, swept: Sequence[str], metric_keys: Sequence[str]) -> Table | None:
    """Mean ± std across seeds per configuration, when a sweep repeats seeds."""
    if SEED_KEY not in swept:
        return None
    ok = df[df["status"] == STATUS_OK]
    others = [k for k in swept if k != SEED_KEY]
    groups = config_groups(ok, others)
    if not groups or max(len(g) for _, g in groups) < 2:
        return None
    extra = ("runtime_s", "scans_per_s", "neff_mean", "trajectory.mean_m")
    wanted = {k for k in metric_keys if k in ACCURACY_KEYS or k in extra} | set(headline_keys(df))
    keys = [m.key for m in METRICS if m.key in wanted]  # table order: CPU time beside wall time
    cols = [Column(k, False) for k in others] + [Column("n seeds")] + [Column(METRIC_BY_KEY[k].label) for k in keys]
    rows = []
    for vals, g in groups:
        cells = [Cell(value_text(v), "", repr(float(v)) if is_number(v) else None) for v in vals]
        cells.append(Cell(str(len(g)), "", str(len(g))))
        for k in keys:
            col = g[k].dropna()
            if col.empty:
                cells.append(Cell("–", "", ""))
                continue
            mean, std = float(col.mean()), float(col.std(ddof=1)) if len(col) > 1 else 0.0
            cells.append(Cell(f"{fmt_number(mean)} ± {fmt_number(std, 2)}", "", repr(mean)))
        rows.append(Row(" ".join(map(str, vals)), STATUS_OK, cells))
    return Table(cols, rows)


def _x_axis(values: Sequence[Any]) -> tuple[list[float], list[str] | None]:
    """Positions of a parameter's values on a plot axis: numbers as numbers; anything else
    (names, a value missing in some runs) as evenly spaced categories with tick labels."""
    if all(is_number(v) and not math.isnan(float(v)) for v in values):
        return [float(v) for v in values], None
    # categories in run order: a sweep lists its values in the order the user chose (e.g. the
    # ladder's steps), which says more than the alphabet; a missing value ("–") goes last
    cats = sorted(dict.fromkeys(value_text(v) for v in values), key=lambda c: c == "–")
    return [float(cats.index(value_text(v))) for v in values], cats


def param_series(df: pd.DataFrame, param: str, others: Sequence[str], key: str) -> list[figures.Series]:
    """Metric `key` of the successful runs against swept `param`: one Series per value of the
    `others` swept parameters (so two parameters are never mixed into one line), each point
    the mean ± std over seeds at one value of `param`. `df` needs an `_x` column: the plot
    position of each run's `param` value (_x_axis)."""
    ok = df[(df["status"] == STATUS_OK) & df[key].notna()]
    series = []
    for gvals, g in config_groups(ok, others)[:MAX_SERIES]:
        stats = g.groupby("_x", sort=True)[key].agg(["mean", "std", "count"])
        std = stats["std"].where(stats["count"] > 1, 0.0).to_numpy(float)
        series.append(figures.Series(config_label(others, gvals) if others else "", stats.index.to_numpy(float),
                                     stats["mean"].to_numpy(float), std, g["_x"].to_numpy(float),
                                     g[key].to_numpy(float)))
    return series


def param_plots(df: pd.DataFrame, swept: Sequence[str]) -> list[dict[str, str]]:
    """The headline metrics (headline_keys) versus each swept parameter (seed excluded: it is
    averaged over), one line per value of the other swept parameters (param_series)."""
    ok = df[df["status"] == STATUS_OK]
    params = varying(ok, [k for k in swept if k != SEED_KEY])  # a value shared by every finished run is no axis
    keys = headline_keys(df)
    if ok.empty or not params or not keys:
        return []
    out = []
    for p in params:
        xs, cats = _x_axis(ok[p].tolist())
        ok_x = ok.assign(_x=xs)
        others = [k for k in params if k != p]
        panels = [(METRIC_BY_KEY[k].label, s) for k in keys if (s := param_series(ok_x, p, others, k))]
        if panels:
            title = f"versus {p}" + (f", one line per {', '.join(others)}" if others else "")
            n_lines = len(config_groups(ok, others))
            if n_lines > MAX_SERIES:
                title += f" (the first {MAX_SERIES} of {n_lines} combinations; the table has them all)"
            out.append({"title": title, "img": sweep_figures.metric_panels(p, panels, cats)})
    return out


def _sweep_commands(runs: Sequence[RunDir]) -> list[str]:
    """`slamlab -m ...` for every sweep the runs came from (multirun.yaml beside the jobs)."""
    cmds: list[str] = []
    for root in dict.fromkeys(r.path.parent for r in runs):
        mr = read_yaml(root / SweepFile.MULTIRUN)
        if not isinstance(mr, dict):
            continue
        task = (((mr.get("hydra") or {}).get("overrides") or {}).get("task")) or []
        cmd = "slamlab -m " + " ".join(shlex.quote(str(t)) for t in task)
        cmds.append(f"{cmd.strip()}    # {root}")
    return cmds


def _short_params(swept: Sequence[str], values: dict[str, list[Any]], i: int) -> str:
    return " ".join(f"{k.split('.')[-1]}={short_value(values[k][i])}" for k in swept)


def _primary_metric(df: pd.DataFrame) -> str | None:
    for k in ACCURACY_KEYS:
        if k in df and df.loc[df["status"] == STATUS_OK, k].notna().any():
            return k
    return None


# How a run is scored, named for the verdict's heading: the first of ACCURACY_KEYS it has.
SCORED_BY = {
    "trajectory.rmse_m": "against ground truth (ATE)",
    "relations.trans_abs_mean_m": "against benchmark relations",
    "map.agreement": "against the true map",
    "consistency.contradiction_share": "by their own map's consistency (no ground truth, no relations)",
}


SCORE_KEYS = (*ACCURACY_KEYS, "consistency.contradiction_share")


def scored_by(df: pd.DataFrame) -> pd.Series:
    """Each run's first score key with a value (None: none), in SCORE_KEYS order."""
    out = pd.Series([None] * len(df), index=df.index, dtype=object)
    for key in reversed([k for k in SCORE_KEYS if k in df]):
        out[df[key].notna()] = key
    return out


def _verdict_sections(df: pd.DataFrame, params: Sequence[str], runs: Sequence[RunDir]) -> list[dict[str, Any]]:
    """One verdict per way the runs are scored (ground truth, relations, ...): runs of
    another dataset scored another way get their own verdict instead of being left out; a
    run scored no way is named in the note of the first."""
    ok = df["status"] == STATUS_OK
    kinds = scored_by(df)
    groups = [k for k in SCORE_KEYS if ((kinds == k) & ok).any()]
    out = []
    for key in groups:
        part = df[(kinds == key) & ok]
        section = _verdict_section(part, params, [runs[i] for i in part.index], key)
        if section is not None:
            if len(groups) > 1:
                section["scope"] = f"Runs scored {SCORED_BY.get(key, key)}: {len(part)} of {int(ok.sum())}"
            out.append(section)
    if not out:
        return out
    notes = []
    n_bad = int((~ok).sum())
    if n_bad:
        notes.append(f"{n_bad} failed or incomplete run{'s' if n_bad != 1 else ''} not counted.")
    unscored = [str(df.loc[i, "run"]) for i in df.index[ok & kinds.isna()]]
    if unscored:
        notes.append(f"Not ranked (no ground truth, relations or consistency score): run{'s' if len(unscored) > 1 else ''}"
                     f" {', '.join(unscored)}.")
    out[0]["excluded"] = " ".join(notes)
    return out


def varying(df: pd.DataFrame, params: Sequence[str]) -> list[str]:
    """The parameters whose values differ between the rows of `df` (as the tables show them)."""
    return [k for k in params if k in df and df[k].map(value_text).nunique() > 1]


def _verdict_section(df: pd.DataFrame, params: Sequence[str], runs: Sequence[RunDir], key: str | None = None) -> dict[str, Any] | None:
    """The verdict on the headline metric (`key`, default the first headline key), as the
    template shows it: summary sentence, the cheapest of the best and its ties, and one row
    per configuration (named by the parameters that differ among these runs)."""
    params = varying(df[df["status"] == STATUS_OK], params)
    keys = [key] if key is not None else headline_keys(df)
    if not keys or keys[0] not in METRIC_BY_KEY:
        return None
    verdict = sweep_verdict(df, params, keys[0])
    if verdict is None:
        return None
    cost_key = next((k for k in ("cpu_time_s", "runtime_s") if df.loc[df["status"] == STATUS_OK, k].notna().any()), None)
    cost = {s.label: s for s in config_stats(df, params, cost_key)} if cost_key else {}
    unit_better = "lower" if METRIC_BY_KEY[verdict.key].better != "max" else "higher"
    rows = []
    best_mean = verdict.standings[0].stat.mean
    for st in verdict.standings:
        c = cost.get(st.stat.label)
        rel = f" ({st.diff / best_mean * 100:+.1f} % of best)" if st.diff and best_mean else ""
        rows.append({
            "label": st.stat.label, "n": st.stat.n, "verdict": st.verdict,
            "value": fmt_number(st.stat.mean) + ("" if math.isnan(st.stat.std) else f" ± {fmt_number(st.stat.std, 2)}"),
            "diff": "–" if st.verdict == "best" else fmt_number(st.diff, 3) + rel,
            "spread": "unknown" if math.isnan(st.spread) else fmt_number(st.spread, 2),
            "cost": "–" if c is None else fmt_number(c.mean, 3),
        })
    contenders = [st.stat.label for st in verdict.standings if st.verdict in ("best", "tie")]
    cheapest = ""
    if cost_key and len(contenders) > 1 and all(c in cost for c in contenders):
        pick = min(contenders, key=lambda c: cost[c].mean)
        cheapest = (f"Of the best and its ties, the cheapest is {pick}"
                    f" ({METRIC_BY_KEY[cost_key].label}: {fmt_number(cost[pick].mean, 3)}, mean over seeds).")
    n_bad = sum(not r.ok for r in runs)
    return {
        "scope": "", "summary": verdict.summary, "cheapest": cheapest, "rows": rows, "label": verdict.label,
        "better": unit_better, "cost_label": METRIC_BY_KEY[cost_key].label if cost_key else "cost",
        "spread_known": verdict.spread_known,
        "excluded": f"{n_bad} failed or incomplete run{'s' if n_bad != 1 else ''} not counted." if n_bad else "",
    }


def _error_over_time(runs: Sequence[RunDir], ok_idx: Sequence[int], groups: Sequence[str],
                     labels: Sequence[str]) -> tuple[str | None, str]:
    """Every run's error over time on one axis (sweep_figures.error_over_time) and its caption."""
    curves, kinds = [], set()
    for i in ok_idx:
        es = _safe(f"error series of {labels[i]}", lambda i=i: error_series(runs[i]))
        if es is not None and es.t.size:
            curves.append(sweep_figures.ErrorCurve(groups[i], es.t, es.error_m))
            kinds.add(es.kind)
    if not curves:
        return None, "No run has ground truth or relations, so there is no error over time."
    if len(kinds) > 1:
        return None, "Some runs are scored against ground truth and others against relations: not one axis."
    if kinds == {ATE}:
        ylabel, smooth = "position error (m)", False
        note = ("Position error of the SLAM trajectory against ground truth at every pose (ATE per pose): "
                "where the lines part is where a configuration went wrong.")
    else:
        ylabel, smooth = "relation error (m)", True
        note = ("Translational error of every benchmark relation, at the time of its later scan, as a rolling "
                "median over 1/40 of the relations: a rise marks where the map broke.")
    note += " One colour per configuration; each of its seeds is a line of that colour."
    return _safe("error over time", lambda: sweep_figures.error_over_time(curves, ylabel, smooth)), note


def _run_maps(runs: Sequence[RunDir], ok_idx: Sequence[int], display: Sequence[str],
              labels: Sequence[str]) -> list[dict[str, str]]:
    """Each successful run's own map with its path (sweep_figures.run_map)."""
    out = []
    for i in ok_idx:
        m = _safe(f"map of {labels[i]}", runs[i].load_map)
        tr = _safe(f"trajectory of {labels[i]}", lambda i=i: runs[i].load_trajectory("slam"))
        gt = _safe(f"ground truth of {labels[i]}", lambda i=i: runs[i].load_trajectory("groundtruth"))
        if m is None:
            continue
        drawn = _safe(f"map figure of {labels[i]}", lambda m=m, tr=tr, gt=gt: sweep_figures.run_map(m, tr, gt))
        if drawn is not None:
            img, (w_m, h_m) = drawn
            out.append({"title": display[i], "img": img, "size": f"{w_m:.0f} × {h_m:.0f} m"})
    return out


def _overlay(runs: Sequence[RunDir], ok_idx: Sequence[int], df: pd.DataFrame, display: Sequence[str],
             labels: Sequence[str]) -> tuple[str | None, str]:
    """Every SLAM path over one map (the most accurate run's); the caption names exactly what is drawn."""
    datasets = {(runs[i].dataset, data_fingerprint(runs[i].manifest)) for i in ok_idx}
    if not ok_idx:
        return None, ""
    if len(datasets) > 1:
        return None, "Runs use different datasets, so their trajectories are not overlaid."
    primary = _primary_metric(df)
    bg = ok_idx[0]
    if primary is not None:
        col = df[primary].where(df["status"] == STATUS_OK)
        bg = int(col.idxmin() if METRIC_BY_KEY[primary].better != "max" else col.idxmax())
    else:
        primary = None  # only interrupted runs: the first one's map
    paths = [(display[i], t) for i in ok_idx
             if (t := _safe("trajectory", lambda i=i: runs[i].load_trajectory("slam"))) is not None]
    if not paths:
        return None, ""
    gt = _safe("ground truth", lambda: runs[bg].load_trajectory("groundtruth"))
    odo = _safe("odometry", lambda: runs[bg].load_trajectory("odometry"))
    bg_map = _safe("map", runs[bg].load_map)
    img = _safe("overlay", lambda: figures.trajectories_overlay(bg_map, f"run {labels[bg]}", paths, gt, odo))
    drawn = ["one colour per run"]
    if gt is not None:
        drawn.insert(0, "black: ground truth")
    if odo is not None:
        drawn.append("dashed red: odometry")
    where = (f"Background: the map of run {labels[bg]}" + (f" (best {METRIC_BY_KEY[primary].label})" if primary else "")
             if bg_map is not None else "No map to draw beneath the paths")
    note = f"{where}. {'; '.join(drawn).capitalize()}."
    if gt is None:
        note += " These runs have no ground truth."
    return img, note


# Runs whose lengths differ more than this are drawn against the share of the run: an 85 s
# run beside a 2,650 s one would be a sliver at the left of a shared time axis.
DURATION_RATIO = 3.0


def _neff(runs: Sequence[RunDir], ok_idx: Sequence[int], display: Sequence[str], labels: Sequence[str]) -> tuple[str | None, str]:
    """N_eff curves; normalised by N when particle counts differ, else raw; against the share
    of each run when their lengths differ by more than DURATION_RATIO, else time."""
    curves = []
    smooth_windows: list[int] = []
    single = [i for i in ok_idx if runs[i].one_trajectory]  # filter=graph: its steps.csv holds a flat N_eff of 1, not a measurement
    ok_idx = [i for i in ok_idx if not runs[i].one_trajectory]
    normalise = len({runs[i].particles for i in ok_idx}) > 1
    tables = {i: s for i in ok_idx if (s := _safe(f"steps of {labels[i]}", runs[i].load_steps)) is not None
              and "neff" in s and len(s)}
    spans = [float(figures.step_times(s)[-1]) for s in tables.values()]
    by_share = len(spans) > 1 and min(spans) > 0 and max(spans) / min(spans) > DURATION_RATIO
    for i, steps in tables.items():
        t = figures.step_times(steps)
        if by_share:
            t = 100.0 * t / max(float(t[-1]), 1e-9)
        y = np.asarray(steps["neff"], float)
        if normalise and runs[i].particles:
            y = y / runs[i].particles
        # N_eff saw-tooths between resamplings; overlaid raw, a dozen runs are a solid band.
        # A centred rolling mean over ~1/50 of the run keeps the trend comparable.
        win = max(1, len(y) // 50)
        if win > 1:
            y = pd.Series(y).rolling(win, center=True, min_periods=1).mean().to_numpy()
        smooth_windows.append(win)
        curves.append((display[i], t, y))
    xlabel = "share of the run (%)" if by_share else "time since first step (s)"
    img = _safe("N_eff overlay", lambda: figures.neff_overlay(curves, "N_eff / N" if normalise else "N_eff", xlabel)) if curves else None
    note = ("N_eff divided by each run's particle count N, since N differs between runs."
            if normalise else "N_eff per filter step of every run.")
    if by_share:
        note += (f" Drawn against the share of each run (0-100 %): the runs last {min(spans):.0f} to {max(spans):.0f} s,"
                 " and on one time axis the short ones would be slivers.")
    if smooth_windows and max(smooth_windows) > 1:
        lo, hi = min(smooth_windows), max(smooth_windows)
        note += (f" Smoothed by a centred rolling mean over {lo if lo == hi else f'{lo}–{hi}'} steps"
                 " (each run's report shows the raw curve with its resampling events).")
    if single:
        note += (f" Not drawn: {', '.join(display[i] for i in single)}"
                 " (one trajectory, no particles: nothing to weigh).")
    return img, note


def build_sweep_report(
    dirs: Sequence[Path],
    out_dir: Path,
    title: str | None = None,
    *,
    filename: str = SweepFile.REPORT,
) -> Path:
    """Compare every run found at or under `dirs`; write `out_dir/<filename>` (self-contained
    HTML, atomically) and `out_dir/runs.csv` (the table). Returns the HTML path.

    Raises SlamlabError when a path does not exist or holds no run directory. Failed or
    unreadable runs are listed with their error; they never stop the report."""
    out_dir = Path(out_dir)
    run_paths = find_run_dirs([Path(d) for d in dirs])
    runs = [_load_safely(p) for p in run_paths]
    labels = run_labels(runs)
    swept, values, common = swept_parameters(runs)
    df = runs_dataframe(runs, labels, swept, values)
    out_dir.mkdir(parents=True, exist_ok=True)
    table, metric_keys = html_table(df, runs, swept, out_dir.resolve(), mark_best=not is_ladder(swept, values))

    display = [f"{labels[i]}: {_short_params(swept, values, i)}" if swept else labels[i] for i in range(len(runs))]
    ok_idx = [i for i, r in enumerate(runs) if r.ok]
    # what the figures draw: the finished runs and the interrupted ones' partial results (marked);
    # the verdict and the best marks count finished runs only
    shown_idx = [i for i, r in enumerate(runs) if r.ok or is_partial(r)]
    display = [f"{d} (interrupted)" if is_partial(runs[i]) else d for i, d in enumerate(display)]
    params = [k for k in swept if k != SEED_KEY]  # a configuration = every swept value but the seed
    groups = [config_label(params, [values[k][i] for k in params]) for i in range(len(runs))]

    ladder = is_ladder(swept, values)
    verdicts = [] if ladder else (_safe("verdict", lambda: _verdict_sections(df, params, runs)) or [])
    runtime = _safe("runtime check", lambda: runtime_check(df, runs))
    memory = _safe("memory note", lambda: memory_note(runs, labels)) or ""
    errors_img, errors_note = _error_over_time(runs, shown_idx, groups, labels)
    maps = _run_maps(runs, shown_idx, display, labels)
    overlay_img, overlay_note = _overlay(runs, shown_idx, df, display, labels)
    neff_img, neff_note = _neff(runs, shown_idx, display, labels)
    plots = _safe("parameter plots", lambda: param_plots(df, swept)) or []
    aggregate = _safe("seed aggregate", lambda: seed_aggregate(df, swept, metric_keys))

    diff = config_differences(runs)
    diff_table = None
    if diff:
        diff_table = {"columns": ["run", *diff.keys()],
                      "rows": [[labels[i], *(value_text(diff[k][i]) for k in diff)] for i in range(len(runs))]}
    base = next((r.config for r in runs if r.config), None)

    failed = [{"label": labels[i], "status": r.status, "error": r.error or "", "log_tail": r.log_tail,
               "params": _short_params(swept, values, i)} for i, r in enumerate(runs) if not r.ok]

    if title is None:
        roots = {r.path.parent for r in runs}
        title = f"Sweep {next(iter(roots))}" if len(roots) == 1 and len(runs) > 1 else f"Comparison of {count_text(len(runs), 'run')}"
    html = render(
        "sweep.html",
        title=title,
        version=package_version(),
        generated=now_text(),
        n_runs=len(runs),
        n_ok=len(ok_idx),
        n_bad=len(runs) - len(ok_idx),
        sources=[str(d) for d in dirs],
        sweep_cmds=_sweep_commands(runs),
        common=" ".join(common),
        verdicts=verdicts,
        ladder_note=LADDER_NOTE if ladder else "",
        runtime=runtime,
        memory_note=memory,
        table=table,
        failed=failed,
        param_plots=plots,
        param_note=("Points: single runs; markers with bars: mean ± standard deviation across seeds."
                    if SEED_KEY in swept else "One point per run."),
        aggregate=aggregate,
        errors_img=errors_img,
        errors_note=errors_note,
        maps=maps,
        has_groundtruth=any(runs[i].file(RunFile.GROUNDTRUTH) is not None for i in shown_idx),
        n_partial=len(shown_idx) - len(ok_idx),
        overlay_img=overlay_img,
        overlay_note=overlay_note,
        neff_img=neff_img,
        neff_note=neff_note,
        diff=diff_table,
        base_config=yaml.safe_dump(base, sort_keys=False) if base else None,
    )
    csv = df.drop(columns=["particles_metric"])
    atomic_write_text(out_dir / SweepFile.RUNS_CSV, csv.to_csv(index=False))
    return atomic_write_text(out_dir / filename, html)
