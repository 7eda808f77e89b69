"""What it takes to reproduce a run: resolved config, data fingerprint, versions, seed."""

from __future__ import annotations

import hashlib
import platform
import subprocess
import sys
from importlib import metadata
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

import slamlab


FULL_HASH_LIMIT = 256 << 20  # bytes; larger files (multi-GB RGB logs) are sampled


def _file_digest(path: Path) -> tuple[str, str]:
    """(sha256 hex, how): the whole file, or for very large files its size plus the first
    and last 4 MB, so that fingerprinting a several-GB RGB log takes milliseconds."""
    h = hashlib.sha256()
    size = path.stat().st_size
    with path.open("rb") as f:
        if size <= FULL_HASH_LIMIT:
            for chunk in iter(lambda: f.read(1 << 20), b""):
                h.update(chunk)
            return h.hexdigest(), "full"
        h.update(str(size).encode())
        h.update(f.read(4 << 20))
        f.seek(size - (4 << 20))
        h.update(f.read())
        return h.hexdigest(), "size+head+tail"


def fingerprint_files(paths: list[str]) -> dict:
    """sha256 over the given files (folders: every file inside, sorted by relative path).

    Returns {"sha256": hex digest over all, "files": {name: {"bytes", "sha256", "hashed"}}}.
    """
    total = hashlib.sha256()
    files: dict[str, dict] = {}
    for src in sorted(paths):
        p = Path(src)
        members = sorted(q for q in p.rglob("*") if q.is_file()) if p.is_dir() else [p]
        for q in members:
            digest, how = _file_digest(q)
            # names without machine paths keep the fingerprint equal across machines
            name = str(q.relative_to(p.parent)) if p.is_dir() else q.name
            if name in files:  # two inputs of the same name in different folders
                name = f"{name} ({q.parent})"
            files[name] = {"bytes": q.stat().st_size, "sha256": digest, "hashed": how}
            total.update(name.encode() + b"\0" + digest.encode())
    return {"sha256": total.hexdigest(), "files": files}


def _git_commit() -> str | None:
    try:
        root = Path(slamlab.__file__).resolve().parents[1]
        out = subprocess.run(
            ["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=5
        )
        return out.stdout.strip() or None if out.returncode == 0 else None
    except (OSError, subprocess.SubprocessError):
        return None


def _version(package: str) -> str | None:
    """A package's version: `__version__` when it is imported already, else its installed
    metadata (importing scipy only to name its version cost 0.3 s and 50 MB a run)."""
    module = sys.modules.get(package)
    if module is not None and hasattr(module, "__version__"):
        return str(module.__version__)
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return None


def _numba_threads() -> dict | None:
    """The threading layer numba's parallel kernels ran on ("tbb", "omp" or "workqueue") and
    its thread count, when a kernel started numba's threads in this process (else None)."""
    numba = sys.modules.get("numba")
    if numba is None:
        return None
    try:
        return {"layer": numba.threading_layer(), "threads": int(numba.get_num_threads())}
    except ValueError:  # no parallel kernel has run: no threads, no layer
        return None


def build_manifest(cfg: DictConfig, sources: list[str], overrides: list[str], cwd: str) -> dict:
    """The manifest.json content for a run."""
    return {
        "slamlab_version": slamlab.__version__,
        "git_commit": _git_commit(),
        "seed": int(cfg.seed),
        "overrides": list(overrides),
        "cwd": cwd,
        "command": " ".join(["slamlab", *overrides]),
        "data": fingerprint_files(sources),
        "platform": {
            "python": sys.version.split()[0],
            "machine": platform.machine(),
            "system": platform.system(),
            "numpy": _version("numpy"),
            "scipy": _version("scipy"),
            "numba": _version("numba"),
            "numba_threads": _numba_threads(),
        },
        "config": OmegaConf.to_container(cfg, resolve=True),
    }
