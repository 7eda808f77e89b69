"""The fixed cost of a `slamlab` process: a one-scan run, end to end (issue 10).

    .venv/bin/python benchmarks/bench_process.py [--repeat 3] [--only intel,intel_nocache,sim]

Each case is a whole `python -m slamlab.cli.app ... steps.max_scans=1` process, run
`--repeat` times; the table gives the median CPU (user + sys of the process, s), wall (s)
and peak resident memory (MB, the kernel's `ru_maxrss` of the child) against the budget of
1.5 s CPU. Cases: `intel` (`+experiment=lidar2d` on intel.clf.bz2, the parsed-log cache
warm), `intel_nocache` (the same with an empty SLAMLAB_CACHE_DIR every time: the log is
parsed from the .bz2), `sim` (the default simulated run with texture; sequence cached).
`intel_full` (not run by default: about 50 s CPU a run) is the whole Intel log, for its
peak memory.

A second table splits one more run of each case into phases, in CPU s, measured inside the
process by timing the pipeline's own functions (this script re-runs itself with `--probe`):
import (`import slamlab.cli.app`), config (override check + Hydra composing the config),
setup (the engine's imports, numba's included, and building the components), log read
(`load_sequence`), numba (loading compiled kernels from numba's cache, or compiling
them when it is cold), slam (the filter without numba loading), map.png etc. (`write_map`),
texture, other artifacts (metrics, consistency, TUM/CSV/npz files), report (`report.html`),
rest (interpreter start-up, Hydra's own set-up, and shutdown: total minus the phases). A
third table gives the peak resident memory so far (MB, VmHWM) when each phase ended (for
other artifacts: when the run ended), to see which phase raised the peak.
Numba kernels come from the on-disk cache after the first run of a checkout; run once
before measuring.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

BUDGET_CPU_S = 1.5
PHASES = ("import", "config", "setup", "log read", "numba", "slam", "map.png etc.", "texture", "other artifacts", "report")


def case_args(name: str, data: Path | None) -> list[str] | None:
    """The slamlab arguments of a case (None when its data is missing)."""
    if name.startswith("intel"):
        if data is None or not (data / "carmen" / "intel.clf.bz2").is_file():
            return None
        whole = ["+experiment=lidar2d", f"dataset.path={data / 'carmen' / 'intel.clf.bz2'}"]
        return whole if name == "intel_full" else [*whole, "steps.max_scans=1"]
    if name == "sim":
        return ["steps.max_scans=1"]
    raise SystemExit(f"unknown case {name!r}")


def run_once(args: list[str], run_dir: Path, env: dict[str, str], probe: Path | None = None) -> dict:
    """One process: CPU (user + sys, s), wall (s) and peak RSS (MB) from the kernel."""
    head = [sys.executable, __file__, "--probe", str(probe), "--"] if probe else [sys.executable, "-m", "slamlab.cli.app"]
    cmd = [*head, *args, f"hydra.run.dir={run_dir}", "progress=off"]
    t0 = time.perf_counter()
    # cwd: the run folder's parent, not a checkout: `python -m` puts the cwd first on
    # sys.path, which would import the checkout there whatever PYTHONPATH says
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env, cwd=run_dir.parent)
    err = proc.stderr.read() if proc.stderr else b""
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({proc.returncode}):\n{err.decode(errors='replace')[-2000:]}")
    return {"cpu_s": usage.ru_utime + usage.ru_stime, "wall_s": wall, "peak_mb": usage.ru_maxrss / 1024.0}


def measure(names: list[str], repeat: int, tmp: Path) -> tuple[list[dict], list[dict], list[dict]]:
    from slamlab.paths import CACHE_DIR_ENV, data_dir

    data = data_dir()
    rows: list[dict] = []
    phases: list[dict] = []
    memory: list[dict] = []
    for name in names:
        args = case_args(name, data)
        if args is None:
            print(f"{name}: skipped (no shared data; set SLAMLAB_DATA_DIR)", file=sys.stderr)
            continue
        env = dict(os.environ)

        def fresh_env(k: int) -> dict[str, str]:
            if name != "intel_nocache":
                return env
            return {**env, CACHE_DIR_ENV: str(tmp / f"cache-{name}-{k}")}

        run_once(args, tmp / f"{name}-warmup", fresh_env(-1))  # fills caches (numba, sim sequence, log)
        runs = [run_once(args, tmp / f"{name}-{k}", fresh_env(k)) for k in range(repeat)]
        row = {"case": name}
        for key in ("cpu_s", "wall_s", "peak_mb"):
            row[key] = statistics.median(r[key] for r in runs)
        row["budget_cpu_s"] = BUDGET_CPU_S
        row["within"] = "yes" if row["cpu_s"] <= BUDGET_CPU_S else "no"
        rows.append(row)
        out = tmp / f"{name}-probe.json"
        total = run_once(args, tmp / f"{name}-probe", fresh_env(repeat), probe=out)
        probed = json.loads(out.read_text())
        split = {"case": name, **{p: probed["cpu"].get(p, 0.0) for p in PHASES}}
        split["rest"] = total["cpu_s"] - sum(split[p] for p in PHASES)
        split["total"] = total["cpu_s"]
        phases.append(split)
        memory.append({"case": name, **{p: probed["rss"].get(p, float("nan")) for p in PHASES}, "peak": total["peak_mb"]})
    return rows, phases, memory


# ----------------------------------------------------------------------------- the probe


def probe(out: Path, argv: list[str]) -> None:
    """Run `slamlab argv` in this process with timers around the pipeline's phases (CPU s)."""
    spent: dict[str, float] = {}
    rss: dict[str, float] = {}  # peak resident MB so far when each phase last ended
    inner: list[float] = []  # CPU of nested timed calls, subtracted from their callers

    def timed(phase: str, fn):
        def wrapper(*a, **k):
            c0 = time.process_time()
            inner.append(0.0)
            try:
                return fn(*a, **k)
            finally:
                nested = inner.pop()
                dt = time.process_time() - c0
                spent[phase] = spent.get(phase, 0.0) + dt - nested
                rss[phase] = _rss_mb()
                if inner:
                    inner[-1] += dt

        return wrapper

    c0 = time.process_time()
    import slamlab.cli.app as app

    spent["import"] = time.process_time() - c0
    rss["import"] = _rss_mb()
    import slamlab.pipeline as pipeline

    original_load_sequence = pipeline.load_sequence
    started: list[float] = []

    def load_sequence(*a, **k):
        # run_pipeline has imported the engine and built the components by now
        spent["setup"] = time.process_time() - started[0]
        rss["setup"] = _rss_mb()
        return timed("log read", original_load_sequence)(*a, **k)

    def run_pipeline(*a, **k):
        started.append(time.process_time())
        spent["config"] = started[0] - c0 - spent["import"]
        rss["config"] = _rss_mb()
        import numba.core.dispatcher as dispatcher  # the engine's imports: counted in setup

        import slamlab.slam.engine as engine

        # kernels load (or compile) on their first call with each signature
        dispatcher.Dispatcher._compile_for_args = timed("numba", dispatcher.Dispatcher._compile_for_args)
        engine.run_slam = timed("slam", engine.run_slam)
        pipeline.load_sequence = load_sequence
        pipeline.artifacts.write_map = timed("map.png etc.", pipeline.artifacts.write_map)
        pipeline.run_texture_stage = timed("texture", pipeline.run_texture_stage)
        if hasattr(pipeline, "_write_report"):  # older layout: the pipeline wrote the report
            pipeline._write_report = timed("report", pipeline._write_report)
        return pipeline.run_pipeline(*a, **k)

    def run_pipeline_timed(*a, **k):
        try:
            return timed("other artifacts", run_pipeline)(*a, **k)
        finally:
            spent["other artifacts"] -= spent.get("setup", 0.0)

    app.run_pipeline = run_pipeline_timed
    if hasattr(app, "run_and_report"):  # the CLI writes the report after run_pipeline
        app.run_and_report = timed("report", app.run_and_report)
    sys.argv = ["slamlab", *argv]
    try:
        app.main()
    finally:
        out.write_text(json.dumps({"cpu": spent, "rss": rss}))


def _rss_mb() -> float:
    """This process's peak resident memory so far (MB; Linux's VmHWM, which the run resets
    when it starts: see slamlab.memory)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3, help="runs per case; medians are reported")
    ap.add_argument("--only", default="intel,intel_nocache,sim", help="comma-separated cases")
    ap.add_argument("--probe", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("rest", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.probe:
        probe(a.probe, [x for x in a.rest if x != "--"])
        return
    import pandas as pd

    with tempfile.TemporaryDirectory(prefix="slamlab-bench-process-") as tmp:
        rows, phases, memory = measure(a.only.split(","), a.repeat, Path(tmp))
    pd.set_option("display.width", 200)
    print(f"One-scan runs, median of {a.repeat} (CPU = user + sys of the process):")
    print(pd.DataFrame(rows).to_string(index=False, float_format="{:.2f}".format))
    print("\nWhere the CPU goes (s, one run each):")
    print(pd.DataFrame(phases).to_string(index=False, float_format="{:.2f}".format))
    print("\nPeak resident memory so far when each phase ended, and the process's peak (MB, same run):")
    print(pd.DataFrame(memory).to_string(index=False, float_format="{:.0f}".format))


if __name__ == "__main__":
    main()
