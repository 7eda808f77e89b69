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

from typing import TYPE_CHECKING

import numpy as np

from slamlab.eval.trajectory import sample_onto
from slamlab.frames import GridImage, GroundTruth
from slamlab.texture.texture_map import resample_to_grid

if TYPE_CHECKING:  # for the annotation only: the texture pipeline (open3d etc.) loads when used
    from slamlab.texture.pipeline import TextureResult


def neighbour_contrast(color: np.ndarray, mask: np.ndarray) -> float:
    """Mean absolute colour difference (0-255, channel mean) between 4-neighbour cell pairs
    that are both in `mask`: a sharpness score (blur lowers it)."""
    c = np.asarray(color)  # as it is: the pairs' cells are taken first, then made float64 (not a whole-grid copy)
    diffs = []
    for a, b, ma, mb in (
        (c[:, 1:], c[:, :-1], mask[:, 1:], mask[:, :-1]),
        (c[1:, :], c[:-1, :], mask[1:, :], mask[:-1, :]),
    ):
        both = ma & mb
        if np.any(both):
            diffs.append(np.abs(a[both].astype(np.float64) - b[both].astype(np.float64)).mean(axis=1))
    if not diffs:
        return float("nan")
    return float(np.concatenate(diffs).mean())


def texture_metrics(result: TextureResult, truth: GroundTruth | None,
                    truth_on_grid: tuple[np.ndarray, np.ndarray] | None = None) -> dict:
    """The `texture` section of metrics.json for one `TextureResult`.

    Always: counters and timings (`result.summary()`), `covered_area_m2`. With a true floor
    texture: `colour_error` (mean |RGB| error, 0-255, over covered cells that the truth
    covers), `colour_error_median`, `colour_rmse`, `covered_fraction` (covered / true floor
    area on the grid), `sharpness` and `truth_sharpness`. With ground labels: `detection`
    {detector: {precision, recall, f1, frames, tp, fp, fn, tn}}. `truth_on_grid`: the true floor
    texture already averaged into `result`'s grid (`resample_to_grid`), when the caller has it."""
    out = {"status": "ok"}
    out.update(result.summary())
    if result.detection:
        out["detection"] = {name: c.as_dict() for name, c in sorted(result.detection.items())}
    if truth is None or truth.floor_texture is None:
        return out
    true_col, has = truth_on_grid or resample_to_grid(truth.floor_texture, result.count.shape, result.resolution_m, result.origin_xy)
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
