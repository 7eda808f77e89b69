"""The numbers behind a sweep report's answers: runs grouped into configurations (every
swept value but the seed), each configuration's mean and seed-to-seed spread, the verdict
(best configuration, ties within the spread) and whether wall times can be compared.

Pure functions of the runs table (`sweep_report.runs_dataframe`); nothing here draws.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd
import yaml

from slamlab.report.columns import METRIC_BY_KEY
from slamlab.report.html import fmt_number
from slamlab.io.rundir import RunFile
from slamlab.report.rundir import STATUS_OK, RunDir

SEED_KEY = "seed"
# Wall time above this multiple of CPU time means the run waited for the cores.
LOAD_RATIO = 1.25


def value_text(v: Any) -> str:
    """A parameter value as shown in tables and legends ("–" when the run lacks it)."""
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "–"
    if isinstance(v, (dict, list)):
        return yaml.safe_dump(v, default_flow_style=True, width=10_000).strip()
    return fmt_number(v)


def is_number(v: Any) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)


def config_groups(df: pd.DataFrame, params: Sequence[str]) -> list[tuple[tuple, pd.DataFrame]]:
    """Rows grouped by their values of `params`, in first-seen order: [(values, rows)].
    A run without a value (e.g. from another sweep) groups under "–", never fails."""
    if not params:
        return [((), df)] if len(df) else []
    keys = df[list(params)].apply(lambda row: " ".join(value_text(v) for v in row), axis=1)
    out = []
    for key in dict.fromkeys(keys):
        g = df[keys == key]
        out.append((tuple(g.iloc[0][k] for k in params), g))
    return out


def short_value(v: Any) -> str:
    """A parameter value as a label shows it: a path by its file name (the table's cell keeps
    the whole path in its tooltip), anything else as `value_text`."""
    text = value_text(v)
    if isinstance(v, str) and "/" in text:
        return text.rstrip("/").rsplit("/", 1)[-1] or text
    return text


def config_label(params: Sequence[str], values: Sequence[Any]) -> str:
    """`particles=50 resampler=residual` (last part of dotted keys; paths by their file name)."""
    return " ".join(f"{k.split('.')[-1]}={short_value(v)}" for k, v in zip(params, values)) or "all runs"


@dataclass(frozen=True, slots=True)
class ConfigStat:
    """One configuration's value of a metric over its successful seeds. `std` is the sample
    standard deviation across seeds (NaN with fewer than two seeds: the spread is unknown)."""

    label: str
    n: int
    mean: float
    std: float


def config_stats(df: pd.DataFrame, params: Sequence[str], key: str) -> list[ConfigStat]:
    """Mean and seed spread of metric `key` per configuration, over successful runs with a value."""
    ok = df[(df["status"] == STATUS_OK) & df[key].notna()]
    out = []
    for values, g in config_groups(ok, params):
        y = g[key].to_numpy(dtype=float)
        std = float(np.std(y, ddof=1)) if y.size > 1 else math.nan
        out.append(ConfigStat(config_label(params, values), int(y.size), float(np.mean(y)), std))
    return out


@dataclass(frozen=True, slots=True)
class Standing:
    """A configuration against the best one: `diff` = mean - best mean (signed, metric units),
    `spread` the seed std used to judge it (NaN when unknown), `verdict` best | tie | worse."""

    stat: ConfigStat
    diff: float
    spread: float
    verdict: str


@dataclass(frozen=True, slots=True)
class Verdict:
    """The answer at the top of a sweep report, on one headline metric."""

    key: str
    label: str
    standings: list[Standing]  # best first, then by mean
    spread_known: bool
    summary: str


# With one seed per configuration the spread is unknown; a difference below this share of
# the best value is still called a tie (seeds of one configuration differ by far more: 8e-6 m
# between 100 and 150 particles is no ranking).
TIE_SHARE = 0.01


def _judge(best: ConfigStat, other: ConfigStat) -> tuple[float, str]:
    """(spread, verdict) of `other` against `best`: a difference within the seed-to-seed
    standard deviation (the larger of the two configurations') is a tie; with no spread known,
    a difference under TIE_SHARE of the best value is one too."""
    spreads = [s for s in (best.std, other.std) if not math.isnan(s)]
    spread = max(spreads) if spreads else math.nan
    diff = abs(other.mean - best.mean)
    if diff == 0.0:
        return spread, "tie"
    if math.isnan(spread):
        if diff <= TIE_SHARE * abs(best.mean):
            return spread, "tie"
        return spread, "worse?"  # one seed each: ranked, but nobody knows if it is noise
    return spread, "tie" if diff <= spread else "worse"


def sweep_verdict(df: pd.DataFrame, params: Sequence[str], key: str) -> Verdict | None:
    """Rank the configurations (swept values other than the seed) on `key`; None when no
    successful run has the metric."""
    spec = METRIC_BY_KEY[key]
    stats = config_stats(df, params, key)
    if not stats:
        return None
    sign = -1.0 if spec.better == "max" else 1.0
    stats.sort(key=lambda s: sign * s.mean)
    best = stats[0]
    standings = [Standing(best, 0.0, best.std, "best")]
    for s in stats[1:]:
        spread, verdict = _judge(best, s)
        standings.append(Standing(s, s.mean - best.mean, spread, verdict))
    spread_known = any(s.n > 1 for s in stats)
    return Verdict(key, spec.label, standings, spread_known, _summary(spec.label, standings, spread_known))


def _fmt_stat(s: ConfigStat) -> str:
    spread = f" ± {fmt_number(s.std, 2)}" if not math.isnan(s.std) else ""
    return f"{fmt_number(s.mean)}{spread}"


def _summary(label: str, standings: list[Standing], spread_known: bool) -> str:
    best = standings[0].stat
    if len(standings) == 1:
        seeds = f"over {best.n} seeds" if best.n > 1 else "from a single run"
        return f"One configuration ({best.label}): {label} {_fmt_stat(best)} {seeds}; nothing to compare."
    ties = [s.stat.label for s in standings[1:] if s.verdict == "tie"]
    text = f"Best {label}: {best.label} ({_fmt_stat(best)}"
    text += f", {best.n} seeds)." if best.n > 1 else ")."
    if not spread_known:
        same = (f" Within {TIE_SHARE:.0%} of it, a tie whatever the spread: {', '.join(ties)}." if ties else "")
        return text + same + (" Every configuration ran with a single seed, so the seed-to-seed spread is unknown"
                              " and the ranking may be noise: repeat with several seeds (e.g. seed=0,1,2) to tell.")
    if ties:
        text += (f" Tied with it (difference within the seed-to-seed spread): {', '.join(ties)}."
                 " These cannot be told apart with these seeds.")
    else:
        text += " It is better than every other configuration by more than the seed-to-seed spread."
    return text


@dataclass(frozen=True, slots=True)
class RuntimeCheck:
    """Can the runs' wall times be compared? `parallel`: runs whose start-to-finish spans
    overlap another run's; `ratios`: wall / CPU time per run that records both."""

    comparable: bool
    note: str
    parallel: int
    ratios: list[float]


def _span(run: RunDir) -> tuple[float, float] | None:
    """(start, end) as file times: Hydra writes .hydra/config.yaml when a job starts, the
    pipeline writes metrics.json when it ends."""
    start_file, end_file = run.path / RunFile.HYDRA_CONFIG, run.path / RunFile.METRICS
    if not (start_file.is_file() and end_file.is_file()):
        return None
    return os.stat(start_file).st_mtime, os.stat(end_file).st_mtime


def overlapping_runs(runs: Sequence[RunDir]) -> int:
    """How many runs were running while another one was (the same machine's file times)."""
    spans = [s for r in runs if r.ok and (s := _span(r)) is not None]
    spans.sort()
    overlap = [False] * len(spans)
    for i, (s0, e0) in enumerate(spans):
        for j in range(i + 1, len(spans)):
            if spans[j][0] >= e0:
                break
            overlap[i] = overlap[j] = True
    return sum(overlap)


def runtime_check(df: pd.DataFrame, runs: Sequence[RunDir]) -> RuntimeCheck | None:
    """Say whether wall times compare, from CPU time (metrics `cpu_time_s`) and overlapping runs."""
    ok = df[df["status"] == STATUS_OK]
    if ok.empty or ok["runtime_s"].isna().all():
        return None
    both = ok[ok["runtime_s"].notna() & ok["cpu_time_s"].notna() & (ok["cpu_time_s"] > 0)]
    ratios = [float(r) for r in (both["runtime_s"] / both["cpu_time_s"])]
    parallel = overlapping_runs([r for r in runs if r.ok])
    loaded = [r for r in ratios if r > LOAD_RATIO]
    parts = []
    if parallel:
        parts.append(f"{parallel} of {len(ok)} runs ran at the same time as another run (their start and"
                     " finish times overlap), so they shared the cores.")
    if loaded:
        parts.append(f"In {len(loaded)} of {len(ratios)} runs the filter's wall time was"
                     f" {fmt_number(min(loaded), 2)}–{fmt_number(max(loaded), 2)}× its CPU time: the run"
                     " waited for the cores (parallel jobs or other load on the machine).")
    if not ratios:
        parts.append("These runs do not record CPU time (metrics.json `cpu_time_s`, written by newer slamlab),"
                     " so it cannot be checked whether they ran under load.")
        return RuntimeCheck(not parallel, " ".join(parts), parallel, ratios)
    if parallel or loaded:
        parts.append("Wall times are therefore not comparable between runs: compare CPU time.")
        return RuntimeCheck(False, " ".join(parts), parallel, ratios)
    return RuntimeCheck(True, "Every run's wall time is within"
                        f" {fmt_number(LOAD_RATIO, 3)}× its CPU time and no runs overlapped: wall times compare.",
                        parallel, ratios)


def memory_note(runs: Sequence[RunDir], labels: Sequence[str]) -> str:
    """What the table's peak memory column measures, from each run's `peak_memory_scope`:
    every run's own peak, or which runs' peaks sit on what earlier runs in their process
    left allocated (a launcher's reused workers), or the process's lifetime peak."""
    scopes = {label: r.metrics.get("peak_memory_scope") for r, label in zip(runs, labels) if r.ok and "peak_memory_mb" in r.metrics}
    if not scopes:
        return ""
    own = [k for k, v in scopes.items() if v == "run"]
    if len(own) == len(scopes):
        return ("Peak memory: each run's own peak resident memory (a sweep runs every job in a fresh child process, so a"
                " job's place in the sweep does not change it).")
    reused = [k for k, v in scopes.items() if v not in ("run", "process", None)]
    lifetime = [k for k, v in scopes.items() if v == "process"]
    unknown = [k for k, v in scopes.items() if v is None]
    parts = ["Peak memory:"]
    if own:
        parts.append(f"{len(own)} of {len(scopes)} runs show their own peak.")
    if reused:
        parts.append(f"Run{'s' if len(reused) > 1 else ''} {', '.join(reused)} ran in a process that had run others"
                     " before (a launcher's reused worker): their peak includes what those left allocated.")
    if lifetime:
        parts.append(f"Run{'s' if len(lifetime) > 1 else ''} {', '.join(lifetime)}: the process's lifetime peak (no per-run"
                     " measure on this system).")
    if unknown:
        parts.append(f"Run{'s' if len(unknown) > 1 else ''} {', '.join(unknown)} do not say (older slamlab).")
    return " ".join(parts)
