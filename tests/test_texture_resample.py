"""Texture scores with small temporaries: `texture_map.resample_to_grid` averages a finer colour
image into a grid's cells a band of source rows at a time, and `eval.texture.neighbour_contrast`
takes the cell pairs before making them float64. Both give the whole-array results bit for bit
(uint8 colours sum exactly)."""

from __future__ import annotations

import numpy as np
import pytest

from slamlab.eval.texture import neighbour_contrast
from slamlab.frames import GridImage
from slamlab.texture import texture_map
from slamlab.texture.texture_map import resample_to_grid


def _one_pass(texture: GridImage, shape: tuple[int, int], res: float, origin: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Every source pixel at once, into its target cell (the reference)."""
    h, w = shape
    src = texture.data
    sh, sw = src.shape[:2]
    r = np.floor((texture.origin_xy[1] + (np.arange(sh) + 0.5) * texture.resolution_m - origin[1]) / res).astype(np.int64)
    c = np.floor((texture.origin_xy[0] + (np.arange(sw) + 0.5) * texture.resolution_m - origin[0]) / res).astype(np.int64)
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


@pytest.mark.parametrize("band_pixels", [1, 500, 1 << 30])
def test_banded_resampling_is_the_one_pass_average(monkeypatch, band_pixels):
    rng = np.random.default_rng(2)
    # 0.02 m source pixels over a 0.05 m grid: the source overhangs it left and below, the grid it right and above
    texture = GridImage(rng.integers(0, 256, (230, 170, 3), dtype=np.uint8), 0.02, (-0.37, -0.81))
    shape, res, origin = (90, 80), 0.05, (-0.2, -0.5)
    monkeypatch.setattr(texture_map, "RESAMPLE_BAND_PIXELS", band_pixels)
    colour, has = resample_to_grid(texture, shape, res, origin)
    ref_colour, ref_has = _one_pass(texture, shape, res, origin)
    assert np.array_equal(has, ref_has) and 0 < has.sum() < has.size
    assert np.array_equal(colour, ref_colour)


def test_a_source_that_misses_the_grid_covers_nothing():
    texture = GridImage(np.full((20, 20, 3), 200, dtype=np.uint8), 0.02, (10.0, 10.0))
    colour, has = resample_to_grid(texture, (30, 30), 0.05, (0.0, 0.0))
    assert not has.any() and not colour.any()


def test_neighbour_contrast_is_that_of_the_float64_grid():
    rng = np.random.default_rng(5)
    colour = rng.integers(0, 256, (60, 70, 3), dtype=np.uint8)
    mask = rng.random((60, 70)) < 0.6
    c = colour.astype(np.float64)
    pairs = [np.abs(a[m] - b[m]).mean(axis=1) for a, b, m in ((c[:, 1:], c[:, :-1], mask[:, 1:] & mask[:, :-1]),
                                                               (c[1:], c[:-1], mask[1:] & mask[:-1]))]
    assert neighbour_contrast(colour, mask) == float(np.concatenate(pairs).mean()) > 50
    assert neighbour_contrast(c, mask) == neighbour_contrast(colour, mask)  # float64 colours (the truth's) too


def test_the_accumulators_averages_are_numpys_to_the_bit():
    # the one-pass `finish` against the array formula it replaced: half-way colours round to even,
    # unobserved cells take the blank colour, the cloud lists observed cells in row-major order
    rng = np.random.default_rng(3)
    acc = texture_map.TextureAccumulator((40, 50), 0.05, (-1.0, -2.0))
    world = np.c_[rng.uniform(-1.0, 1.5, 3000), rng.uniform(-2.0, 0.0, 3000), rng.normal(0.0, 0.01, 3000)].astype(np.float32)
    colors = rng.integers(0, 256, (3000, 3), dtype=np.uint8)
    colors[:40] = (1, 2, 3)  # a cell with two points of 1 and 2: 1.5 rounds to 2, 2.5 to 2
    acc.add(world, colors)
    acc.color_sum[7] = (3, 5, 255 * 2)
    acc.count[7] = 2
    color, pts, cols = acc.finish(blank=(9, 8, 7))
    n = acc.count[:, None]
    seen = acc.count > 0
    want = np.empty((acc.count.size, 3), dtype=np.uint8)
    want[seen] = np.clip(np.rint(acc.color_sum[seen] / n[seen]), 0, 255).astype(np.uint8)
    want[~seen] = (9, 8, 7)
    assert np.array_equal(color.reshape(-1, 3), want) and (~seen).any()
    assert tuple(color.reshape(-1, 3)[7]) == (2, 2, 255)
    idx = np.flatnonzero(seen)
    assert np.array_equal(pts, acc.xyz_sum[idx] / acc.count[idx, None].astype(np.float64))
    assert np.array_equal(cols, want[idx])
