"""Whole-process peak memory of slamlab's runs against their budgets, and where it goes (issue 44).

    .venv/bin/python benchmarks/bench_memory.py [--only one_scan,intel,sim,sim_loops,hospital] [--holders N]
                                                [--no-probe] [--set KEY=VALUE] [--out DIR]

Rows: `ROWS` below, one line each (a name, the `slamlab` arguments, the budget in MB), so a
row's preset can be changed or a row added (e.g. one with `filter=graph`) in one place;
`--set` adds an override to every row. `make_test` (not run by default: ~6 min) is the test
suite, `pytest` as `make test` runs it, for its largest process.

Per row:
1. `peak MB`: the kernel's peak resident set size of the whole `slamlab` process (`ru_maxrss`
   from `wait4`, what `/usr/bin/time -f %M` prints), from a plain run. This is what the budget
   is about. It counts what the process touched of its shared libraries' files as well as
   its own (anonymous) memory, so the table also gives both parts at the peak phase.
   `import floor` is a fresh process that only imports every module the run had imported
   by its end (no data, no kernel loaded): the part of the peak that is code, with the
   resident pages of libllvmlite.so (numba's LLVM, loaded by `import numba`) apart, and
   what stays resident once LLVM's pages are given back, as the CLI does between kernel
   loads (`slamlab.code_pages`).
2. Per phase (import, config, setup, read, filter, metrics, files, texture, report), from a
   second, probed run: the peak resident size reached during that phase (Linux's high-water
   mark VmHWM, reset when each phase starts through /proc/self/clear_refs: exact, however
   short the peak) and the resident file-backed / anonymous parts when it ended. The probe
   runs the map's files (`write_map`, a background thread in a normal run) inline, so they
   have a phase of their own; the probed run's peak can therefore differ by a few MB from
   the plain run's.
3. The top holders by phase (`--holders N`, 0 = off), from a third run under memray
   (https://bloomberg.github.io/memray/): for each phase, the allocations made in it that
   were live at its heap peak, grouped by the innermost slamlab line that asked for them
   (and the library that made them), and what it handed on (made in it, alive at its end).

Why these tools: peak RSS is the budget's own unit, and the high-water mark gives a phase's
true peak where sampling would miss a short spike. For *who* holds it, memray because it sees
every allocation, whichever allocator made it: numba's NRT arrays (a kernel's output),
Agg's and Pillow's image buffers, LLVM, as well as Python objects and NumPy arrays; stdlib
`tracemalloc` sees only the last two (Python's allocator and NumPy's traced buffers), and only
as a current snapshot, so a phase's transient peak (a figure rendered and freed) is lost.
memray reports bytes allocated, touched or not: OpenBLAS's 32 MB work buffer, mapped at the
first matrix product (`scan.py`'s or the Kinect calibration's) and hardly touched, shows as a
32 MB holder, and so does an `np.empty` sized for the worst case. Neither tool sees a shared
library's code pages: those are the RSS columns' file-backed MB. Nor does memray follow the
RBPF's tile pools (memory maps grown in place by `mremap`): `maps MB at peak` is the run's own
count of them (metrics.json `map_memory.map_peak_mb`: tiles held at once x 2 kB). memray is in the
`dev` extra; without it the holders table is skipped.

Run each row once before measuring (numba compiles kernels on a checkout's first run, and
LLVM's compile-time memory would count).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

PHASES = ("import", "config", "setup", "read", "filter", "metrics", "files", "texture", "report")


def _data(*parts: str) -> str:
    from slamlab.paths import data_dir

    d = data_dir()
    if d is None:
        raise SystemExit("shared data not found: set SLAMLAB_DATA_DIR")
    return str(d.joinpath(*parts))


def _log(name: str) -> str:
    return f"dataset.path={_data('carmen', name)}"


# name: (the `slamlab` arguments, budget MB). Arguments are built when the row runs.
ROWS: dict[str, tuple[Callable[[], list[str]], float]] = {
    "one_scan": (lambda: ["+experiment=lidar2d", _log("intel.clf.bz2"), "steps.max_scans=1"], 160.0),  # with report
    "intel": (lambda: ["+experiment=lidar2d", _log("intel.clf.bz2")], 200.0),  # with report
    "sim": (lambda: [], 300.0),  # `make run`: the default sim run, texture and report
    "sim_loops": (lambda: ["+experiment=sim_loops", "texture=none", "report=false"], 500.0),  # world_scale 1.5
    "hospital": (lambda: ["+experiment=lidar2d", _log("fr-clinic_robotlaser.clf.bz2")], 400.0),  # with report
    # the loop-closure issue's (43) row: the graph on the 2x building, texture and report as the preset makes them
    "sim_loops_graph_2x": (lambda: ["+experiment=sim_loops", "filter=graph", "dataset.world_scale=2.0"], 600.0),
}
# not a slamlab run: the test suite as `make test` runs it (its largest process)
MAKE_TEST_BUDGET_MB: float | None = None


# ----------------------------------------------------------------------------- measuring


def _run(cmd: list[str], cwd: Path, env: dict[str, str]) -> float:
    """Run `cmd` to its end; its peak resident size (MB, the kernel's ru_maxrss)."""
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env, cwd=cwd)
    err = proc.stderr.read() if proc.stderr else b""
    _, status, usage = os.wait4(proc.pid, 0)
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{err.decode(errors='replace')[-3000:]}")
    return usage.ru_maxrss / 1024.0


def slamlab_cmd(args: list[str], run_dir: Path, probe: list[str] | None = None) -> list[str]:
    head = [sys.executable, __file__, *probe, "--"] if probe else [sys.executable, "-m", "slamlab.cli.app"]
    return [*head, *args, f"hydra.run.dir={run_dir}", "progress=off"]


def measure_row(name: str, args: list[str], tmp: Path, holders: int, probe: bool) -> dict:
    env = dict(os.environ)
    # cwd: not a checkout (`python -m` puts the cwd first on sys.path)
    row: dict = {"peak_mb": _run(slamlab_cmd(args, tmp / f"{name}-plain"), tmp, env)}
    metrics = json.loads((tmp / f"{name}-plain" / "metrics.json").read_text())
    row["maps_peak_mb"] = metrics.get("map_memory", {}).get("map_peak_mb", float("nan"))
    if probe:
        out = tmp / f"{name}-rss.json"
        _run(slamlab_cmd(args, tmp / f"{name}-rss", ["--probe", str(out)]), tmp, env)
        row["phases"] = json.loads(out.read_text())
        row["floor"] = import_floor(row["phases"]["modules"], tmp / f"{name}-floor.json", env)
    if holders:
        out = tmp / f"{name}-holders.json"
        _run(slamlab_cmd(args, tmp / f"{name}-holders", ["--probe", str(out), "--memray", str(tmp / f"{name}-memray"),
                                                          "--holders", str(holders)]), tmp, env)
        row["holders"] = json.loads(out.read_text())["holders"]
    return row


FLOOR_SCRIPT = """
import importlib, json, re, sys, warnings
warnings.simplefilter("ignore")
out = sys.argv[1]
for name in json.load(open(out)):
    try:
        importlib.import_module(name)
    except BaseException:
        pass
def status():
    text = open("/proc/self/status").read()
    return {k: int(re.search(rf"^{k}:\\s+(\\d+)", text, re.M).group(1)) / 1024 for k in ("VmHWM", "VmRSS", "RssAnon", "RssFile")}
def llvm():
    mb, current = 0, ""
    for line in open("/proc/self/smaps"):
        if re.match(r"^[0-9a-f]+-[0-9a-f]+ ", line):
            current = line
        elif line.startswith("Rss:") and "libllvmlite" in current:
            mb += int(line.split()[1]) / 1024
    return mb
mb = {**status(), "llvmlite": llvm()}
from slamlab.code_pages import give_back_llvm_pages_after_loads
give_back_llvm_pages_after_loads()  # as the CLI does before a run's first kernel loads
mb["after"] = status()
json.dump(mb, open(out, "w"))
"""


def import_floor(modules: list[str], path: Path, env: dict[str, str]) -> dict:
    """The floor of a run: a fresh process that imports every module the run had imported by
    its end (its code, NumPy's, numba's and LLVM's, matplotlib's, ...) and does nothing else:
    its peak (MB), resident file-backed and anonymous parts, and libllvmlite's share; under
    "after", the same once LLVM's pages are given back (`code_pages`)."""
    path.write_text(json.dumps(modules))
    _run([sys.executable, "-c", FLOOR_SCRIPT, str(path)], path.parent, env)
    return json.loads(path.read_text())


def measure_make_test(tmp: Path) -> dict:
    """`make test`'s pytest (the layer check aside): its largest process (ru_maxrss of the tree)."""
    repo = Path(__file__).resolve().parent.parent
    t0 = time.perf_counter()
    peak = _run([sys.executable, "-m", "pytest", "-q", "-x", "-p", "no:cacheprovider"], repo, dict(os.environ))
    return {"peak_mb": peak, "wall_s": time.perf_counter() - t0}


# ----------------------------------------------------------------------------- the probe


def _status() -> dict[str, float]:
    """VmHWM, VmRSS, RssAnon, RssFile of this process (MB)."""
    out = {}
    for line in Path("/proc/self/status").read_text().splitlines():
        key = line.split(":", 1)[0]
        if key in ("VmHWM", "VmRSS", "RssAnon", "RssFile"):
            out[key] = int(line.split()[1]) / 1024.0
    return out


class PhaseProbe:
    """Labels the process's time with phases; each phase's peak RSS is the high-water mark
    reached while it was current (reset at every change), and with `memray_dir` each stretch
    of a phase is recorded by its own memray tracker."""

    def __init__(self, memray_dir: Path | None) -> None:
        self.stack: list[str] = []
        self.peak: dict[str, float] = {}
        self.end: dict[str, dict[str, float]] = {}
        self.process_peak = 0.0
        self.memray_dir = memray_dir
        self.captures: list[tuple[str, Path]] = []
        self._tracker = None
        self._clear = Path("/proc/self/clear_refs")

    def fold(self) -> None:
        """Credit the high-water mark since the last change to the current phase, then reset it."""
        s = _status()
        if self.stack:
            ph = self.stack[-1]
            self.peak[ph] = max(self.peak.get(ph, 0.0), s["VmHWM"])
            self.end[ph] = {"rss": s["VmRSS"], "anon": s["RssAnon"], "file": s["RssFile"]}
        self.process_peak = max(self.process_peak, s["VmHWM"])
        self._clear.write_text("5")

    def _switch(self, new_stack: list[str]) -> None:
        self._stop_tracker()
        self.fold()
        self.stack = new_stack
        self._start_tracker()

    def enter(self, phase: str) -> None:
        self._switch([*self.stack, phase])

    def leave(self) -> None:
        self._switch(self.stack[:-1])

    def set(self, phase: str) -> None:
        """Replace the current phase (a sequence of phases at one level)."""
        self._switch([*self.stack[:-1], phase])

    def wrap(self, phase: str, fn: Callable) -> Callable:
        def wrapper(*a, **k):
            self.enter(phase)
            try:
                return fn(*a, **k)
            finally:
                self.leave()

        return wrapper

    def _start_tracker(self) -> None:
        if self.memray_dir is None or not self.stack:
            return
        import memray

        path = self.memray_dir / f"{len(self.captures):03d}-{self.stack[-1]}.bin"
        self.captures.append((self.stack[-1], path))
        self._tracker = memray.Tracker(path, trace_python_allocators=False)
        self._tracker.__enter__()

    def _stop_tracker(self) -> None:
        if self._tracker is not None:
            self._tracker.__exit__(None, None, None)
            self._tracker = None


def probe(out: Path, memray_dir: Path | None, holders: int, argv: list[str]) -> None:
    """Run `slamlab argv` in this process, phase by phase (see the module doc)."""
    if memray_dir is not None:
        memray_dir.mkdir(parents=True, exist_ok=True)
    p = PhaseProbe(memray_dir)
    p.enter("import")
    import slamlab.cli.app as app
    import slamlab.memory as run_memory
    import slamlab.pipeline as pipeline

    class _Clear:
        """slamlab.memory resets the high-water mark when a run starts: fold it first."""

        def write_text(self, text: str) -> None:
            p.fold()

    run_memory.CLEAR_REFS = _Clear()  # type: ignore[assignment]

    class _Inline:
        """The pipeline's background executor, run inline: the map's files get their own phase."""

        def __init__(self, *a, **k) -> None:
            pass

        def submit(self, fn, *a, **k):
            from concurrent.futures import Future

            f: Future = Future()
            try:
                f.set_result(fn(*a, **k))
            except BaseException as exc:  # noqa: BLE001 (handed on as the pool would)
                f.set_exception(exc)
            return f

        def shutdown(self, *a, **k) -> None:
            pass

    original_run_pipeline = pipeline.run_pipeline

    def run_pipeline(*a, **k):
        p.set("setup")  # the engine's imports (numba) and the components
        import slamlab.eval.consistency as consistency
        import slamlab.slam.engine as engine

        engine.run_slam = p.wrap("filter", engine.run_slam)
        consistency.consistency_metrics = p.wrap("metrics", consistency.consistency_metrics)
        for fname in ("filter_metrics", "accuracy_metrics", "relation_table"):
            setattr(pipeline, fname, p.wrap("metrics", getattr(pipeline, fname)))
        pipeline.run_texture_stage = p.wrap("texture", pipeline.run_texture_stage)
        pipeline.ThreadPoolExecutor = _Inline  # type: ignore[misc]
        original_load = pipeline.load_sequence

        def load_sequence(*la, **lk):
            p.set("read")
            try:
                return original_load(*la, **lk)
            finally:
                p.set("files")  # the rest of the run, between the phases wrapped above

        pipeline.load_sequence = load_sequence
        try:
            return original_run_pipeline(*a, **k)
        finally:
            p.set("report")

    app.run_pipeline = run_pipeline
    p.set("config")
    sys.argv = ["slamlab", *argv]
    try:
        app.main()
    finally:
        p.set("exit")
        p.leave()
        skip = ("__main__", "bench_memory")
        result = {"peak": p.peak, "end": p.end, "process_peak": p.process_peak,
                  "modules": sorted(m for m in sys.modules if m not in skip and not m.startswith("memray"))}
        if memray_dir is not None:
            result["holders"] = holders_of(p.captures, holders)
        out.write_text(json.dumps(result))


def _where(stack: list[tuple[str, str, int]]) -> str:
    """An allocation's place: its innermost slamlab line (and the library below it, if any)."""
    ours = next((f for f in stack if "/slamlab/" in f[1]), None)
    lib = stack[0] if stack else ("?", "?", 0)
    lib_name = lib[1].split("site-packages/")[-1].split("/")[0] if "site-packages/" in lib[1] else Path(lib[1]).name
    if ours is None:
        return f"({lib[0]} in {lib_name})"
    place = f"{ours[1].split('/slamlab/')[-1]}:{ours[2]} {ours[0]}"
    return place if lib is ours else f"{place} ({lib_name})"


def holders_of(captures: list[tuple[str, Path]], top: int) -> dict:
    """Per phase: the allocations made in it and live at its heap peak, and those still live
    at its end, grouped by `_where` (MB), largest first; from the memray captures."""
    from collections import Counter

    from memray import FileReader

    out: dict[str, dict] = {}
    for phase, path in captures:
        reader = FileReader(path)
        peak = Counter()
        for rec in reader.get_high_watermark_allocation_records(merge_threads=True):
            peak[_where(rec.stack_trace(max_stacks=64))] += rec.size
        kept = Counter()
        for rec in reader.get_leaked_allocation_records(merge_threads=True):
            kept[_where(rec.stack_trace(max_stacks=64))] += rec.size
        best = out.get(phase)
        heap_peak = reader.metadata.peak_memory / 2**20
        if best is None or heap_peak > best["heap_peak_mb"]:
            out[phase] = {
                "heap_peak_mb": heap_peak,
                "at_peak": [(k, v / 2**20) for k, v in peak.most_common(top)],
                "kept": [(k, v / 2**20) for k, v in kept.most_common(top)],
            }
        reader.close()
    return out


# ----------------------------------------------------------------------------- the tables


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default=",".join(ROWS), help=f"comma-separated rows of {', '.join([*ROWS, 'make_test'])}")
    ap.add_argument("--holders", type=int, default=3, help="top holders per phase (memray; 0 = skip)")
    ap.add_argument("--no-probe", action="store_true", help="only the whole-process peaks")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="an override added to every row")
    ap.add_argument("--out", type=Path, default=None, help="keep the run folders and captures here")
    ap.add_argument("--probe", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--memray", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("rest", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.probe:
        probe(a.probe, a.memray, a.holders, [x for x in a.rest if x != "--"])
        return
    holders = a.holders
    if holders:
        try:
            import memray  # noqa: F401
        except ImportError:
            print("memray is not installed (pip install memray, or the dev extra): no holders table", file=sys.stderr)
            holders = 0

    results: dict[str, dict] = {}
    with tempfile.TemporaryDirectory(prefix="slamlab-memory-") as tmp_name:
        tmp = a.out or Path(tmp_name)
        tmp.mkdir(parents=True, exist_ok=True)
        for name in a.only.split(","):
            if name == "make_test":
                results[name] = measure_make_test(tmp)
                continue
            make_args, _ = ROWS[name]
            results[name] = measure_row(name, make_args() + a.set, tmp, holders, not a.no_probe)
            print(f"{name}: {results[name]['peak_mb']:.0f} MB", file=sys.stderr, flush=True)
    print_tables(results)


def print_tables(results: dict[str, dict]) -> None:
    print("| run | peak MB (whole process) | budget MB | met | peak phase (MB) | its file / anon MB at end "
          "| import floor MB (file / anon; libllvmlite) -> once LLVM is given back | maps MB at peak |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for name, r in results.items():
        budget = MAKE_TEST_BUDGET_MB if name == "make_test" else ROWS[name][1]
        ph = r.get("phases")
        if ph:
            top = max(ph["peak"], key=ph["peak"].get)
            end = ph["end"].get(top, {})
            where = f"{top} ({ph['peak'][top]:.0f})", f"{end.get('file', float('nan')):.0f} / {end.get('anon', float('nan')):.0f}"
        else:
            where = ("-", "-")
        fl = r.get("floor")
        floor = "-"
        if fl:
            after = fl["after"]
            floor = (f"{fl['VmHWM']:.0f} ({fl['RssFile']:.0f} / {fl['RssAnon']:.0f}; {fl['llvmlite']:.0f}) -> "
                     f"{after['VmRSS']:.0f} ({after['RssFile']:.0f} / {after['RssAnon']:.0f})")
        met = "-" if budget is None else ("yes" if r["peak_mb"] <= budget else "no")
        maps = f"{r['maps_peak_mb']:.0f}" if "maps_peak_mb" in r else "-"
        print(f"| {name} | {r['peak_mb']:.0f} | {'-' if budget is None else f'{budget:.0f}'} | {met} | {where[0]} | {where[1]} | {floor} | {maps} |")
    probed = {k: r["phases"] for k, r in results.items() if r.get("phases")}
    if probed:
        print("\nPeak resident MB reached in each phase (probed run; resident file-backed / anonymous MB when it ended):")
        print("| run | " + " | ".join(PHASES) + " |")
        print("| --- " * (len(PHASES) + 1) + "|")
        for name, ph in probed.items():
            cells = []
            for phase in PHASES:
                if phase not in ph["peak"]:
                    cells.append("-")
                    continue
                e = ph["end"][phase]
                cells.append(f"{ph['peak'][phase]:.0f} ({e['file']:.0f}/{e['anon']:.0f})")
            print(f"| {name} | " + " | ".join(cells) + " |")
    for name, r in results.items():
        hold = r.get("holders")
        if not hold:
            continue
        print(f"\nTop holders of {name} by phase (memray, MB allocated in the phase: live at its heap peak | still live at its end;"
              " allocated is not resident: pages never written, or given back while an array is copied, count here, not in RSS):")
        for phase in PHASES:
            h = hold.get(phase)
            if h is None:
                continue
            at_peak = "; ".join(f"{v:.1f} {k}" for k, v in h["at_peak"])
            kept = "; ".join(f"{v:.1f} {k}" for k, v in h["kept"] if v >= 0.05) or "-"
            print(f"- {phase} (heap peak {h['heap_peak_mb']:.0f}): {at_peak} | kept: {kept}")


if __name__ == "__main__":
    main()
