"""A few RGB-D frames kept for the report: ground detection and RGB-D alignment, shown.

The texture stage streams frames and keeps none; for the report it re-runs a handful of
frames spread over the run (`SAMPLE_FRAMES`) through the same steps and keeps small images:
- `rgb`: the colour image, shrunk;
- `registered`: the colour of every valid depth pixel sampled through the IR-to-RGB
  alignment (`align.sample_colors`), on the depth image's grid: if the calibration is right,
  edges in this image line up with the depth image's;
- `masks[name]`: which depth pixels each ground detector calls floor (the run's detector
  and `texture.evaluate_detectors`), `truth` the simulator's label when known.
About 5 frames of ~256x212 pixels: a few hundred kB compressed in `ground_frames.npz`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from slamlab.io.atomic import write_npz
from slamlab.camera import scaled_intrinsics
from slamlab.frames import KinectCalibration, RGBDFrame
from slamlab.texture.align import sample_colors
from slamlab.texture.backproject import Backprojector
from slamlab.texture.detection import DetectionCounts
from slamlab.texture.ground import GroundDetector, GroundQuery

SAMPLE_FRAMES = 5
MAX_SAMPLE_PX = 256  # longest side of the stored depth-grid images (pixels)


def sample_ordinals(total: int, count: int = SAMPLE_FRAMES) -> set[int]:
    """Ordinals (0-based position in the RGB-D stream) of `count` frames spread over `total`,
    avoiding the very first and last frame (often the robot standing still)."""
    if total <= 0:
        return set()
    return {int(round(v)) for v in np.linspace(0, total - 1, count + 2)[1:-1]} if total > count else set(range(total))


@dataclass
class FrameSample:
    """One sampled frame: images on the depth grid (row 0 = top), shrunk by `step`."""

    index: int
    t: float
    rgb: np.ndarray
    registered: np.ndarray
    masks: dict[str, np.ndarray]
    truth: np.ndarray | None
    scores: dict[str, tuple[float, float]] = field(default_factory=dict)  # name -> (precision, recall)


def sample_frame(
    frame: RGBDFrame,
    calib: KinectCalibration,
    backproject: Backprojector,
    T_world_cam: np.ndarray,
    detectors: dict[str, GroundDetector],
    truth: np.ndarray | None,
    distort_rgb: bool,
) -> FrameSample | None:
    """Run one frame through backprojection, every detector and the colour alignment;
    None when the frame has no valid depth or no colour image."""
    depth = np.asarray(frame.depth_m)
    if frame.rgb is None or depth.ndim != 2:
        return None
    pts = backproject(depth)
    if len(pts) == 0:
        return None
    h, w = depth.shape
    step = max(1, int(np.ceil(max(h, w) / MAX_SAMPLE_PX)))
    query = GroundQuery(pts, T_world_cam, scaled_intrinsics(calib.ir, w, h))

    def on_grid(values: np.ndarray, fill, dtype) -> np.ndarray:
        img = np.full((h, w) + values.shape[1:], fill, dtype)
        img[pts.v, pts.u] = values
        return img[::step, ::step]

    rgb = np.asarray(frame.rgb)
    colors, keep = sample_colors(pts.cam, rgb, calib, distort=distort_rgb)
    full = np.zeros((len(pts), 3), np.uint8)
    full[keep] = colors
    registered = on_grid(full, 0, np.uint8)
    rstep = max(1, int(np.ceil(max(rgb.shape[:2]) / (2 * MAX_SAMPLE_PX))))
    sample = FrameSample(index=int(frame.index), t=float(frame.t), rgb=rgb[::rstep, ::rstep].copy(),
                         registered=registered, masks={}, truth=None)
    truth_at = None
    if truth is not None and np.asarray(truth).shape == depth.shape:
        truth = np.asarray(truth, bool)
        truth_at = truth[pts.v, pts.u]
        sample.truth = on_grid(truth_at, False, bool)
    for name, det in detectors.items():
        floor = np.asarray(det(query), bool)
        sample.masks[name] = on_grid(floor, False, bool)
        if truth_at is not None:
            c = DetectionCounts()
            c.add(floor, truth_at)
            sample.scores[name] = (c.precision, c.recall)
    return sample


def write_samples(path: Path, samples: list[FrameSample]) -> None:
    """ground_frames.npz (docs/RUN_DIRECTORY.md): per frame i `rgb_i`, `registered_i`,
    `mask_i_NAME`, `truth_i`; `index`, `t`, `detectors`, `scores` (F, D, 2) precision and
    recall (NaN without labels)."""
    names = sorted({n for s in samples for n in s.masks})
    arrays: dict[str, np.ndarray] = {
        "index": np.array([s.index for s in samples], np.int64),
        "t": np.array([s.t for s in samples], np.float64),
        "detectors": np.array(names, dtype=str),
        "scores": np.array([[s.scores.get(n, (np.nan, np.nan)) for n in names] for s in samples], np.float64).reshape(len(samples), len(names), 2),
    }
    for i, s in enumerate(samples):
        arrays[f"rgb_{i}"] = s.rgb
        arrays[f"registered_{i}"] = s.registered
        for n, m in s.masks.items():
            arrays[f"mask_{i}_{n}"] = m
        if s.truth is not None:
            arrays[f"truth_{i}"] = s.truth
    write_npz(path, **arrays)
