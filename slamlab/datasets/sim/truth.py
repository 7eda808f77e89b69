"""Ground truth files written beside a simulated sequence (folder `truth/`), and reading
them back into a `GroundTruth`.

- `trajectory.tum`: true body pose at every scan time, TUM `t x y z qx qy qz qw` (planar:
  z = 0 and a yaw-only quaternion, like slamlab's own trajectory files).
- `occupancy.png` + `occupancy.yaml`: walls and tall clutter, ROS map_server convention
  (image row 0 = highest y, black 0 = occupied, 254 = free; `origin` = world x, y of the
  lower-left pixel corner).
- `floor_texture.png` + `floor_texture.yaml`: the floor's colours, same image convention.
- `ground_labels.npz`: for a sample of depth frames, key `frame_<k>` (k = 0-based RGB-D
  frame index) -> bool (H, W), un-mirrored, True where the depth pixel sees the floor.
- `body_states.npz`: t (Unix s), pose (x m, y m, theta rad unwrapped), roll, pitch, neck_yaw,
  head_pitch (rad) at scan times; `body_states_joint.npz`: the same at the joint samples.

Every writer here is deterministic (no timestamps in PNG or zip headers), so a simulated
sequence is byte-identical for the same seed.
"""

from __future__ import annotations

import io
import zipfile
from pathlib import Path

import numpy as np
from PIL import Image  # Pillow: a matplotlib dependency

from slamlab.errors import DataError
from slamlab.frames import GridImage, GroundTruth
from slamlab.io.tum import read_tum

TRUTH_DIR = "truth"
TRAJECTORY_FILE = "trajectory.tum"
OCCUPANCY_FILE = "occupancy.png"
TEXTURE_FILE = "floor_texture.png"
LABELS_FILE = "ground_labels.npz"
STATES_FILE = "body_states.npz"
JOINT_STATES_FILE = "body_states_joint.npz"
_ZIP_DATE = (1980, 1, 1, 0, 0, 0)


def _yaml(path: Path, image: str, grid: GridImage, extra: str = "") -> None:
    path.write_text(
        f"image: {image}\nresolution: {grid.resolution_m!r}\norigin: [{grid.origin_xy[0]!r}, {grid.origin_xy[1]!r}, 0.0]\n{extra}"
    )


def _read_yaml(path: Path) -> tuple[float, tuple[float, float]]:
    # A two-key subset of YAML written by `_yaml`; parsed by hand to avoid a yaml dependency.
    vals: dict[str, str] = {}
    try:
        for line in path.read_text().splitlines():
            if ":" in line:
                k, v = line.split(":", 1)
                vals[k.strip()] = v.strip()
        res = float(vals["resolution"])
        ox, oy = (float(s) for s in vals["origin"].strip("[]").split(",")[:2])
    except (OSError, KeyError, ValueError) as exc:
        raise DataError(path, f"cannot read map metadata ({exc.__class__.__name__}: {exc})") from None
    return res, (ox, oy)


def write_grid_png(folder: Path, name: str, grid: GridImage) -> None:
    """A GridImage as `name` (.png, row 0 = highest y) + `.yaml` with resolution/origin."""
    if grid.data.dtype == bool:
        img = np.where(grid.data, 0, 254).astype(np.uint8)  # map_server: dark = occupied
        extra = "negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n"
    else:
        img = grid.data
        extra = ""
    Image.fromarray(np.ascontiguousarray(img[::-1])).save(folder / name, optimize=False)
    _yaml(folder / (Path(name).stem + ".yaml"), name, grid, extra)


def read_grid_png(folder: Path, name: str, as_bool: bool) -> GridImage:
    """Inverse of `write_grid_png` (bool grids: True = occupied)."""
    path = folder / name
    try:
        img = np.asarray(Image.open(path))
    except OSError as exc:
        raise DataError(path, f"cannot read image ({exc})") from None
    res, origin = _read_yaml(folder / (Path(name).stem + ".yaml"))
    data = img[::-1]
    if as_bool:
        data = data < 128
    return GridImage(data=np.ascontiguousarray(data), resolution_m=res, origin_xy=origin)


def write_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """np.savez_compressed without the wall-clock timestamps numpy puts in the zip headers."""
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for key in sorted(arrays):
            buf = io.BytesIO()
            np.lib.format.write_array(buf, np.ascontiguousarray(arrays[key]), allow_pickle=False)
            info = zipfile.ZipInfo(key + ".npy", date_time=_ZIP_DATE)
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            zf.writestr(info, buf.getvalue())


def load_ground_truth(root: str | Path) -> GroundTruth:
    """Read `root/truth/` into a GroundTruth (poses at scan times, occupancy, floor texture,
    ground labels keyed by RGB-D frame index)."""
    folder = Path(root) / TRUTH_DIR
    if not folder.is_dir():
        raise DataError(folder, "simulated ground truth folder is missing")
    _, poses = read_tum(folder / TRAJECTORY_FILE)  # slamlab.io.tum
    occ = read_grid_png(folder, OCCUPANCY_FILE, as_bool=True)
    tex = read_grid_png(folder, TEXTURE_FILE, as_bool=False)
    labels: dict[int, np.ndarray] = {}
    lp = folder / LABELS_FILE
    if lp.is_file():
        with np.load(lp) as z:
            labels = {int(k.split("_")[1]): z[k].astype(bool) for k in z.files}
    return GroundTruth(poses=poses, occupancy=occ, floor_texture=tex, ground_labels=labels)
