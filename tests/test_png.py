"""PNG without matplotlib: the same bytes plt.imsave wrote (slamlab.io.png)."""

from __future__ import annotations

import io
import subprocess
import sys

import numpy as np
import pytest

from slamlab.io import png

plt = pytest.importorskip("matplotlib.pyplot")


def _imsave(arr: np.ndarray, **kw) -> bytes:
    buf = io.BytesIO()
    plt.imsave(buf, arr, format="png", **kw)
    return buf.getvalue()


def _ours(rgba: np.ndarray) -> bytes:
    buf = io.BytesIO()
    png.write_png(buf, rgba)
    return buf.getvalue()


def _grey_cases() -> list[np.ndarray]:
    rng = np.random.default_rng(0)
    # every table boundary k/256, every byte level k/255, and their float neighbours
    edges = np.concatenate([np.arange(257) / 256, np.arange(256) / 255, [0.5, 1e-12, 1 - 1e-12]])
    near = [np.nextafter(edges, 2.0).clip(0, 1), np.nextafter(edges, -1.0).clip(0, 1)]
    log_odds = rng.normal(0.0, 3.0, (64, 80)).astype(np.float32)  # as write_map shades a map
    return [
        rng.random((37, 53)),
        edges.reshape(1, -1),
        *(e.reshape(1, -1) for e in near),
        np.array([[np.nan, -0.5, 1.5, 0.3]]),
        1.0 - 1.0 / (1.0 + np.exp(-log_odds.astype(np.float64))),
        _tall_with_every_kind(rng),
    ]


def _tall_with_every_kind(rng: np.random.Generator) -> np.ndarray:
    """Taller than the rows `grey_rgba` converts at a time (its last band partial), with NaN and
    values below 0 and above 1 in several bands."""
    v = rng.random((2 * png._BAND_ROWS + 45, 23))
    v[rng.random(v.shape) < 0.05] = np.nan
    v[rng.random(v.shape) < 0.05] = -0.3
    v[rng.random(v.shape) < 0.05] = 1.7
    return v


@pytest.mark.parametrize("case", range(len(_grey_cases())))
def test_grey_png_is_byte_identical_to_imsave_gray(case):
    values = _grey_cases()[case]
    assert _ours(png.grey_rgba(values)) == _imsave(values, cmap="gray", vmin=0.0, vmax=1.0)


@pytest.mark.parametrize("channels", [3, 4])
def test_rgb_and_rgba_png_are_byte_identical_to_imsave(channels):
    img = np.random.default_rng(channels).integers(0, 256, (20, 30, channels), dtype=np.uint8)
    assert _ours(png.as_rgba(img)) == _imsave(img)


def test_bad_shapes_are_refused():
    with pytest.raises(ValueError, match="2-D"):
        png.grey_rgba(np.zeros((2, 2, 2)))
    with pytest.raises(ValueError, match="uint8"):
        png.as_rgba(np.zeros((2, 2, 3), dtype=np.float32))


def test_writing_a_map_does_not_import_matplotlib(tmp_path):
    code = (
        "import sys, numpy as np\n"
        "from slamlab import artifacts\n"
        "from slamlab.frames import GridImage\n"
        f"artifacts.write_map({str(tmp_path)!r}, GridImage(np.zeros((3, 4), np.float32), 0.05, (0.0, 0.0)))\n"
        "print('matplotlib' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def _pillow(rgba: np.ndarray) -> bytes:
    """What Pillow's own writer gives the whole image, with the chunks write_png adds."""
    from PIL import Image, PngImagePlugin

    h, w = rgba.shape[:2]
    image = Image.frombuffer("RGBA", (w, h), np.ascontiguousarray(rgba), "raw", "RGBA", 0, 1)
    info = PngImagePlugin.PngInfo()
    software = png._imsave_software()
    if software is not None:
        info.add_text("Software", software)
    buf = io.BytesIO()
    image.save(buf, format="png", pnginfo=info, dpi=(100, 100))
    return buf.getvalue()


def _banded(rgba: np.ndarray, rows: int) -> bytes:
    buf = io.BytesIO()
    png.write_png_bands(buf, rgba.shape[1], rgba.shape[0], (rgba[r:r + rows] for r in range(0, len(rgba), rows)))
    return buf.getvalue()


def _streaming_cases() -> list[np.ndarray]:
    rng = np.random.default_rng(5)
    sparse = (rng.random((300, 400)) < 0.02).astype(np.uint8)[..., None].repeat(4, axis=2) * 200
    walls = png.grey_rgba(1.0 - 1.0 / (1.0 + np.exp(-np.repeat(rng.normal(0, 3, (60, 90)), 4, axis=0))))
    return [
        rng.integers(0, 256, (200, 300, 4), dtype=np.uint8),  # noise: the deflate stream spans several IDAT chunks
        rng.integers(0, 256, (3, 20000, 4), dtype=np.uint8),  # wider than 16384 px: Pillow's chunks are 4 x width
        np.zeros((5, 7, 4), dtype=np.uint8),  # zero rows: no filter tried
        sparse,  # long runs: every filter wins somewhere
        walls,  # rows repeated four times: up filters to zeros
    ]


@pytest.mark.parametrize("case", range(len(_streaming_cases())))
@pytest.mark.parametrize("rows", [1, 7, 64, 100000])
def test_png_written_band_by_band_is_byte_identical_to_pillow_whole(case, rows):
    rgba = _streaming_cases()[case]
    assert _banded(rgba, rows) == _pillow(rgba)


def test_png_filters_and_chunks_are_pillows():
    """The noise case really uses several IDAT chunks and every filter Pillow tries (a check
    that the cases above test what they say)."""
    import struct
    import zlib

    def parse(b: bytes):
        at, kinds, data = 8, [], b""
        while at < len(b):
            (n,) = struct.unpack(">I", b[at:at + 4])
            kinds.append((b[at + 4:at + 8], n))
            if b[at + 4:at + 8] == b"IDAT":
                data += b[at + 8:at + 8 + n]
            at += 12 + n
        return kinds, zlib.decompress(data)

    noise = _streaming_cases()[0]
    kinds, raw = parse(_banded(noise, 64))
    assert [n for k, n in kinds if k == b"IDAT"][:3] == [65536, 65536, 65536]
    assert set(np.frombuffer(raw, dtype=np.uint8)[::300 * 4 + 1].tolist()) == {0, 1, 2, 4}


def test_map_png_bands_give_the_whole_maps_png():
    """write_map's map.png, band by band, is what imsave gave for the whole map."""
    from slamlab.artifacts import BAND_ROWS, map_png_bands, occupancy_probability

    log_odds = np.random.default_rng(2).normal(0.0, 3.0, (2 * BAND_ROWS + 13, 70)).astype(np.float32)
    buf = io.BytesIO()
    png.write_png_bands(buf, 70, len(log_odds), map_png_bands(log_odds))
    values = np.flipud(1.0 - occupancy_probability(log_odds))
    assert buf.getvalue() == _imsave(values, cmap="gray", vmin=0.0, vmax=1.0)


def test_png_bands_of_the_wrong_size_are_refused():
    rgba = np.zeros((4, 5, 4), dtype=np.uint8)
    with pytest.raises(ValueError, match="rows"):
        png.write_png_bands(io.BytesIO(), 5, 5, [rgba])
    with pytest.raises(ValueError, match="shape"):
        png.write_png_bands(io.BytesIO(), 6, 4, [rgba])


def test_png_of_no_pixels_or_of_other_than_bytes_is_refused():
    with pytest.raises(ValueError, match="at least one pixel"):
        png.write_png_bands(io.BytesIO(), 0, 3, [])
    with pytest.raises(ValueError, match="uint8"):
        png.write_png_bands(io.BytesIO(), 5, 4, [np.zeros((4, 5, 4), dtype=np.float32)])
    with pytest.raises(ValueError, match="more than"):
        png.write_png_bands(io.BytesIO(), 5, 3, [np.zeros((2, 5, 4), dtype=np.uint8)] * 2)
