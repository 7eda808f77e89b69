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
    ]


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
