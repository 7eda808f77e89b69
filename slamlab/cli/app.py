"""`slamlab`: the Hydra app. One run, or a sweep with `-m` (e.g. `slamlab -m particles=50,100,150`).

User mistakes (bad files, impossible config values) print one clear line and exit with
status 2; in a sweep, a failed job is recorded in its run folder and the sweep goes on.
Ctrl-C prints one line (`interrupted at scan K/N; partial results in DIR`) and exits 130.
"""

from __future__ import annotations

import gc
import importlib
import logging
import os
import re
import signal
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig

import slamlab.config.store  # noqa: F401  (the schemas the YAML files extend, whatever the config path: -cp, verify)
from slamlab.cli import run_claim
from slamlab.cli.overrides import check_overrides, hydra_mode_unset
from slamlab.code_pages import give_back_llvm_pages_after_loads, start_numba_runtime
from slamlab.errors import SlamlabError
from slamlab.interrupt import EXIT_INTERRUPTED, RunInterrupted
from slamlab.io.rundir import RunFile
from slamlab.pipeline import (
    claimed_by_this_process,
    run_pipeline,
    user_error,
)

log = logging.getLogger("slamlab")


def run_and_report(
    cfg: DictConfig,
    run_dir: Path,
    overrides: list[str] | None = None,
    progress: Callable[[int, int], None] | str | None = "auto",
) -> dict:
    """`run_pipeline` (same arguments and metrics), then `report.html` in `run_dir` when
    `cfg.report` is on. A report problem is logged and never fails a finished run. A run
    stopped by Ctrl-C gets its report too, marked "interrupted", from what it wrote."""
    try:
        metrics = run_pipeline(cfg, run_dir, overrides=overrides, progress=progress)
    except RunInterrupted:
        if cfg.get("report", True):
            _write_report(Path(run_dir))
        raise
    if cfg.get("report", True):
        _write_report(Path(run_dir))
    return metrics


def _write_report(run_dir: Path) -> None:
    """report.html in `run_dir`; a problem (or a second Ctrl-C meanwhile) is logged, not raised."""
    try:
        from slamlab.report.run_report import write_run_report

        write_run_report(run_dir)
    except (Exception, KeyboardInterrupt) as exc:  # a report problem must not fail a run
        log.error("could not write report.html: %s", exc or type(exc).__name__)


def _limit_threads_for_parallel_jobs() -> None:
    """Parallel sweep jobs each get one thread, so N jobs use N cores, not N x cores."""
    import os

    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
        os.environ[var] = "1"
    try:
        import numba

        numba.set_num_threads(1)
    except (ImportError, ValueError):
        pass


def _skip_numba_probes() -> None:
    """numba's first kernel load probes for two optional libraries that slamlab's kernels
    never use, at a cost paid by every run:
    - whether SciPy's BLAS exists, by importing scipy.linalg (0.2-0.25 s CPU and 13 MB of a
      one-scan Intel run, which needs no SciPy otherwise). The answer only picks how
      np.correlate / np.convolve compile inside a kernel (BLAS's dot or numba's own loop);
      slamlab's kernels call neither, and any other linear algebra in a kernel still imports
      SciPy's BLAS when that kernel compiles.
    - whether cffi exists (installed here for google-auth, which Ray brings), by building a
      `cffi.FFI()`, which imports cffi's C parser: ~0.07 s CPU. It only lets kernels call
      cffi functions; slamlab's call none.
    So each probe runs here, once per process, with its one module hidden: it finds nothing.
    The modules stay importable for everything else afterwards (`_hydra_main` calls this first,
    before any thread of the run could import them while they are hidden)."""
    for probe, hidden in (("numba.np.arraymath", "scipy.linalg.cython_blas"), ("numba.core.typing.cffi_utils", "cffi")):
        if probe in sys.modules or hidden in sys.modules:
            continue  # probed already, or the library is loaded and the probe costs nothing
        sys.modules[hidden] = None  # type: ignore[assignment]  (an import of it raises ImportError)
        try:
            importlib.import_module(probe)  # the module whose import probes
        except ModuleNotFoundError as exc:
            if exc.name is None or not (probe == exc.name or probe.startswith(exc.name + ".")):
                raise
            # another numba version keeps the probe elsewhere: it then runs as numba has it
        finally:
            del sys.modules[hidden]


def _run_in_child(work: Callable[[], None]) -> int:
    """Run `work` in a forked child process and return its exit status (128 + N when a
    signal N ended it). Why: jobs of a sequential sweep used to run one after the other in
    one process, and each job's peak memory then included what the jobs before it left
    allocated (caches, the allocator's free lists: 50 particles, seeds 0 / 1 / 2 measured 444 /
    539 / 523 MB). A child starts from the same parent every time, so each job's peak is its
    own whatever its place, and a job the system kills for memory ends that job, not the sweep.
    The parent runs no kernel and starts no thread pool, so forking is safe; Ctrl-C reaches the
    child, which stops after its step and writes its partial run, and the sweep then stops."""
    sys.stdout.flush()
    sys.stderr.flush()
    pid = os.fork()
    if pid == 0:  # the child: run the job, never return into Hydra
        code = 1
        try:
            work()
            code = 0
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
        except BaseException:  # noqa: BLE001 - a bug: its traceback, then the child ends
            import traceback

            traceback.print_exc()
        finally:
            logging.shutdown()
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(code)
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)  # the child handles Ctrl-C and says where it stopped
    try:
        while True:
            try:
                _, status = os.waitpid(pid, 0)
                break
            except InterruptedError:
                continue
    finally:
        signal.signal(signal.SIGINT, previous)
    code = os.waitstatus_to_exitcode(status)
    return 128 - code if code < 0 else code


def is_sweep_job(hc: Any) -> bool:
    """Whether this is one job of a sweep: `-m`, or a config that sets `hydra.mode: MULTIRUN`
    (`+experiment=ladder`), where Hydra leaves the job's mode unset but numbers the job."""
    from omegaconf import OmegaConf

    return hc.mode == RunMode.MULTIRUN or not OmegaConf.is_missing(hc.job, "num")


def _isolate_jobs(hc: Any) -> bool:
    """Run this sweep's jobs in child processes: Hydra's basic launcher (one job after the
    other in this process) on Linux; the parallel launchers give jobs worker processes of
    their own."""
    # Linux only: macOS forbids using many system libraries in a forked child that did not exec
    return sys.platform.startswith("linux") and "BasicLauncher" in str(hc.launcher.get("_target_", ""))


@hydra.main(version_base="1.3", config_path="../conf", config_name="config")
def _hydra_main(cfg: DictConfig) -> None:
    hc = HydraConfig.get()
    multirun = is_sweep_job(hc)
    if multirun and _isolate_jobs(hc):
        code = _run_in_child(lambda: _run_job(cfg, hc, multirun))
        if code == EXIT_INTERRUPTED:
            sys.exit(EXIT_INTERRUPTED)  # Ctrl-C: the child said where it stopped; the sweep stops too
        if code != 0:
            log.error("job %s ended with status %d; details in %s", hc.job.num, code, Path(hc.runtime.output_dir))
        return
    _run_job(cfg, hc, multirun)


def _run_job(cfg: DictConfig, hc: Any, multirun: bool) -> None:
    """One run (or one job of a sweep): the pipeline and its report, errors said in one line."""
    _skip_numba_probes()
    give_back_llvm_pages_after_loads()  # LLVM's code resident only while numba loads a kernel
    start_numba_runtime()  # its first load's LLVM pages now, while the process is small, not on top of the run's data
    if multirun and "BasicLauncher" not in str(hc.launcher.get("_target_", "")):
        _limit_threads_for_parallel_jobs()  # joblib, submitit, ray: jobs run side by side
    run_dir = Path(hc.runtime.output_dir)
    try:
        run_and_report(cfg, run_dir, overrides=list(hc.overrides.task), progress=cfg.get("progress", "auto"))
        log.info("outputs in %s%s", run_dir, " (open report.html)" if cfg.get("report", True) else "")
    except RunInterrupted as exc:
        print(exc, file=sys.stderr)
        sys.exit(EXIT_INTERRUPTED)
    except Exception as exc:
        err = user_error(exc)
        if err is None and not multirun:
            raise  # a bug: keep the traceback
        log.error("%s", err or exc)
        if not multirun and err is not None and _discard_unrun(run_dir):
            # a mistake found before any work (a config value, a missing file): the line
            # above says it all, and a folder holding nothing but that would only be litter
            sys.exit(2)
        log.error("run failed; details in %s", run_dir / RunFile.METRICS)
        if not multirun:
            sys.exit(2)


# What a run leaves in its folder before it produces anything (Hydra's record, the claim, the
# failure's metrics.json and log): a folder holding only these held no run.
_BEFORE_ANY_RESULT = frozenset({RunFile.HYDRA_DIR, RunFile.CLAIM, RunFile.METRICS, RunFile.LOG})


def _discard_unrun(run_dir: Path) -> bool:
    """Remove a single run's folder when the run stopped before it produced anything (a
    config error, a missing data file: its folder holds nothing but Hydra's record, the claim,
    metrics.json and the log). True when removed; a folder with anything else is kept, and one
    that existed before the run is emptied of the run's files but stays."""
    import shutil

    run_dir = Path(run_dir)
    try:
        names = {p.name for p in run_dir.iterdir()}
    except OSError:
        return False
    if not names <= _BEFORE_ANY_RESULT:
        return False
    for name in names:
        path = run_dir / name
        shutil.rmtree(path, ignore_errors=True) if path.is_dir() else path.unlink(missing_ok=True)
    if run_dir.resolve() not in run_claim.PRE_EXISTING:
        try:
            run_dir.rmdir()
            # the date folder Hydra made for it (outputs/DATE/), if the run was its only one
            if re.fullmatch(r"\d{4}-\d{2}-\d{2}", run_dir.parent.name):
                run_dir.parent.rmdir()
        except OSError:
            pass
    return True


def _release_unused_claim() -> None:
    """Hydra stopped before the run started (a config error found late, an error in Hydra's
    own set-up): give the folder `run_claim` claimed back."""
    if not run_claim.CLAIMED:
        return
    run_dir, created = run_claim.CLAIMED.pop()
    if (run_dir / RunFile.METRICS).exists() or not claimed_by_this_process(run_dir):
        return
    (run_dir / RunFile.CLAIM).unlink(missing_ok=True)
    if created:
        try:
            run_dir.rmdir()  # only if empty
        except OSError:
            pass


def _exit_if_sweep_runs_failed() -> None:
    """After a sweep (and its report): a failed job makes the whole command fail, and the
    last line names the failed jobs and their errors."""
    from slamlab.report.callback import LAST_SWEEP

    failed = LAST_SWEEP["failed"]
    if failed:
        print(f"{len(failed)} of {LAST_SWEEP['runs']} runs failed: {'; '.join(failed)}", file=sys.stderr)
        sys.exit(1)


def _skip_hydra_mode_compose() -> None:
    """Hydra composes the whole config once only to read `hydra.mode` (`Hydra.get_mode`),
    then again to run. When no config file or override sets that mode (`hydra_mode_unset`)
    its answer is None (then `-m` alone decides), so answer None without composing: 0.2-0.3 s
    of a one-scan run's CPU. A Hydra without that method is left as it is."""
    from hydra._internal.hydra import Hydra

    if callable(getattr(Hydra, "get_mode", None)):
        Hydra.get_mode = lambda self, config_name, overrides: None  # type: ignore[method-assign]


def main() -> None:
    """Console entry point."""
    # What is imported so far lives as long as the process: the garbage collector need not
    # scan it again at every full collection.
    gc.freeze()
    # a log line that cannot be written (a full disk under slamlab.log) must not print a
    # traceback per line: the console still shows it, and the run's error says why
    logging.raiseExceptions = False
    if any(a in ("--help", "-h") for a in sys.argv[1:]):
        from slamlab.cli.help import help_text

        print(help_text())  # one line per group and key, from the schemas (Hydra's lists schema/* too)
        return
    mistake = check_overrides(sys.argv[1:])
    if mistake:
        print(f"slamlab: {mistake}", file=sys.stderr)
        sys.exit(2)
    if hydra_mode_unset(sys.argv[1:]):
        _skip_hydra_mode_compose()
    try:
        _hydra_main()
        _exit_if_sweep_runs_failed()
    except SlamlabError as exc:  # raised before Hydra's own reporting (rare)
        print(f"slamlab: {exc}", file=sys.stderr)
        sys.exit(2)
    except KeyboardInterrupt as exc:  # Ctrl-C outside a run (while Hydra starts or ends)
        print(exc if isinstance(exc, RunInterrupted) else "interrupted", file=sys.stderr)
        sys.exit(EXIT_INTERRUPTED)
    finally:
        _release_unused_claim()
        # The process ends here: without this, Python's last full collections at exit scan
        # every object the run imported or kept (0.6 s of CPU after a one-scan run). Frozen
        # objects are freed with the process instead; files are closed and logs flushed by
        # then (logging flushes in its atexit hook, which still runs, or in `command` before a
        # single run's `os._exit`).
        gc.freeze()


def command() -> None:
    """The `slamlab` command: `main`, then, for one run, the process ends at once (`os._exit`)
    once the log is flushed, without Python's teardown. Why: by then every file of the run is
    written and closed; the teardown only frees what the process's end frees anyway, and the
    C++ libraries' destructors (LLVM's, GTSAM's) read their code back in to do it: a one-scan
    run's whole-process peak was 149 MB until it exited and 158 MB after (`/usr/bin/time`),
    and the teardown took 0.03-0.1 s. A sweep (`hydra.mode` set anywhere, or any Hydra flag:
    argparse reads `--multi` and `-mc job` as `-m` too) ends the normal way: its launchers'
    exit hooks stop their workers (Ray's processes). An exception other than SystemExit also
    ends the normal way, with its traceback."""
    argv = sys.argv[1:]
    if any(a.startswith("-") for a in argv) or not hydra_mode_unset(argv):
        main()
        return
    code: object = None
    try:
        main()
    except SystemExit as exc:
        code = exc.code
    if code is None:
        status = 0
    elif isinstance(code, int):
        status = code & 0xFF  # the status the shell sees, as Python's own exit gives it
    else:  # sys.exit("message"): printed, status 1, as Python does
        print(code, file=sys.stderr)
        status = 1
    logging.shutdown()  # flush and close every handler (slamlab.log), as Python's own exit would
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed or broken pipe: nothing more can be said there
            pass
    os._exit(status)


if __name__ == "__main__":
    command()
