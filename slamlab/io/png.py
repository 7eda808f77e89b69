"""PNG files of plain images (a grey map, an RGB(A) texture), without matplotlib.

`matplotlib.pyplot.imsave` wrote these before; importing pyplot costs about 0.4 s and
40 MB, more than a one-scan run spends on anything else. These functions write the same
bytes as `plt.imsave(path, values, cmap="gray", vmin=0, vmax=1)` and `plt.imsave(path,
rgba)`: the same RGBA pixels, the same tEXt chunk (`Software`, naming matplotlib, as
imsave does) and the same 100 dpi pHYs chunk, so a run made before this module still
verifies byte for byte (`slamlab-verify`). They encode as Pillow's writer does (imsave's
encoder), but a band of rows at a time (`write_png_bands`): a building's map is ~200 MB of
RGBA pixels. tests/test_png.py checks the bytes against imsave and Pillow.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Iterable
from importlib import metadata
from pathlib import Path
from typing import BinaryIO

import numpy as np

# plt.imsave's defaults: a 256-entry colour table (rcParams image.lut) and 100 dpi.
_LUT_SIZE = 256
_BAND_ROWS = 128  # rows of `grey_rgba`'s input converted at a time
_DPI = 100


def grey_rgba(values: np.ndarray) -> np.ndarray:
    """(H, W, 4) uint8 RGBA of `values` in [0, 1] (0 black, 1 white), as matplotlib's
    "gray" colormap with vmin=0, vmax=1 renders it: value v takes table entry
    floor(v * 256) (1.0 takes the last), whose level is floor(255 * entry / 255) in
    float64; NaN is transparent black; values outside [0, 1] take the end colours."""
    values = np.asarray(values)
    if values.ndim != 2:
        raise ValueError(f"expected a 2-D array of values in [0, 1], got shape {values.shape}")
    # matplotlib builds the table with linspace and truncates table * 255 to bytes
    levels = (np.linspace(0.0, 1.0, _LUT_SIZE) * 255).astype(np.uint8)
    rgba = np.empty(values.shape + (4,), dtype=np.uint8)
    for r in range(0, values.shape[0], _BAND_ROWS):  # a band at a time: whole-image float64 / int64 temporaries were 4x the result
        v = np.array(values[r : r + _BAND_ROWS], dtype=np.float64)  # a copy: scaled in place below
        bad = np.isnan(v)
        v *= _LUT_SIZE
        v[v == _LUT_SIZE] = _LUT_SIZE - 1
        with np.errstate(invalid="ignore"):
            idx = v.astype(np.int64)
        np.clip(idx, 0, _LUT_SIZE - 1, out=idx)  # below 0: first colour, above 1: last
        band = rgba[r : r + _BAND_ROWS]
        band[..., :3] = levels[idx][..., None]
        band[..., 3] = 255
        band[bad] = 0
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


def write_png(path: Path | BinaryIO, rgba: np.ndarray) -> None:
    """Write a (H, W, 4) uint8 RGBA image as PNG to `path` (not atomic: callers write to a
    temporary name, see `artifacts.atomic_path`)."""
    rgba = np.ascontiguousarray(rgba, dtype=np.uint8)
    write_png_bands(path, rgba.shape[1], rgba.shape[0], [rgba])


def write_png_bands(path: Path | BinaryIO, width: int, height: int, bands: Iterable[np.ndarray]) -> None:
    """Write an RGBA PNG of `width` x `height` pixels from `bands`, (rows, width, 4) uint8
    blocks of its rows top to bottom, holding one band at a time (a building's map.png is
    ~200 MB of RGBA pixels as one array).

    The bytes are those Pillow's PNG writer gives the whole image (what plt.imsave called):
    its chunks (IHDR, tEXt Software, pHYs 100 dpi, IDAT, IEND), its row filters (per row the
    first of none, up, sub, Paeth with the least sum of |byte| read as signed, libpng's
    heuristic, as Pillow's ZipEncode.c picks them without `optimize`; no further one once a
    row's best costs 0), its zlib settings (level 6, 32 kB window, memLevel 9, Z_FILTERED)
    and its IDAT chunks (the deflate stream cut into max(64 kB, 4 x width) pieces).
    tests/test_png.py checks it against Pillow and imsave."""
    if width < 1 or height < 1:
        raise ValueError(f"a PNG has at least one pixel a side, got {width} x {height}")
    own = not hasattr(path, "write")
    f = open(path, "wb") if own else path  # type: ignore[arg-type]
    try:
        f.write(b"\x89PNG\r\n\x1a\n")
        _chunk(f, b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 6, 0, 0, 0))  # 8-bit RGBA, no interlace
        software = _imsave_software()
        if software is not None:
            _chunk(f, b"tEXt", b"Software\0" + software.encode("latin-1"))
        per_m = int(_DPI / 0.0254 + 0.5)
        _chunk(f, b"pHYs", struct.pack(">IIB", per_m, per_m, 1))
        idat = max(_PILLOW_BLOCK, 4 * width)
        deflate = zlib.compressobj(6, zlib.DEFLATED, 15, 9, zlib.Z_FILTERED)
        pending = bytearray()
        previous = np.zeros(4 * width, dtype=np.uint8)
        rows = 0
        for band in bands:
            if band.dtype != np.uint8 or band.ndim != 3 or band.shape[1:] != (width, 4):
                raise ValueError(f"expected ({width}, 4) uint8 pixel rows, got a {band.dtype} band of shape {band.shape}")
            if rows + len(band) > height:
                raise ValueError(f"the bands hold more than the image's {height} rows")
            if not len(band):
                continue
            band = np.ascontiguousarray(band)
            raw = band.reshape(len(band), 4 * width)
            pending += deflate.compress(_filtered_rows(raw, previous))
            previous = raw[-1].copy()
            rows += len(band)
            while len(pending) >= idat:
                _chunk(f, b"IDAT", bytes(pending[:idat]))
                del pending[:idat]
        if rows != height:
            raise ValueError(f"the bands held {rows} rows, the image has {height}")
        pending += deflate.flush()
        for at in range(0, len(pending), idat):
            _chunk(f, b"IDAT", bytes(pending[at:at + idat]))
        _chunk(f, b"IEND", b"")
    finally:
        if own:
            f.close()


_PILLOW_BLOCK = 65536  # Pillow's ImageFile.MAXBLOCK: its encoder's output buffer, one IDAT chunk each


def _chunk(f: BinaryIO, kind: bytes, data: bytes) -> None:
    f.write(struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(data, zlib.crc32(kind))))


def _filtered_rows(raw: np.ndarray, previous: np.ndarray) -> bytes:
    """PNG scanlines of pixel rows `raw` (n, 4W) uint8 below the row `previous` (4W,), each
    row's filter chosen as Pillow's encoder does (`png_filter.filter_rows`)."""
    from slamlab.io.png_filter import filter_rows  # numba: loaded when a PNG is written, not on import

    out = np.empty((raw.shape[0], raw.shape[1] + 1), dtype=np.uint8)
    filter_rows(raw, previous, out)
    return out.tobytes()


def _imsave_software() -> str | None:
    """The `Software` text plt.imsave writes, from matplotlib's installed version (read
    from its package metadata: no import)."""
    try:
        return f"Matplotlib version{metadata.version('matplotlib')}, https://matplotlib.org/"
    except metadata.PackageNotFoundError:
        return None
