"""The run report's ground-detection strip: sample RGB-D frames (ground_frames.npz, written
by the texture stage, slamlab.texture.samples) with each detector's floor tinted and the
registered colour, so a reader sees what the detectors pick and that the alignment holds."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slamlab.report.figures import fig_to_data_uri, plt
from slamlab.io.rundir import RunFile
from slamlab.report.rundir import RunDir

FLOOR_TINT = np.array([0.1, 0.85, 0.2])  # detected floor (correct, or no labels)
FALSE_TINT = np.array([0.95, 0.1, 0.1])  # detected floor where the label says not floor
MISS_TINT = np.array([0.15, 0.35, 1.0])  # labelled floor the detector missed


@dataclass(frozen=True, slots=True)
class GroundFrames:
    img: str
    frames: int
    detectors: list[str]
    labelled: bool


def tint(base: np.ndarray, mask: np.ndarray, truth: np.ndarray | None, alpha: float = 0.5) -> np.ndarray:
    """`base` (H, W, 3) uint8 with the detected floor tinted green; with labels, false floor
    red and missed floor blue. Returns float RGB in [0, 1]."""
    out = base.astype(np.float64) / 255.0
    layers = [(mask if truth is None else mask & truth, FLOOR_TINT)]
    if truth is not None:
        layers += [(mask & ~truth, FALSE_TINT), (~mask & truth, MISS_TINT)]
    for sel, colour in layers:
        out[sel] = (1 - alpha) * out[sel] + alpha * colour
    return out


def ground_frames_section(run: RunDir) -> GroundFrames | None:
    """One figure: a row per sample frame, columns colour image | registered RGB-D | one per
    detector; None when the run kept no frames."""
    z = run.files.read_arrays(RunFile.GROUND_FRAMES)
    if z is None:
        return None
    n = len(z["index"])
    names = [str(v) for v in z["detectors"]]
    if n == 0:
        return None
    labelled = any(f"truth_{i}" in z for i in range(n))
    ncols = 2 + len(names)
    fig, axes = plt.subplots(n, ncols, figsize=(2.9 * ncols, 2.5 * n), squeeze=False)
    for i in range(n):
        reg = z[f"registered_{i}"]
        truth = z.get(f"truth_{i}")
        row = axes[i]
        row[0].imshow(z[f"rgb_{i}"])
        row[0].set_title(f"frame {int(z['index'][i])}: colour image", fontsize=8)
        row[1].imshow(reg)
        row[1].set_title("registered: colour at each depth pixel", fontsize=8)
        for j, name in enumerate(names):
            mask = z.get(f"mask_{i}_{name}")
            ax = row[2 + j]
            if mask is None:
                ax.axis("off")
                continue
            ax.imshow(tint(reg, mask.astype(bool), None if truth is None else truth.astype(bool)))
            prec, rec = z["scores"][i, j]
            score = f"\nP {prec:.2f}  R {rec:.2f}" if np.isfinite(prec) or np.isfinite(rec) else ""
            ax.set_title(f"{name}{score}", fontsize=8)
        for ax in row:
            ax.set_xticks([])
            ax.set_yticks([])
    fig.tight_layout()
    return GroundFrames(img=fig_to_data_uri(fig, fmt="jpeg"), frames=n, detectors=names, labelled=labelled)
