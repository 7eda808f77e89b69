"""Memory work must not change a result (issue 44): the whole Intel `lidar2d` run and the
default simulated run (`make run`'s, texture included) give, file by file, the results of
main e5c8188, before the memory work.

Each result file of the run folder (`run_compare.result_files`: everything but the records,
i.e. manifest, logs, report, .hydra/) is reduced to a sha256 of what `slamlab-verify`
compares: arrays of an .npz (names, dtypes, shapes, bytes; the zip's own bytes carry dates),
metrics.json and steps.csv without the timing and memory figures (`run_compare.VOLATILE`),
every other file's bytes; the map-consistency files and section, which issue 45 replaced on
purpose, are left out. `RESULTS_BEFORE` holds those digests as e5c8188 wrote them, made by
this file's `main` with that commit's code first on the path:

    git worktree add /tmp/old e5c8188   # or: git archive e5c8188 | tar -x -C /tmp/old
    cd /tmp && SLAMLAB_DATA_DIR=... PYTHONPATH=/tmp/old python /path/to/tests/test_results_unchanged.py OUT.json

(the working folder must not be a checkout: `python` puts it first on the path).

metrics.json is compared by value, not by digest (`METRICS_BEFORE`, `metrics_difference`):
its statistics are sums and angles over thousands of relations, and numpy picks its vector
kernels by the CPU (`numpy.show_runtime()`: X86_V3 found, X86_V4 / AVX-512 not, on the machine
below), which may differ in the last bits. On an AMD EPYC (2026-11-30) every other file was still
e5c8188's bit for bit while metrics.json's digest differed; its values there (kept in
`METRICS_BEFORE`, made by `main` from runs whose every other file matches e5c8188) agree
with e5c8188's to far better than `METRICS_RTOL`, and a changed run moves them by more.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

RESULTS_BEFORE = Path(__file__).with_name("results_e5c8188.json")
METRICS_BEFORE = Path(__file__).with_name("results_e5c8188_metrics.json")
METRICS_RTOL = 1e-9  # a float in metrics.json may differ by this share (summation order), no more


def runs(data: Path | None) -> dict[str, list[str]]:
    """The runs compared, as `slamlab` arguments (no report: it is a record, not a result)."""
    out = {"sim": ["report=false"]}
    if data is not None:
        # the RBPF, as `lidar2d` ran it at e5c8188 (the preset's filter is `graph` since 2026-11-29)
        out["intel"] = ["+experiment=lidar2d", "filter=rbpf", f"dataset.path={data / 'carmen' / 'intel.clf.bz2'}", "report=false"]
    return out


def _without_volatile(d: object, volatile) -> object:
    if isinstance(d, dict):
        return {k: _without_volatile(v, volatile) for k, v in d.items() if not volatile.search(str(k))}
    return d


# What issue 45 changed on purpose (the map-consistency verdict replaced the old score): its
# files and its metrics section are not SLAM results and are left out of the comparison.
CONSISTENCY_FILES = frozenset({"consistency.csv", "consistency_map.npz"})
CONSISTENCY_KEY = "consistency"


def file_digest(path: Path) -> str:
    """sha256 of what a re-run must reproduce of one result file (module doc)."""
    from slamlab.io.rundir import RunFile
    from slamlab.run_compare import VOLATILE

    h = hashlib.sha256()
    if path.suffix == ".npz":
        with np.load(path) as z:
            for key in sorted(z.files):
                a = z[key]
                h.update(f"{key} {a.dtype.str} {a.shape}\n".encode())
                h.update(np.ascontiguousarray(a).tobytes())
    elif path.name == RunFile.METRICS:
        h.update(json.dumps(kept_metrics(path), sort_keys=True).encode())
    elif path.name == RunFile.STEPS_CSV:
        rows = list(csv.reader(io.StringIO(path.read_text())))
        keep = [i for i, name in enumerate(rows[0]) if not VOLATILE.search(name)]
        for row in rows:
            h.update((",".join(row[i] for i in keep) + "\n").encode())
    else:
        h.update(path.read_bytes())
    return h.hexdigest()


def kept_metrics(path: Path) -> dict:
    """metrics.json without its timing and memory figures and its consistency section."""
    from slamlab.run_compare import VOLATILE

    kept = _without_volatile(json.loads(path.read_text()), VOLATILE)
    assert isinstance(kept, dict)
    kept.pop(CONSISTENCY_KEY, None)
    return kept


def metrics_difference(before: object, now: object, key: str = "metrics.json") -> str | None:
    """The first value that differs between two kept metrics: floats by more than
    METRICS_RTOL of their size, anything else at all; None when they agree."""
    if isinstance(before, dict) and isinstance(now, dict):
        if set(before) != set(now):
            return f"{key}: keys {sorted(set(before) ^ set(now))} in one only"
        for k in sorted(before):
            d = metrics_difference(before[k], now[k], f"{key} {k}")
            if d is not None:
                return d
        return None
    if isinstance(before, float) and isinstance(now, float):
        return None if math.isclose(before, now, rel_tol=METRICS_RTOL, abs_tol=1e-12) else f"{key}: {before!r} before, {now!r} now"
    return None if before == now and type(before) is type(now) else f"{key}: {before!r} before, {now!r} now"


def run_digests(run_dir: Path) -> dict[str, str]:
    from slamlab.run_compare import result_files

    return {name: file_digest(run_dir / name) for name in sorted(result_files(run_dir)) if name not in CONSISTENCY_FILES}


def run_slamlab(args: list[str], run_dir: Path, cache: Path | None) -> None:
    env = {**os.environ, "MPLBACKEND": "Agg"}
    if cache is not None:
        env["SLAMLAB_CACHE_DIR"] = str(cache)
    proc = subprocess.run([sys.executable, "-m", "slamlab.cli.app", *args, f"hydra.run.dir={run_dir}", "progress=off"],
                          cwd=run_dir.parent, env=env, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]


def first_difference(before: dict[str, str], now: dict[str, str]) -> str | None:
    for name in sorted(set(before) | set(now)):
        if name not in now:
            return f"{name}: written before, missing now"
        if name not in before:
            return f"{name}: new (not written before)"
        if before[name] != now[name]:
            return f"{name}: differs"
    return None


@pytest.mark.slow
@pytest.mark.parametrize("name", ["sim", "intel"])
def test_results_are_those_of_before_the_memory_work(name, tmp_path, sim_cache, request):
    data = request.getfixturevalue("shared_data") if name == "intel" else None
    before = json.loads(RESULTS_BEFORE.read_text())[name]
    run_dir = tmp_path / name
    run_slamlab(runs(data)[name], run_dir, sim_cache)
    now = run_digests(run_dir)
    assert len(now) >= 10, f"only {sorted(now)} written"
    # metrics.json by value (module doc), every other file by its digest
    from slamlab.io.rundir import RunFile

    metrics = RunFile.METRICS
    assert metrics in now
    before.pop(metrics), now.pop(metrics)
    assert first_difference(before, now) is None, first_difference(before, now)
    diff = metrics_difference(json.loads(METRICS_BEFORE.read_text())[name], kept_metrics(run_dir / metrics))
    assert diff is None, diff


def test_a_changed_result_is_caught(tmp_path):
    """The comparison sees a one-value change in an array, in a kept metric and in a step
    column, and ignores timing and memory figures."""
    from slamlab.io.rundir import RunFile

    np.savez(tmp_path / "a.npz", data=np.arange(6, dtype=np.float32))
    (tmp_path / RunFile.METRICS).write_text(json.dumps({"scans": 3, "runtime_s": 1.0, "peak_memory_mb": 200.0}))
    (tmp_path / RunFile.STEPS_CSV).write_text("step,neff,step_time_s\n0,30,0.01\n")
    before = {p.name: file_digest(p) for p in tmp_path.iterdir()}

    (tmp_path / RunFile.METRICS).write_text(json.dumps({"scans": 3, "runtime_s": 2.5, "peak_memory_mb": 150.0}))
    (tmp_path / RunFile.STEPS_CSV).write_text("step,neff,step_time_s\n0,30,0.02\n")
    assert {p.name: file_digest(p) for p in tmp_path.iterdir()} == before  # time and memory only

    np.savez(tmp_path / "a.npz", data=np.array([0, 1, 2, 3, 4, 5.0000005], dtype=np.float32))
    (tmp_path / RunFile.METRICS).write_text(json.dumps({"scans": 4, "runtime_s": 2.5, "peak_memory_mb": 150.0}))
    (tmp_path / RunFile.STEPS_CSV).write_text("step,neff,step_time_s\n0,29,0.02\n")
    now = {p.name: file_digest(p) for p in tmp_path.iterdir()}
    assert all(now[k] != before[k] for k in before)
    assert first_difference(before, now) == "a.npz: differs"


def test_metrics_are_compared_to_a_billionth_of_each_value():
    """By value: the last bits of a sum pass, a change in the ninth digit does not, nor a
    changed count, a missing key or an int turned float; timing and memory never count."""
    before = {"scans": 3, "relations": {"trans_abs_mean_m": 0.0197593076283280, "count": 2984}, "status": "ok"}
    same = {"scans": 3, "relations": {"trans_abs_mean_m": 0.0197593076283280 * (1 + 4e-16), "count": 2984}, "status": "ok"}
    assert metrics_difference(before, same) is None
    moved = {"scans": 3, "relations": {"trans_abs_mean_m": 0.0197593076283280 * (1 + 1e-8), "count": 2984}, "status": "ok"}
    assert metrics_difference(before, moved).startswith("metrics.json relations trans_abs_mean_m:")
    assert metrics_difference(before, {**before, "scans": 4}) == "metrics.json scans: 3 before, 4 now"
    assert metrics_difference(before, {**before, "scans": 3.0}) is not None
    assert "keys ['status']" in metrics_difference(before, {k: v for k, v in before.items() if k != "status"})


def test_kept_metrics_leave_out_timing_memory_and_the_consistency_section(tmp_path):
    path = tmp_path / "metrics.json"
    path.write_text(json.dumps({"scans": 3, "runtime_s": 1.0, "peak_memory_mb": 2.0, "consistency": {"hit_fraction_p10": 0.5}, "graph": {"total_runtime_s": 1.0, "nodes": 5}}))
    assert kept_metrics(path) == {"scans": 3, "graph": {"nodes": 5}}


def main() -> None:
    """Write the digests of both runs made with the slamlab on the path to `argv[1]`, and
    their kept metrics beside it (`argv[1]`'s stem + `_metrics.json`)."""
    import tempfile

    from slamlab.paths import data_dir

    out = Path(sys.argv[1])
    result, metrics = {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, args in runs(data_dir()).items():
            run_dir = Path(tmp) / name
            run_slamlab(args, run_dir, Path(tmp) / "cache")
            result[name] = run_digests(run_dir)
            metrics[name] = kept_metrics(run_dir / "metrics.json")
    out.write_text(json.dumps(result, indent=1, sort_keys=True) + "\n")
    out.with_name(out.stem + "_metrics.json").write_text(json.dumps(metrics, indent=1, sort_keys=True) + "\n")


if __name__ == "__main__":
    main()
