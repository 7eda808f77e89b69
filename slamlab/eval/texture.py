"""Texture-mapping metrics against the simulator's ground truth.

- colour error: mean absolute RGB difference (0-255 scale, averaged over the 3 channels) over
  the covered cells, against the true floor texture resampled to the texture grid by
  averaging the true texture's pixels inside each cell (our cells are averages too);
- covered area (m^2) and the fraction of the true floor it represents;
- sharpness: mean absolute colour difference between 4-neighbouring covered cells, beside
  the truth's own value over the same cells. A weak signal: a drifting trajectory mostly
  SHIFTS the texture (sharp but wrong), so compare trajectories by colour error;
- ground detection precision / recall per detector on the labelled depth frames.

`texture_metrics(result, truth)` returns a JSON-friendly dict (the `texture` section of
metrics.json); `truth=None` (real data) gives the counters and coverage only.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from slamlab.eval.trajectory import sample_onto
from slamlab.frames import GridImage, GroundTruth

if TYPE_CHECKING:  # the pipeline imports this module; avoid the cycle at run time
    from slamlab.texture.pipeline import TextureResult


@dataclass(slots=True)
class DetectionCounts:
    """Pixel counts of one detector against ground labels, summed over labelled frames.
    Only valid depth pixels (the ones a detector sees) are counted."""

    tp: int = 0
    fp: int = 0
    fn: int = 0
    tn: int = 0
    frames: int = 0

    def add(self, predicted: np.ndarray, truth: np.ndarray) -> None:
        """Add one frame: `predicted`, `truth` (M,) bool over the same points."""
        p = np.asarray(predicted, dtype=bool)
        t = np.asarray(truth, dtype=bool)
        tp = int(np.count_nonzero(p & t))
        np_ = int(np.count_nonzero(p))
        nt = int(np.count_nonzero(t))
        self.tp += tp
        self.fp += np_ - tp
        self.fn += nt - tp
        self.tn += int(p.size) - np_ - nt + tp
        self.frames += 1

    @property
    def precision(self) -> float:
        """TP / (TP + FP); NaN if nothing was predicted."""
        d = self.tp + self.fp
        return self.tp / d if d else float("nan")

    @property
    def recall(self) -> float:
        """TP / (TP + FN); NaN if no pixel is labelled floor."""
        d = self.tp + self.fn
        return self.tp / d if d else float("nan")

    def as_dict(self) -> dict:
        p, r = self.precision, self.recall
        f1 = 2 * p * r / (p + r) if (p + r) > 0 else float("nan")
        return {
            "precision": p, "recall": r, "f1": f1, "frames": self.frames,
            "tp": self.tp, "fp": self.fp, "fn": self.fn, "tn": self.tn,
        }  # fmt: skip


def resample_to_grid(
    texture: GridImage, shape: tuple[int, int], resolution_m: float, origin_xy: tuple[float, float]
) -> tuple[np.ndarray, np.ndarray]:
    """Average a (finer) colour GridImage into the cells of another grid.

    Returns (colour (H, W, 3) float64, has_truth (H, W) bool); each source pixel goes to the
    cell holding its centre. If the source is coarser than the target, nearest sampling at
    cell centres is used instead (every target cell would otherwise miss out)."""
    h, w = int(shape[0]), int(shape[1])
    src = np.asarray(texture.data)
    sh, sw = src.shape[:2]
    if texture.resolution_m > resolution_m:
        cy = origin_xy[1] + (np.arange(h) + 0.5) * resolution_m
        cx = origin_xy[0] + (np.arange(w) + 0.5) * resolution_m
        r = np.floor((cy - texture.origin_xy[1]) / texture.resolution_m).astype(int)
        c = np.floor((cx - texture.origin_xy[0]) / texture.resolution_m).astype(int)
        rr, cc = np.meshgrid(r, c, indexing="ij")
        ok = (rr >= 0) & (rr < sh) & (cc >= 0) & (cc < sw)
        out = np.zeros((h, w, 3))
        out[ok] = src[rr[ok], cc[ok], :3]
        return out, ok
    ys = texture.origin_xy[1] + (np.arange(sh) + 0.5) * texture.resolution_m
    xs = texture.origin_xy[0] + (np.arange(sw) + 0.5) * texture.resolution_m
    r = np.floor((ys - origin_xy[1]) / resolution_m).astype(np.int64)
    c = np.floor((xs - origin_xy[0]) / resolution_m).astype(np.int64)
    rr, cc = np.meshgrid(r, c, indexing="ij")
    ok = (rr >= 0) & (rr < h) & (cc >= 0) & (cc < w)
    lin = (rr * w + cc)[ok]
    n = np.bincount(lin, minlength=h * w).astype(np.float64)
    out = np.zeros((h * w, 3))
    for k in range(3):
        out[:, k] = np.bincount(lin, weights=src[..., k][ok].astype(np.float64), minlength=h * w)
    has = n > 0
    out[has] /= n[has, None]
    return out.reshape(h, w, 3), has.reshape(h, w)


def neighbour_contrast(color: np.ndarray, mask: np.ndarray) -> float:
    """Mean absolute colour difference (0-255, channel mean) between 4-neighbour cell pairs
    that are both in `mask`: a sharpness score (blur lowers it)."""
    c = np.asarray(color, dtype=np.float64)
    diffs = []
    for a, b, ma, mb in (
        (c[:, 1:], c[:, :-1], mask[:, 1:], mask[:, :-1]),
        (c[1:, :], c[:-1, :], mask[1:, :], mask[:-1, :]),
    ):
        both = ma & mb
        if np.any(both):
            diffs.append(np.abs(a[both] - b[both]).mean(axis=1))
    if not diffs:
        return float("nan")
    return float(np.concatenate(diffs).mean())


def texture_metrics(result: TextureResult, truth: GroundTruth | None) -> dict:
    """The `texture` section of metrics.json for one `TextureResult`.

    Always: counters and timings (`result.summary()`), `covered_area_m2`. With a true floor
    texture: `colour_error` (mean |RGB| error, 0-255, over covered cells that the truth
    covers), `colour_error_median`, `colour_rmse`, `covered_fraction` (covered / true floor
    area on the grid), `sharpness` and `truth_sharpness`. With ground labels: `detection`
    {detector: {precision, recall, f1, frames, tp, fp, fn, tn}}."""
    out = {"status": "ok"}
    out.update(result.summary())
    if result.detection:
        out["detection"] = {name: c.as_dict() for name, c in sorted(result.detection.items())}
    if truth is None or truth.floor_texture is None:
        return out
    true_col, has = resample_to_grid(truth.floor_texture, result.count.shape, result.resolution_m, result.origin_xy)
    cov = result.covered & has
    out["evaluated_cells"] = int(np.count_nonzero(cov))
    floor_cells = has
    if truth.occupancy is not None:
        # the true walls, looked up at the texture grid's cell centres (grids differ in size and origin)
        target = GridImage(result.count, result.resolution_m, result.origin_xy)
        wall = sample_onto(GridImage(truth.occupancy.data.astype(np.float64), truth.occupancy.resolution_m,
                                     truth.occupancy.origin_xy), target)
        floor_cells = has & ~(wall > 0.5)
    out["covered_fraction"] = float(np.count_nonzero(result.covered & floor_cells)) / max(1, int(np.count_nonzero(floor_cells)))
    if not np.any(cov):
        out["colour_error"] = float("nan")
        return out
    err = np.abs(result.color[cov].astype(np.float64) - true_col[cov])  # (K, 3)
    per_cell = err.mean(axis=1)
    out["colour_error"] = float(per_cell.mean())
    out["colour_error_median"] = float(np.median(per_cell))
    out["colour_rmse"] = float(np.sqrt(np.mean(err**2)))
    out["sharpness"] = neighbour_contrast(result.color, cov)
    out["truth_sharpness"] = neighbour_contrast(true_col, cov)
    return out
