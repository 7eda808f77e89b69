"""PNG files of plain images (a grey map, an RGB(A) texture) with Pillow alone.

`matplotlib.pyplot.imsave` wrote these before; importing pyplot costs about 0.4 s and
40 MB, more than a one-scan run spends on anything else. These functions write the same
bytes as `plt.imsave(path, values, cmap="gray", vmin=0, vmax=1)` and `plt.imsave(path,
rgba)`: the same RGBA pixels, the same tEXt chunk (`Software`, naming matplotlib, as
imsave does) and the same 100 dpi pHYs chunk, so a run made before this module still
verifies byte for byte (`slamlab-verify`). tests/test_png.py checks it against imsave.
"""

from __future__ import annotations

from importlib import metadata
from pathlib import Path

import numpy as np

# plt.imsave's defaults: a 256-entry colour table (rcParams image.lut) and 100 dpi.
_LUT_SIZE = 256
_DPI = 100


def grey_rgba(values: np.ndarray) -> np.ndarray:
    """(H, W, 4) uint8 RGBA of `values` in [0, 1] (0 black, 1 white), as matplotlib's
    "gray" colormap with vmin=0, vmax=1 renders it: value v takes table entry
    floor(v * 256) (1.0 takes the last), whose level is floor(255 * entry / 255) in
    float64; NaN is transparent black; values outside [0, 1] take the end colours."""
    v = np.array(values, dtype=np.float64)  # a copy: scaled in place below
    if v.ndim != 2:
        raise ValueError(f"expected a 2-D array of values in [0, 1], got shape {v.shape}")
    bad = np.isnan(v)
    v *= _LUT_SIZE
    v[v == _LUT_SIZE] = _LUT_SIZE - 1
    with np.errstate(invalid="ignore"):
        idx = v.astype(np.int64)
    np.clip(idx, 0, _LUT_SIZE - 1, out=idx)  # below 0: first colour, above 1: last
    # matplotlib builds the table with linspace and truncates table * 255 to bytes
    levels = (np.linspace(0.0, 1.0, _LUT_SIZE) * 255).astype(np.uint8)
    rgba = np.empty(v.shape + (4,), dtype=np.uint8)
    rgba[..., :3] = levels[idx][..., None]
    rgba[..., 3] = 255
    rgba[bad] = 0
    return rgba


def as_rgba(image: np.ndarray) -> np.ndarray:
    """(H, W, 4) uint8 RGBA of a uint8 RGB or RGBA image (RGB gets alpha 255)."""
    img = np.asarray(image)
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] not in (3, 4):
        raise ValueError(f"expected a (H, W, 3|4) uint8 image, got {img.dtype} {img.shape}")
    if img.shape[2] == 4:
        return np.ascontiguousarray(img)
    rgba = np.empty(img.shape[:2] + (4,), dtype=np.uint8)
    rgba[..., :3] = img
    rgba[..., 3] = 255
    return rgba


def write_png(path: Path, rgba: np.ndarray) -> None:
    """Write a (H, W, 4) uint8 RGBA image as PNG to `path` (not atomic: callers write to a
    temporary name, see `artifacts.atomic_path`)."""
    from PIL import Image, PngImagePlugin

    rgba = np.ascontiguousarray(rgba, dtype=np.uint8)
    h, w = rgba.shape[:2]
    image = Image.frombuffer("RGBA", (w, h), rgba, "raw", "RGBA", 0, 1)
    info = PngImagePlugin.PngInfo()
    software = _imsave_software()
    if software is not None:
        info.add_text("Software", software)
    image.save(path, format="png", pnginfo=info, dpi=(_DPI, _DPI))


def _imsave_software() -> str | None:
    """The `Software` text plt.imsave writes, from matplotlib's installed version (read
    from its package metadata: no import)."""
    try:
        return f"Matplotlib version{metadata.version('matplotlib')}, https://matplotlib.org/"
    except metadata.PackageNotFoundError:
        return None
