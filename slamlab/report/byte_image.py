"""Map images drawn as bytes: `imshow_bytes` puts a uint8 RGBA raster (a map, a map layer) in
an Axes, drawn with nearest sampling by NumPy at the output's pixel size.

Why not `Axes.imshow`: matplotlib (3.9+) resamples a uint8 RGBA image in float32 with
premultiplied alpha at the output's size: for a map filling a 13-15 inch report figure,
~1,000 x 900 pixels, that is 30-40 bytes a pixel of temporaries while the figure is saved
(+17-25 MB), and it was the report's peak, the whole process's for a one-scan run and for
`make run` (issue 44). Nearest sampling needs none of it: each output pixel takes the
image's pixel under its centre, one uint8 copy at the output's size.

The geometry is matplotlib's own for images drawn on a raster canvas (`_ImageBase._make_image`):
the image's extent through the Axes' transform, clipped to the Axes, rounded out to whole
output pixels; pixels then match `imshow(..., interpolation="nearest")` but where a pixel
centre falls on an image cell's border (tested). Anything else (other interpolation, a
vector backend, scalar alpha, an unclipped image, axes that rotate, shear or are not affine)
goes through matplotlib's own path (`NearestBytesImage.samples_as_bytes`).
"""

from __future__ import annotations

import math

import numpy as np

from slamlab.report.mpl import Affine2D, AxesImage, Bbox, rcParams


class NearestBytesImage(AxesImage):
    """An AxesImage of uint8 RGBA (origin "lower" or "upper") sampled by nearest neighbour in
    NumPy (see the module doc)."""

    def samples_as_bytes(self, unsampled: bool = False) -> bool:
        """Whether `make_image` samples this image itself: uint8 RGBA, nearest, no scalar alpha,
        clipped to the Axes, on axes whose transform only scales and shifts (no rotation or
        shear). Otherwise matplotlib's own path draws it."""
        A = self._A
        if (unsampled or A is None or A.ndim != 3 or A.shape[2] != 4 or A.dtype != np.uint8
                or self.get_interpolation() != "nearest" or self.get_alpha() is not None or not self.get_clip_on()):
            return False
        trans = self.get_transform()
        if not trans.is_affine:
            return False
        m = trans.get_affine().get_matrix()
        return m[0, 1] == 0.0 and m[1, 0] == 0.0

    def make_image(self, renderer, magnification: float = 1.0, unsampled: bool = False):
        if not self.samples_as_bytes(unsampled):
            return super().make_image(renderer, magnification, unsampled)
        A = self._A
        trans = self.get_transform()
        x1, x2, y1, y2 = self.get_extent()
        corners = trans.transform([[x1, y1], [x2, y2]])  # display pixels (an axis may run backwards)
        clipped = Bbox.intersection(Bbox(corners), self.get_clip_box() or self.axes.bbox)
        if clipped is None:
            return None, 0, 0, None
        e = clipped.extents * magnification
        # rounded to whole output pixels as matplotlib does, so the image meets the Axes' edges
        X0, Y0 = math.floor(e[0] + 0.5), math.ceil(e[1] - 0.5 - 1e-8)
        X1, Y1 = math.floor(e[2] + 0.5 + 1e-8), math.ceil(e[3] - 0.5)
        if X1 <= X0 or Y1 <= Y0:
            return None, 0, 0, None
        H, W = A.shape[:2]
        (dx0, dy0), (dx1, dy1) = corners * magnification
        # the image cell under each output pixel's centre (display y up; row 0 of `out` is the bottom)
        cols = np.floor((X0 + np.arange(X1 - X0) + 0.5 - dx0) / (dx1 - dx0) * W).astype(np.int64)
        rows = np.floor((Y0 + np.arange(Y1 - Y0) + 0.5 - dy0) / (dy1 - dy0) * H).astype(np.int64)
        if self.origin == "upper":
            rows = H - 1 - rows
        out = np.zeros((Y1 - Y0, X1 - X0, 4), dtype=np.uint8)  # off the image: transparent
        r_in = np.flatnonzero((rows >= 0) & (rows < H))
        c_in = np.flatnonzero((cols >= 0) & (cols < W))
        if len(r_in) and len(c_in):
            out[r_in[:, None], c_in[None, :]] = A[rows[r_in][:, None], cols[c_in][None, :]]
        return out, X0 / magnification, Y0 / magnification, Affine2D()


def imshow_bytes(ax, rgba: np.ndarray, extent: tuple[float, float, float, float], origin: str = "lower",
                 zorder: float | None = None) -> NearestBytesImage:
    """`ax.imshow(rgba, origin=origin, extent=extent, interpolation="nearest")` for a uint8 RGBA
    raster (H, W, 4), drawn as `NearestBytesImage`; extent (left, right, bottom, top) in data
    units. Like imshow, it sets the Axes' aspect (rcParams "image.aspect") and the data limits
    to the extent, and clips to the Axes' patch."""
    rgba = np.asarray(rgba)
    if rgba.ndim != 3 or rgba.shape[2] != 4 or rgba.dtype != np.uint8:
        raise ValueError(f"imshow_bytes wants (H, W, 4) uint8 RGBA, got {rgba.shape} {rgba.dtype}")
    ax.set_aspect(rcParams["image.aspect"])
    im = NearestBytesImage(ax, origin=origin, extent=extent, interpolation="nearest")
    im.set_data(rgba)
    im.set_clip_path(ax.patch)
    if zorder is not None:
        im.set_zorder(zorder)
    im.set_extent(im.get_extent())
    ax.add_image(im)
    return im
