"""`report.byte_image.imshow_bytes`: a uint8 RGBA raster drawn by nearest sampling in NumPy
draws what `Axes.imshow(..., interpolation="nearest")` draws: the same pixels where the image
is enlarged; where it is shrunk, each pixel one of its matplotlib pixel's or a neighbour's
(where an output pixel's centre falls on a cell border the two round differently)."""

from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image

from slamlab.report.byte_image import NearestBytesImage, imshow_bytes
from slamlab.report.figures import subplots


def _render(image: np.ndarray, extent: tuple[float, float, float, float], ours: bool, origin: str = "lower",
            layer: np.ndarray | None = None, line: bool = True) -> np.ndarray:
    fig, ax = subplots(figsize=(9.0, 7.0))
    if ours:
        imshow_bytes(ax, image, extent, origin=origin)
        if layer is not None:
            imshow_bytes(ax, layer, extent, zorder=3)
    else:
        ax.imshow(image, origin=origin, extent=extent, interpolation="nearest")
        if layer is not None:
            ax.imshow(layer, origin="lower", extent=extent, interpolation="nearest", zorder=3)
    ax.set_aspect("equal")
    if line:  # something else on the axes, drawn over the image
        ax.plot([extent[0], extent[1]], [extent[2], extent[3]], lw=0.5)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    return np.asarray(Image.open(buf)).astype(np.int16)


def _random_rgba(rng: np.random.Generator, h: int, w: int, opaque: bool) -> np.ndarray:
    img = rng.integers(0, 256, (h, w, 4), dtype=np.uint8)
    img[..., 3] = 255 if opaque else rng.choice(np.array([0, 76, 242, 255], dtype=np.uint8), (h, w))
    return img


@pytest.mark.parametrize("origin", ["lower", "upper"])
def test_an_enlarged_opaque_raster_draws_matplotlibs_pixels(origin):
    rng = np.random.default_rng(3)
    img = _random_rgba(rng, 150, 190, opaque=True)  # ~3 output pixels a cell
    extent = (-3.0, -3.0 + 190 * 0.05, 10.0, 10.0 + 150 * 0.05)
    ours, theirs = _render(img, extent, True, origin, line=False), _render(img, extent, False, origin, line=False)
    assert ours.shape == theirs.shape
    differ = (ours != theirs).any(-1)
    # where a row (or column) of output pixel centres falls exactly on a cell border, the two
    # round it to either side: at most a couple of whole lines differ, every other pixel is equal
    assert differ.sum() <= 2 * (differ.shape[0] + differ.shape[1])
    shifted = np.zeros_like(differ)
    for dy, dx in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        shifted |= (np.roll(theirs, (dy, dx), axis=(0, 1)) == ours).all(-1)
    assert shifted[differ].all()  # each differing pixel is its neighbour's colour in matplotlib's drawing


@pytest.mark.parametrize("shape,opaque", [((700, 1300), True), ((800, 800), False), ((40, 2000), True)])
def test_a_shrunk_raster_takes_each_pixel_from_the_same_cell_or_a_neighbours(shape, opaque):
    rng = np.random.default_rng(shape[0])
    img = _random_rgba(rng, *shape, opaque=opaque)
    extent = (0.0, shape[1] * 0.05, 0.0, shape[0] * 0.05)
    layer = _random_rgba(rng, 8, 8, opaque=False)  # a second, transparent layer over it
    ours, theirs = _render(img, extent, True, layer=layer), _render(img, extent, False, layer=layer)
    assert ours.shape == theirs.shape
    # premultiplied-alpha round trips move a translucent colour by 1 in matplotlib's path
    near = (np.abs(ours - theirs) <= 1).all(-1)
    assert near.mean() > 0.97  # random cells: any shifted cell border shows, and most pixels still agree
    for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0), (1, 1), (1, -1), (-1, 1), (-1, -1)):
        near |= (np.abs(np.roll(theirs, (dy, dx), axis=(0, 1)) - ours) <= 1).all(-1)
    assert near[1:-1, 1:-1].mean() > 0.995  # a flipped, shifted or scaled image would agree on ~0


def test_only_uint8_rgba_goes_the_byte_way():
    fig, ax = subplots()
    with pytest.raises(ValueError, match="uint8 RGBA"):
        imshow_bytes(ax, np.zeros((4, 4, 4)), (0.0, 1.0, 0.0, 1.0))
    im = imshow_bytes(ax, np.zeros((4, 4, 4), dtype=np.uint8), (0.0, 1.0, 0.0, 1.0))
    assert isinstance(im, NearestBytesImage) and im in ax.get_images()
    assert ax.get_xlim() == (0.0, 1.0) and ax.get_ylim() == (0.0, 1.0)  # the data limits follow the extent, as imshow's


def test_the_bytes_are_sampled_here_and_anything_else_goes_to_matplotlib(monkeypatch):
    """The memory saving is the NumPy path being taken: matplotlib's own `make_image` must not
    run for a plain uint8 RGBA map, and must run where the fast path would be wrong (a rotated
    image, a float image)."""
    from matplotlib.image import AxesImage
    from matplotlib.transforms import Affine2D

    calls = []
    original = AxesImage.make_image

    def spy(self, *args, **kwargs):
        calls.append(type(self).__name__)
        return original(self, *args, **kwargs)

    monkeypatch.setattr(AxesImage, "make_image", spy)
    fig, ax = subplots(figsize=(4.0, 3.0))
    img = _random_rgba(np.random.default_rng(0), 30, 40, opaque=True)
    im = imshow_bytes(ax, img, (0.0, 4.0, 0.0, 3.0))
    fig.savefig(io.BytesIO(), format="png")
    assert im.samples_as_bytes() and calls == []
    im.set_transform(Affine2D().rotate_deg_around(2.0, 1.5, 30.0) + ax.transData)
    assert not im.samples_as_bytes()
    fig.savefig(io.BytesIO(), format="png")
    assert calls  # the rotated image went to matplotlib
    other = imshow_bytes(ax, img, (0.0, 4.0, 0.0, 3.0))
    other.set_interpolation("bilinear")
    assert not other.samples_as_bytes()  # another interpolation: matplotlib's


def test_a_saved_figure_lets_go_of_its_renderer_at_once(monkeypatch):
    """`fig_to_data_uri`: the renderer savefig drew with (the whole figure's pixels) is freed when
    the figure is dropped, not at the garbage collector's next full pass (Text artists cache it,
    and a figure lives in reference cycles)."""
    import gc
    import weakref

    from matplotlib.backends import backend_agg

    from slamlab.report.figures import fig_to_data_uri

    made = []
    original = backend_agg.FigureCanvasAgg.get_renderer

    def spy(self, *args, **kwargs):
        renderer = original(self, *args, **kwargs)
        made.append(weakref.ref(renderer))
        return renderer

    monkeypatch.setattr(backend_agg.FigureCanvasAgg, "get_renderer", spy)
    gc.collect()
    gc.disable()
    try:
        fig, ax = subplots(figsize=(6.0, 4.0))
        ax.plot([0, 1], [0, 1], label="a line")
        ax.set_title("a title")
        ax.legend()
        assert fig_to_data_uri(fig).startswith("data:image/png;base64,")
        del fig, ax
        assert made and all(r() is None for r in made)
    finally:
        gc.enable()
