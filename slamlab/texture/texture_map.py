"""The texture map: a colour grid aligned cell-for-cell with the occupancy grid.

Each floor point adds its colour to the cell it falls in; a cell's colour is the average of
its points. Two averages are offered:
- `mean`: the running mean of every point (cheap, but one mis-registered frame smears in);
- `robust`: a gated running mean: once a cell has `robust_min_count` points, a point whose
  colour differs from the cell's current mean by more than `robust_reject` (0-255, any
  channel) is ignored. It rejects colours from a badly placed frame or a foot in view without
  storing per-cell histories (memory stays 7 numbers per cell whatever the sequence length).
Cells never observed stay blank (count 0).

The per-cell mean of the points' world positions is kept too, so the floor point cloud is a
voxel-downsampled cloud (one point per cell column) for free.
"""

from __future__ import annotations

import numba
import numpy as np

from slamlab.frames import GridImage

RESAMPLE_BAND_PIXELS = 1 << 19  # `resample_to_grid` bins this many source pixels at a time


@numba.njit(cache=True, nogil=True)
def _accumulate(lin, colors, xyz, color_sum, xyz_sum, count, robust, reject, min_count):  # pragma: no cover - compiled
    """Add points to cells in order. Returns how many were rejected by the robust gate."""
    rejected = 0
    for i in range(lin.shape[0]):
        c = lin[i]
        n = count[c]
        if robust and n >= min_count:
            bad = False
            for k in range(3):
                if abs(colors[i, k] - color_sum[c, k] / n) > reject:
                    bad = True
            if bad:
                rejected += 1
                continue
        for k in range(3):
            color_sum[c, k] += colors[i, k]
            xyz_sum[c, k] += xyz[i, k]
        count[c] = n + 1
    return rejected


class TextureAccumulator:
    """Accumulates coloured floor points into a (H, W) grid with the occupancy grid's
    `resolution_m` and `origin_xy` (cell (r, c) covers x in [ox + c res, +res), y in
    [oy + r res, +res), row 0 = lowest y)."""

    def __init__(
        self,
        shape: tuple[int, int],
        resolution_m: float,
        origin_xy: tuple[float, float],
        average: str = "mean",
        robust_reject: float = 60.0,
        robust_min_count: int = 5,
    ):
        if average not in ("mean", "robust"):
            raise ValueError(f"average must be 'mean' or 'robust', got {average!r}")
        self.shape = (int(shape[0]), int(shape[1]))
        self.resolution_m = float(resolution_m)
        self.origin_xy = (float(origin_xy[0]), float(origin_xy[1]))
        self.robust = average == "robust"
        self.robust_reject = float(robust_reject)
        self.robust_min_count = int(robust_min_count)
        ncell = self.shape[0] * self.shape[1]
        self.color_sum = np.zeros((ncell, 3), dtype=np.float64)
        self.xyz_sum = np.zeros((ncell, 3), dtype=np.float64)
        self.count = np.zeros(ncell, dtype=np.int64)
        self.points_outside = 0
        self.points_rejected = 0

    @classmethod
    def like(cls, grid: GridImage, **kwargs) -> TextureAccumulator:
        """An accumulator aligned with `grid` (same shape, resolution and origin)."""
        return cls(grid.data.shape[:2], grid.resolution_m, grid.origin_xy, **kwargs)

    def cell_index(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Linear cell index of each (x, y) (m) and a mask of those inside the grid."""
        res = self.resolution_m
        c = np.floor((xy[:, 0] - self.origin_xy[0]) / res).astype(np.int64)
        r = np.floor((xy[:, 1] - self.origin_xy[1]) / res).astype(np.int64)
        inside = (c >= 0) & (c < self.shape[1]) & (r >= 0) & (r < self.shape[0])
        return r * self.shape[1] + c, inside

    def add(self, world: np.ndarray, colors: np.ndarray) -> int:
        """Add (K, 3) world points (m) with (K, 3) uint8 colours; returns how many landed in the grid."""
        if world.shape[0] == 0:
            return 0
        lin, inside = self.cell_index(world)
        self.points_outside += int(world.shape[0] - np.count_nonzero(inside))
        lin = lin[inside]
        self.points_rejected += int(
            _accumulate(
                lin,
                # No dtype conversion: the kernel is compiled for uint8 colours / float32 points.
                np.ascontiguousarray(colors[inside]),
                np.ascontiguousarray(world[inside]),
                self.color_sum,
                self.xyz_sum,
                self.count,
                self.robust,
                self.robust_reject,
                self.robust_min_count,
            )
        )
        return int(lin.size)

    # ---- results -------------------------------------------------------------------------
    @property
    def counts(self) -> np.ndarray:
        """(H, W) int64 points per cell."""
        return self.count.reshape(self.shape)

    def finish(self, blank: tuple[int, int, int] = (0, 0, 0)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The averages, in one pass over the cells (no cell-sized temporaries: on the 2x
        `sim_loops` building those took ~100 MB at the texture stage's end):
        - (H, W, 3) uint8 mean colour, unobserved cells `blank`;
        - one point per observed cell, in row-major cell order: (K, 3) float64 mean position (m)
          and (K, 3) uint8 mean colour (a voxel-downsampled floor cloud)."""
        k = int(np.count_nonzero(self.count))
        color = np.empty((self.count.size, 3), dtype=np.uint8)
        pts = np.empty((k, 3), dtype=np.float64)
        cols = np.empty((k, 3), dtype=np.uint8)
        _averages(self.color_sum, self.xyz_sum, self.count, np.asarray(blank, dtype=np.uint8), color, pts, cols)
        return color.reshape(self.shape + (3,)), pts, cols


@numba.njit(cache=True, nogil=True)
def _averages(color_sum, xyz_sum, count, blank, color, pts, cols):  # pragma: no cover - compiled
    """`TextureAccumulator.finish`'s pass: each observed cell's means, rounded as NumPy's
    `clip(rint(sum / n), 0, 255)` rounds them (half to even)."""
    j = 0
    for c in range(count.shape[0]):
        n = count[c]
        if n == 0:
            for k in range(3):
                color[c, k] = blank[k]
            continue
        for k in range(3):
            v = min(max(np.rint(color_sum[c, k] / n), 0.0), 255.0)
            color[c, k] = np.uint8(v)
            cols[j, k] = np.uint8(v)
            pts[j, k] = xyz_sum[c, k] / n
        j += 1


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
    cols = np.flatnonzero((c >= 0) & (c < w))
    n = np.zeros(h * w)
    out = np.zeros((h * w, 3))
    # a band of source rows at a time: the cell indices and weights of a few MB of source pixels,
    # not of the whole image (a simulated floor's made the texture stage's peak). Integer
    # colours (uint8) sum exactly in float64, so the bands give the one-pass sums, bit for bit.
    band = max(1, RESAMPLE_BAND_PIXELS // max(len(cols), 1))
    for r0 in range(0, sh, band):
        rows = r0 + np.flatnonzero((r[r0:r0 + band] >= 0) & (r[r0:r0 + band] < h))
        if len(rows) == 0 or len(cols) == 0:
            continue
        lin = (r[rows][:, None] * w + c[cols][None, :]).ravel()
        block = src[rows][:, cols]
        n += np.bincount(lin, minlength=h * w)
        for k in range(3):
            out[:, k] += np.bincount(lin, weights=block[..., k].ravel().astype(np.float64), minlength=h * w)
    has = n > 0
    out[has] /= n[has, None]
    return out.reshape(h, w, 3), has.reshape(h, w)
