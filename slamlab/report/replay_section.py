"""The run report's replay: a slider over the snapshots in `replay.npz` (slamlab.slam.replay).

Each snapshot becomes one small greyscale PNG of the map at that moment, all drawn on the
same window (the final map's observed area plus the SLAM path), so frames line up when
scrubbing. Particles, the current scan, the best path so far and the N_eff curve are drawn
over it in the browser (a canvas) from a few kB of JSON, which keeps the page small: about
100 frames of ~5-20 kB each.
"""

from __future__ import annotations

import base64
import io
import json
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from slamlab.eval.trajectory import sample_onto
from slamlab.frames import GridImage
from slamlab.io.rundir import RunFile
from slamlab.report.rundir import RunDir, Trajectory
from slamlab.numeric import evenly_spaced

FRAME_PX = 640  # longest side of a replay frame (pixels)
MAX_PATH_POINTS = 3000
MAX_CURVE_POINTS = 1200
FRAMES_BUDGET_BYTES = 4_000_000  # the frames' share of the 8 MB page budget


@dataclass(frozen=True, slots=True)
class ReplaySection:
    """What run.html needs: the frames as data URIs and the overlay data as JSON text."""

    frames: list[str]
    data_json: str
    width: int
    height: int
    count: int


def _png_uri(grey: np.ndarray) -> str:
    from PIL import Image

    buf = io.BytesIO()
    # zlib's default level, not `optimize`: on Intel's 100 frames (encoded alone, one thread)
    # optimize took 2.3 s of CPU against 0.35 s, the report's largest cost, for frames 5.7 %
    # smaller (1.33 MB against 1.41 MB); the whole replay section: 3.1 -> 1.15 s CPU
    Image.fromarray(grey, mode="L").save(buf, format="PNG")
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _window(extent: np.ndarray, path: Trajectory | None, margin_m: float = 1.0) -> tuple[float, float, float, float]:
    """(x0, x1, y0, y1) m: the final snapshot's map and the SLAM path, plus a margin."""
    x0, x1, y0, y1 = (float(v) for v in extent)
    if path is not None and len(path):
        x0, x1 = min(x0, float(path.xy[:, 0].min())), max(x1, float(path.xy[:, 0].max()))
        y0, y1 = min(y0, float(path.xy[:, 1].min())), max(y1, float(path.xy[:, 1].max()))
    return x0 - margin_m, x1 + margin_m, y0 - margin_m, y1 + margin_m


def frame_image(pixels: np.ndarray, extent: np.ndarray, window: tuple[float, float, float, float], w: int, h: int) -> np.ndarray:
    """A snapshot map (uint8, row 0 = lowest y, square cells covering `extent`) sampled at
    the centres of a w x h image of `window` (row 0 = top, as images are stored); unknown
    grey outside the snapshot."""
    ex0, ex1, ey0, _ = (float(v) for v in extent)
    src = GridImage(pixels, (ex1 - ex0) / pixels.shape[1], (ex0, ey0))
    dst = GridImage(np.zeros((h, w)), (window[1] - window[0]) / w, (window[0], window[2]))
    values = sample_onto(src, dst)
    return np.flipud(np.where(np.isnan(values), 128, values)).astype(np.uint8)


def replay_section(run: RunDir) -> ReplaySection | None:
    """The replay of a run with replay.npz (record.replay), or None."""
    z = run.files.read_arrays(RunFile.REPLAY)
    if z is None:
        return None
    shapes, extents, counts = z["map_shape"], z["map_extent"], z["scan_count"]
    if not len(shapes):
        return None
    best_path = run.load_trajectory("causal") or run.load_trajectory("slam")
    window = _window(extents[-1], best_path)
    span = max(window[1] - window[0], window[3] - window[2])
    w = max(1, int(round(FRAME_PX * (window[1] - window[0]) / span)))
    h = max(1, int(round(FRAME_PX * (window[3] - window[2]) / span)))
    window = (window[0], window[1], window[2], window[2] + h * (window[1] - window[0]) / w)  # square pixels

    snaps = []
    pix_at = np.concatenate([[0], np.cumsum(shapes[:, 0] * shapes[:, 1])])
    scan_at = np.concatenate([[0], np.cumsum(counts)])

    def frame(i: int) -> str:
        pixels = z["map_pixels"][pix_at[i]:pix_at[i + 1]].reshape(int(shapes[i, 0]), int(shapes[i, 1]))
        return _png_uri(frame_image(pixels, extents[i], window, w, h))

    # a building's 100 frames take seconds to encode; Pillow's encoder lets go of the GIL
    with ThreadPoolExecutor(max_workers=min(4, os.cpu_count() or 1)) as pool:
        frames = list(pool.map(frame, range(len(shapes))))
    for i in range(len(shapes)):
        best = int(z["best"][i])
        snaps.append({
            "t": round(float(z["t"][i] - z["t"][0]), 2),
            "step": int(z["step"][i]),
            "scan": int(z["scan_index"][i]),
            "particles": np.round(z["poses"][i][:, :2], 2).tolist(),
            "pose": np.round(z["poses"][i][best], 3).tolist(),
            "points": np.round(z["scan_xy"][scan_at[i]:scan_at[i + 1]], 2).tolist(),
        })
    size = sum(len(f) for f in frames)
    if size > FRAMES_BUDGET_BYTES:  # a huge, detailed map: fewer snapshots, never a page over budget
        every = int(np.ceil(size / FRAMES_BUDGET_BYTES))
        keep = sorted(set(range(0, len(frames), every)) | {len(frames) - 1})
        frames, snaps = [frames[i] for i in keep], [snaps[i] for i in keep]

    data: dict = {"window": window, "w": w, "h": h, "snaps": snaps, "t0": float(z["t"][0]),
                  "scale": scale_bar((window[1] - window[0]) / w)}
    if best_path is not None:
        keep = evenly_spaced(len(best_path), MAX_PATH_POINTS)
        data["path"] = {"t": np.round(best_path.t[keep] - z["t"][0], 3).tolist(), "xy": np.round(best_path.xy[keep], 2).tolist()}
    steps = run.load_steps()
    if steps is not None and "neff" in steps and len(steps):
        keep = evenly_spaced(len(steps), MAX_CURVE_POINTS)
        t = np.asarray(steps["t"], float) - z["t"][0] if "t" in steps else np.arange(len(steps), dtype=float)
        data["neff"] = {"t": np.round(t[keep], 2).tolist(), "v": np.round(np.asarray(steps["neff"], float)[keep], 2).tolist(),
                        "n": run.particles or float(np.nanmax(steps["neff"]))}
    return ReplaySection(frames=frames, data_json=json.dumps(data, separators=(",", ":")), width=w, height=h, count=len(frames))


def scale_bar(m_per_px: float, target_px: float = 110.0) -> dict[str, float]:
    """The replay's scale bar: a round length (1, 2 or 5 x 10^k m) about `target_px` long at
    `m_per_px`, as {"m": length, "px": its pixels}."""
    want = target_px * m_per_px
    k = 10.0 ** np.floor(np.log10(want))
    m = min((f * k for f in (1.0, 2.0, 5.0, 10.0)), key=lambda v: abs(np.log(v / want)))
    return {"m": float(f"{m:.6g}"), "px": round(m / m_per_px, 2)}


def replay_size_bytes(section: ReplaySection) -> int:
    """Bytes the replay adds to the page (frames + JSON), for tests and notes."""
    return sum(len(f) for f in section.frames) + len(section.data_json)


__all__ = ["ReplaySection", "frame_image", "replay_section", "replay_size_bytes"]
