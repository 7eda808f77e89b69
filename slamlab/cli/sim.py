"""`slamlab-sim OUT`: write a simulated THOR-OP sequence into folder OUT.

Every simulator knob is an option (`--seed 3 --duration-s 60 --kinect-scale 1.0 ...`, the
names of `SimParams` / conf/dataset/sim.yaml). The folder then reads like a real recording:
`slamlab dataset=thor dataset.root=OUT`, or `scipy.io.loadmat` in your own code.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

from slamlab.errors import SlamlabError


def _bool(text: str) -> bool:
    t = text.strip().lower()
    if t in ("1", "true", "yes", "on"):
        return True
    if t in ("0", "false", "no", "off"):
        return False
    raise argparse.ArgumentTypeError(f"expected true/false, got {text!r}")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser: OUT, --force, --calibration-dir, and one option per SimParams field."""
    from slamlab.datasets.sim import SimParams

    p = argparse.ArgumentParser(prog="slamlab-sim", description=__doc__.split("\n\n")[0], formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("out", type=Path, help="folder to create (must not exist unless --force)")
    p.add_argument("--force", action="store_true", help="replace OUT if it exists")
    p.add_argument("--calibration-dir", type=Path, default=None, help="real cameraParam/ folder for the Kinect numbers (default: built-in THOR values)")
    from slamlab.datasets.sim.world import LAYOUTS

    for f in dataclasses.fields(SimParams):
        if f.type in ("str", str):
            choices = LAYOUTS if f.name == "layout" else None
            p.add_argument("--" + f.name.replace("_", "-"), dest=f.name, type=str, default=f.default, choices=choices)
            continue
        kind = _bool if f.type in ("bool", bool) else (int if f.type in ("int", int) else float)
        p.add_argument("--" + f.name.replace("_", "-"), dest=f.name, type=kind, default=f.default, metavar=kind.__name__.lstrip("_").upper())
    return p


def main(argv: list[str] | None = None) -> int:
    """Generate the sequence; prints a one-line summary. Returns the exit status."""
    from slamlab.datasets.sim import SimParams, generate_atomic
    from slamlab.datasets.sim.generate import validate_params

    args = build_parser().parse_args(argv)
    params = SimParams(**{f.name: getattr(args, f.name) for f in dataclasses.fields(SimParams)})
    out: Path = args.out
    try:
        validate_params(params)
        if out.exists() and not args.force:
            raise SlamlabError(f"{out} exists (use --force to replace it)")
        t0 = time.perf_counter()
        generate_atomic(out, params, args.calibration_dir, replace=True)
    except SlamlabError as exc:
        print(f"slamlab-sim: error: {exc}", file=sys.stderr)
        return 2
    files = sorted(p for p in out.rglob("*") if p.is_file())
    size = sum(p.stat().st_size for p in files)
    scans = int(round(params.duration_s * 40))
    print(f"wrote {out} in {time.perf_counter() - t0:.1f} s: {scans} scans, seed {params.seed}, {len(files)} files, {size / 1e6:.1f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
