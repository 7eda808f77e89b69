"""Hydra callback: a single run claims its folder before Hydra writes anything into it.

Hydra writes `.hydra/` (the saved config and overrides) into `hydra.run.dir` before the app
runs, so a run that the pipeline refuses later (the folder holds another run) would already
have overwritten that run's saved config. `on_run_start` comes first: Hydra calls it for a
single run only (a sweep's jobs write into `hydra.sweep.dir`, each claiming its own folder in
the pipeline), with the folder's name as the command line and the config files make it,
interpolations too (`hydra.run.dir=out/seed${seed}`). Enabled in conf/config.yaml:

    hydra:
      callbacks:
        claim_run_dir:
          _target_: slamlab.cli.run_claim.ClaimRunDirCallback
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from hydra.core.hydra_config import HydraConfig
from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf, read_write

from slamlab.pipeline import RunDirectoryInUse, claim_run_dir

# The folder this process claimed and whether it made it (the CLI gives it back if the run
# never starts), and the folders that existed before (a run that never started empties them of
# its own files but never removes them).
CLAIMED: list[tuple[Path, bool]] = []
PRE_EXISTING: set[Path] = set()


def claim(run_dir: Path) -> None:
    """Make `run_dir` (created if missing) this process's, or say why not and exit 2."""
    created = not run_dir.exists()
    if not created:
        PRE_EXISTING.add(run_dir.resolve())
    run_dir.mkdir(parents=True, exist_ok=True)
    try:
        claim_run_dir(run_dir)
    except RunDirectoryInUse as exc:
        print(f"slamlab: {exc}", file=sys.stderr)
        sys.exit(2)
    CLAIMED.append((run_dir, created))


class ClaimRunDirCallback(Callback):
    """See module doc."""

    def on_run_start(self, config: DictConfig, **kwargs: Any) -> None:
        HydraConfig.instance().set_config(config)  # `${hydra:...}` in the folder's name resolves as the run will resolve it
        run_dir = str(OmegaConf.select(config, "hydra.run.dir"))
        with read_write(config.hydra.run):
            # resolved once: the default name's `${now:...%f}` would name another folder when Hydra reads it again
            config.hydra.run.dir = run_dir
        claim(Path(run_dir))
