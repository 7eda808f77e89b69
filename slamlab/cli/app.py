"""`slamlab`: the Hydra app. One run, or a sweep with `-m` (e.g. `slamlab -m particles=50,100,150`).

User mistakes (bad files, impossible config values) print one clear line and exit with
status 2; in a sweep, a failed job is recorded in its run folder and the sweep goes on.
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig

from slamlab.errors import SlamlabError
from slamlab.pipeline import RUN_MARKERS, run_pipeline, user_error

log = logging.getLogger("slamlab")


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


@hydra.main(version_base="1.3", config_path="../conf", config_name="config")
def _hydra_main(cfg: DictConfig) -> None:
    hc = HydraConfig.get()
    multirun = hc.mode == RunMode.MULTIRUN
    if multirun and "BasicLauncher" not in str(hc.launcher.get("_target_", "")):
        _limit_threads_for_parallel_jobs()  # joblib, submitit, ray: jobs run side by side
    run_dir = Path(hc.runtime.output_dir)
    try:
        run_pipeline(cfg, run_dir, overrides=list(hc.overrides.task), progress=cfg.get("progress", "auto"))
        log.info("outputs in %s%s", run_dir, " (open report.html)" if cfg.get("report", True) else "")
    except Exception as exc:
        err = user_error(exc)
        if err is None and not multirun:
            raise  # a bug: keep the traceback
        log.error("%s", err or exc)
        log.error("run failed; details in %s", run_dir / "metrics.json")
        if not multirun:
            sys.exit(2)


def _refuse_reused_run_dir(argv: list[str]) -> None:
    """Hydra writes .hydra/ into the run dir before the app starts: stop first if a user
    points `hydra.run.dir` at a folder that already holds a run."""
    for arg in argv:
        if arg.startswith("hydra.run.dir="):
            d = Path(arg.split("=", 1)[1])
            taken = [m for m in RUN_MARKERS if (d / m).exists()]
            if taken:
                print(f"slamlab: {d} already holds a run ({', '.join(taken)}); "
                      "slamlab never overwrites a run. Choose another hydra.run.dir.", file=sys.stderr)
                sys.exit(2)


def main() -> None:
    """Console entry point."""
    _refuse_reused_run_dir(sys.argv[1:])
    try:
        _hydra_main()
    except SlamlabError as exc:  # raised before Hydra's own reporting (rare)
        print(f"slamlab: {exc}", file=sys.stderr)
        sys.exit(2)


if __name__ == "__main__":
    main()
