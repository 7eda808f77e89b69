"""The run report's ground-detection strip: sample RGB-D frames (ground_frames.npz, written
by the texture stage, slamlab.texture.samples) with each detector's floor tinted and the
registered colour, so a reader sees what the detectors pick and that the alignment holds."""

from __future__ import annotations

import base64
import io
from dataclasses import dataclass

import numpy as np

from slamlab.io.rundir import RunFile
from slamlab.report.rundir import RunDir

FLOOR_TINT = np.array([0.1, 0.85, 0.2])  # detected floor (correct, or no labels)
FALSE_TINT = np.array([0.95, 0.1, 0.1])  # detected floor where the label says not floor
MISS_TINT = np.array([0.15, 0.35, 1.0])  # labelled floor the detector missed


@dataclass(frozen=True, slots=True)
class Panel:
    img: str  # data URI ("" = an empty cell: the detector kept no mask for that frame)
    caption: str


@dataclass(frozen=True, slots=True)
class GroundFrames:
    rows: list[list[Panel]]  # a row per frame: colour image | registered RGB-D | one per detector
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
    """A row of panels per sample frame: colour image | registered RGB-D | one per
    detector; None when the run kept no frames. The panels are the frames themselves, laid
    out by the page (a grid with captions): drawing them into one matplotlib figure took
    0.8-1.2 s of the default run's report, nearly all of it axes and layout."""
    z = run.files.read_arrays(RunFile.GROUND_FRAMES)
    if z is None:
        return None
    n = len(z["index"])
    names = [str(v) for v in z["detectors"]]
    if n == 0:
        return None
    labelled = any(f"truth_{i}" in z for i in range(n))
    rows = []
    for i in range(n):
        reg = z[f"registered_{i}"]
        truth = z.get(f"truth_{i}")
        row = [Panel(jpeg_data_uri(z[f"rgb_{i}"]), f"frame {int(z['index'][i])}: colour image"),
               Panel(jpeg_data_uri(reg), "registered: colour at each depth pixel")]
        for j, name in enumerate(names):
            mask = z.get(f"mask_{i}_{name}")
            if mask is None:
                row.append(Panel("", name))
                continue
            tinted = tint(reg, mask.astype(bool), None if truth is None else truth.astype(bool))
            prec, rec = z["scores"][i, j]
            score = f" \N{EM DASH} P {prec:.2f}  R {rec:.2f}" if np.isfinite(prec) or np.isfinite(rec) else ""
            row.append(Panel(jpeg_data_uri(np.round(tinted * 255.0).astype(np.uint8)), f"{name}{score}"))
        rows.append(row)
    return GroundFrames(rows=rows, frames=n, detectors=names, labelled=labelled)


def jpeg_data_uri(rgb: np.ndarray, quality: int = 85) -> str:
    """An (H, W, 3) uint8 image as a base64 JPEG data URI (camera frames: PNG would be ~5x larger)."""
    from PIL import Image  # pillow ships with matplotlib

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgb)).save(buf, format="JPEG", quality=quality)
    return "data:image/jpeg;base64," + base64.b64encode(buf.getvalue()).decode("ascii")
