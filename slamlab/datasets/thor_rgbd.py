"""Stream THOR Kinect v2 frames (`DEPTH_K.mat`, `RGB_K_j.mat`) as RGBDFrames.

A full sequence is several GB (each `RGB_K_j.mat` holds 300 frames of 1920x1080x3), so
frames are never all held in memory. Instead of `scipy.io.loadmat` (which materialises a
whole file), a small MAT v5 reader here walks the file's cell array record by record:

- opening a sequence reads only the small metadata fields of every frame (time, head
  angles, odometry, IMU); the image field is skipped (a seek for uncompressed files, a
  discarded decompression for MATLAB v7 compressed ones);
- iterating reads one depth frame and the one colour frame paired with it at a time, so
  memory is bounded by about one depth + one colour image, whatever the file sizes.

Each record is the 1x1 struct `loadmat(f)['DEPTH'][0][k][0][0]` with 16 fields read by
position: `t, width, imu_rpy, id, odom, head_angles, c, sz, vel, rsz, body_height, tr, bpp,
name, height` and then `depth` (HxW mm) or `image` (HxWx3 uint8), stored mirrored left-right.
Each depth frame is paired with the colour frame nearest in time (both streams must be
time-ordered); a frame without colour within `max_pair_gap_s` gets `rgb=None`.
"""

from __future__ import annotations

import re
import warnings
import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import numpy as np

from slamlab import robot
from slamlab.datasets.stamps import nearest_index
from slamlab.errors import DataError
from slamlab.frames import KINECT_MAX_DEPTH_M, KINECT_MIN_DEPTH_M, RGBDFrame

__all__ = ["open_rgbd", "RGBDStream", "iter_struct_cell", "DEPTH_MIN_MM", "DEPTH_MAX_MM"]

DEPTH_MIN_MM = round(KINECT_MIN_DEPTH_M * 1000)  # Kinect v2 valid range (THOR_FORMAT.md: about 400..4500 mm)
DEPTH_MAX_MM = round(KINECT_MAX_DEPTH_M * 1000)
MAX_PAIR_GAP_S = 0.25  # colour further than this from a depth frame is not its colour
N_FIELDS = 16
F_T, F_IMU_RPY, F_ODOM, F_HEAD, F_DATA = 0, 2, 4, 5, 15  # field positions (THOR_FORMAT.md)

# ----------------------------------------------------------------------- MAT v5 reading
# Level 5 MAT-File Format (MathWorks): a 128-byte header, then data elements, each an
# 8-byte tag (type, byte count) or a 4-byte "small element" tag, data padded to 8 bytes.
# miCOMPRESSED elements hold a zlib stream of one miMATRIX element.

_MI_DTYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 9: "f8", 12: "i8", 13: "u8", 16: "u1", 17: "u2", 18: "u4"}
_MX_DTYPES = {6: "f8", 7: "f4", 8: "i1", 9: "u1", 10: "i2", 11: "u2", 12: "i4", 13: "u4", 14: "i8", 15: "u8"}
_MI_MATRIX, _MI_COMPRESSED = 14, 15
_MX_CELL, _MX_STRUCT, _MX_CHAR = 1, 2, 4
_CHUNK = 1 << 20


class _MatFormatError(Exception):
    pass


class _FileSource:
    """Reads a byte range of an uncompressed file; skipping is a seek (free)."""

    def __init__(self, f: BinaryIO, size: int):
        self.f, self.pos, self.size = f, 0, size

    def read(self, n: int) -> bytes:
        if self.pos + n > self.size:
            raise EOFError
        b = self.f.read(n)
        if len(b) != n:
            raise EOFError
        self.pos += n
        return b

    def skip(self, n: int) -> None:
        if self.pos + n > self.size:
            raise EOFError
        self.f.seek(n, 1)
        self.pos += n


class _ZlibSource:
    """Reads a miCOMPRESSED element incrementally; memory stays about one request."""

    def __init__(self, f: BinaryIO, nbytes: int):
        self.f, self.remaining, self.pos = f, nbytes, 0
        self.d = zlib.decompressobj()
        self.buf = bytearray()

    def _fill(self, n: int) -> None:
        while len(self.buf) < n:
            if self.d.unconsumed_tail:
                data = self.d.unconsumed_tail
            elif self.remaining > 0 and not self.d.eof:
                data = self.f.read(min(_CHUNK, self.remaining))
                if not data:
                    raise EOFError
                self.remaining -= len(data)
            else:
                raise EOFError
            self.buf += self.d.decompress(data, max(n - len(self.buf), _CHUNK))

    def read(self, n: int) -> bytes:
        self._fill(n)
        out = bytes(self.buf[:n])
        del self.buf[:n]
        self.pos += n
        return out

    def skip(self, n: int) -> None:
        while n > 0:
            k = min(n, _CHUNK)
            self.read(k)
            n -= k


class _Reader:
    def __init__(self, src: _FileSource | _ZlibSource, endian: str):
        self.src, self.e = src, endian

    def tag(self) -> tuple[int, int, bytes | None]:
        b = self.src.read(8)
        word = int.from_bytes(b[:4], self.e_name)
        if word >> 16:  # small data element: size in the upper 2 bytes, data in the tag
            n = word >> 16
            if n > 4:
                raise _MatFormatError("bad small element")
            return word & 0xFFFF, n, b[4 : 4 + n]
        return word, int.from_bytes(b[4:], self.e_name), None

    @property
    def e_name(self) -> str:
        return "little" if self.e == "<" else "big"

    def data(self) -> tuple[int, bytes]:
        typ, n, small = self.tag()
        if small is not None:
            return typ, small
        b = self.src.read(n)
        self.src.skip((-n) % 8)
        return typ, b

    def array(self, typ: int, b: bytes) -> np.ndarray:
        if typ not in _MI_DTYPES:
            raise _MatFormatError(f"unknown data type {typ}")
        return np.frombuffer(b, dtype=self.e + _MI_DTYPES[typ])

    def matrix(self, skip: bool = False) -> object:
        """One miMATRIX element: numeric -> ndarray (MATLAB shape), char -> str,
        1x1 struct -> dict (field order kept), other struct/cell -> object ndarray."""
        typ, n, _ = self.tag()
        if typ != _MI_MATRIX:
            raise _MatFormatError(f"expected a matrix element, got type {typ}")
        if skip:
            self.src.skip(n)
            return None
        if n == 0:
            return np.empty((0, 0))
        end = self.src.pos + n
        value = self._matrix_body()
        if self.src.pos < end:  # parts we do not interpret (e.g. sparse, objects)
            self.src.skip(end - self.src.pos)
        return value

    def header(self) -> tuple[int, int, tuple[int, ...], str]:
        _, flags_b = self.data()
        flags = int(self.array(6, flags_b)[0]) if len(flags_b) >= 4 else 0
        _, dims_b = self.data()
        dims = tuple(int(d) for d in self.array(5, dims_b))
        _, name_b = self.data()
        return flags & 0xFF, flags, dims, name_b.decode("latin1")

    def _matrix_body(self) -> object:
        cls, flags, dims, _name = self.header()
        count = int(np.prod(dims)) if dims else 0
        if cls == _MX_CELL:
            out = np.empty(count, dtype=object)
            for k in range(count):
                out[k] = self.matrix()
            return out.reshape(dims, order="F")
        if cls == _MX_STRUCT:
            names = self.struct_names()
            elems = [{nm: self.matrix() for nm in names} for _ in range(count)]
            if count == 1:
                return elems[0]
            out = np.empty(count, dtype=object)
            out[:] = elems
            return out.reshape(dims, order="F")
        if cls == _MX_CHAR:
            typ, b = self.data()
            codes = self.array(typ, b)
            return "".join(map(chr, codes))  # rows of a char matrix are concatenated
        if cls in _MX_DTYPES:
            typ, b = self.data()
            arr = self.array(typ, b).astype(_MX_DTYPES[cls], copy=False)  # no copy when stored as its class
            if flags & 0x0800:  # complex
                typ_i, b_i = self.data()
                arr = arr + 1j * self.array(typ_i, b_i)
            if flags & 0x0200:  # logical
                arr = arr.astype(bool)
            if arr.size != count:
                raise _MatFormatError(f"array holds {arr.size} values, dims say {dims}")
            return arr.reshape(dims, order="F")
        return None  # sparse/object classes: skipped by the caller

    def struct_names(self) -> list[str]:
        _, fl_b = self.data()
        fl = int(self.array(5, fl_b)[0])
        _, names_b = self.data()
        if fl <= 0:
            return []
        return [names_b[i : i + fl].split(b"\0", 1)[0].decode("latin1") for i in range(0, len(names_b), fl)]


def iter_struct_cell(
    path: str | Path,
    varname: str,
    want_last: Callable[[int], bool] = lambda k: True,
) -> Iterator[dict[str, object]]:
    """Stream a MATLAB cell of 1x1 structs, record by record, from a v5/v7 .mat file.

    Yields one dict per cell element (field name -> value, in file order), the same values
    `loadmat(path)[varname][0][k][0][0]` holds: numeric fields as arrays in MATLAB shape,
    strings as str. The LAST field (the image) of record k is read only if `want_last(k)`,
    else skipped and left out of the dict. Raises DataError on a missing variable or a
    truncated/corrupt file (naming the record).
    """
    path = Path(path)
    if not path.is_file():
        raise DataError(path, "file not found")
    k = -1
    with path.open("rb") as f:
        size = f.seek(0, 2)
        f.seek(0)
        hdr = f.read(128)
        if hdr.startswith(b"MATLAB 7.3"):
            raise DataError(path, "MATLAB v7.3 (HDF5) files are not supported: re-save with save(..., '-v7')")
        if len(hdr) < 128 or hdr[126:128] not in (b"IM", b"MI"):
            raise DataError(path, "not a MATLAB v5/v7 .mat file (bad header)")
        endian = "<" if hdr[126:128] == b"IM" else ">"
        pos = 128
        try:
            while pos + 8 <= size:
                f.seek(pos)
                tag = f.read(8)
                typ = int.from_bytes(tag[:4], "little" if endian == "<" else "big")
                n = int.from_bytes(tag[4:], "little" if endian == "<" else "big")
                nxt = pos + 8 + n + (0 if typ == _MI_COMPRESSED else (-n) % 8)
                head = None
                if typ == _MI_COMPRESSED:
                    r = _Reader(_ZlibSource(f, n), endian)
                    inner_typ, _, _ = r.tag()  # the zlib stream holds one miMATRIX element
                    if inner_typ == _MI_MATRIX:
                        head = r.header()
                elif typ == _MI_MATRIX and n > 0:
                    r = _Reader(_FileSource(f, n), endian)
                    head = r.header()
                if head is None or head[3] != varname:
                    pos = nxt  # another variable: skipped without decompressing it
                    continue
                cls, _flags, dims, _ = head
                if cls != _MX_CELL:
                    raise DataError(path, f"expected a cell array of structs (class {cls})", field=varname)
                count = int(np.prod(dims)) if dims else 0
                for k in range(count):
                    etyp, en, _ = r.tag()
                    if etyp != _MI_MATRIX:
                        raise _MatFormatError(f"cell element of type {etyp}")
                    if en == 0:
                        raise DataError(path, "is empty, expected a 1x1 struct", record=f"frame {k}")
                    ecls, _, edims, _ = r.header()
                    if ecls != _MX_STRUCT or int(np.prod(edims)) != 1:
                        raise DataError(path, f"is not a 1x1 struct (class {ecls}, dims {edims})", record=f"frame {k}")
                    names = r.struct_names()
                    rec: dict[str, object] = {}
                    for i, nm in enumerate(names):
                        last = i == len(names) - 1
                        value = r.matrix(skip=last and not want_last(k))
                        if value is not None or not last:
                            rec[nm] = value
                    yield rec
                return
        except (EOFError, _MatFormatError, zlib.error, ValueError) as exc:
            where = f"frame {k}" if k >= 0 else None
            raise DataError(path, f"truncated or corrupt .mat file ({exc.__class__.__name__}: {exc})", record=where) from None
    raise DataError(path, "variable missing", field=varname)


# ----------------------------------------------------------------------- Kinect frames


@dataclass
class _KinectIndex:
    """Metadata of every frame of one stream (no images): times s, head angles rad
    (neck yaw, head pitch), odometry (x m, y m, theta rad), IMU roll/pitch/yaw rad; and
    (file, record-in-file) of each frame."""

    t: np.ndarray
    head: np.ndarray
    odom: np.ndarray
    rpy: np.ndarray
    file_of: np.ndarray
    rec_of: np.ndarray


def _vec(rec_values: list, pos: int, size: int, path: Path, k: int, names: list[str]) -> np.ndarray:
    try:
        a = np.asarray(rec_values[pos], dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        a = np.empty(0)
    if a.size != size or not np.all(np.isfinite(a)):
        raise DataError(path, f"expected {size} finite numbers, got {rec_values[pos]!r:.60}", record=f"frame {k}", field=names[pos])
    return a


def _index_files(paths: list[Path], varname: str) -> _KinectIndex:
    t, head, odom, rpy, file_of, rec_of = [], [], [], [], [], []
    for fi, path in enumerate(paths):
        n_here = 0
        for k, rec in enumerate(iter_struct_cell(path, varname, want_last=lambda k: False)):
            names = list(rec.keys())
            vals = list(rec.values())
            if len(names) != N_FIELDS - 1:  # the last (image) field was skipped
                raise DataError(path, f"has {len(names) + 1} fields, expected {N_FIELDS} (t, width, imu_rpy, id, odom, head_angles, ..., {'depth' if varname == 'DEPTH' else 'image'})", record=f"frame {k}")
            t.append(_vec(vals, F_T, 1, path, k, names)[0])
            rpy.append(_vec(vals, F_IMU_RPY, 3, path, k, names))
            odom.append(_vec(vals, F_ODOM, 3, path, k, names))
            head.append(_vec(vals, F_HEAD, 2, path, k, names))
            file_of.append(fi)
            rec_of.append(k)
            n_here += 1
        if n_here == 0:
            raise DataError(path, "holds no frames", field=varname)
    idx = _KinectIndex(np.array(t), np.array(head).reshape(-1, 2), np.array(odom).reshape(-1, 3), np.array(rpy).reshape(-1, 3), np.array(file_of, dtype=int), np.array(rec_of, dtype=int))
    back = np.flatnonzero(np.diff(idx.t) < 0)
    if back.size:
        i = int(back[0]) + 1
        raise DataError(paths[idx.file_of[i]], f"time steps back from {idx.t[i - 1]:.6f} to {idx.t[i]:.6f} s (frames must be time-ordered to be paired)", record=f"frame {idx.rec_of[i]}", field="t")
    return idx


def _rgb_files(root: Path, sequence: int) -> list[Path]:
    """`RGB_{sequence}_{j}.mat` sorted by j; j must run 1, 2, ... without gaps."""
    pat = re.compile(rf"RGB_{sequence}_(\d+)\.mat$")
    found = {int(m.group(1)): p for p in root.iterdir() if (m := pat.match(p.name))}
    if not found:
        return []
    js = sorted(found)
    for want, j in enumerate(js, start=1):
        if j != want:
            raise DataError(root / f"RGB_{sequence}_{want}.mat", f"file not found but RGB_{sequence}_{j}.mat exists (colour files must be numbered 1, 2, ... without gaps)")
    return [found[j] for j in js]


class RGBDStream:
    """A zero-argument callable returning a fresh iterator of RGBDFrames (file order).

    `count` depth frames; `files` the DEPTH file then the RGB files in j order;
    `rgb_index[k]` the global colour frame paired with depth frame k (-1: none).
    """

    def __init__(self, depth_path: Path, rgb_paths: list[Path], depth: _KinectIndex, rgb: _KinectIndex | None, rgb_index: np.ndarray):
        self.depth_path, self.rgb_paths = depth_path, rgb_paths
        self.files = [depth_path, *rgb_paths]
        self.count = int(depth.t.size)
        self._depth, self._rgb, self.rgb_index = depth, rgb, rgb_index

    def __call__(self) -> Iterator[RGBDFrame]:
        return self._frames()

    def _rgb_images(self) -> Iterator[tuple[int, np.ndarray]]:
        """(global colour index, un-mirrored image) for the paired colour frames, streaming
        one RGB file after the other and reading only the images that are needed."""
        assert self._rgb is not None
        needed = set(int(i) for i in self.rgb_index if i >= 0)
        base = 0
        for fi, path in enumerate(self.rgb_paths):
            n_here = int(np.count_nonzero(self._rgb.file_of == fi))
            if any(base <= i < base + n_here for i in needed):
                for k, rec in enumerate(iter_struct_cell(path, "RGB", want_last=lambda k, b=base: (b + k) in needed)):
                    if (base + k) in needed:
                        field = list(rec)[-1]
                        img = np.asarray(rec.pop(field))
                        if img.ndim != 3 or img.shape[2] != 3:
                            raise DataError(path, f"expected an HxWx3 image, got shape {img.shape}", record=f"frame {k}", field=field)
                        out = np.ascontiguousarray(np.flip(img.astype(np.uint8, copy=False), 1))  # un-mirror
                        del img, rec  # drop the raw buffer before handing the frame out
                        yield base + k, out
            base += n_here

    def _frames(self) -> Iterator[RGBDFrame]:
        d = self._depth
        rgb_iter = self._rgb_images() if self._rgb is not None else iter(())
        current: tuple[int, np.ndarray] | None = None
        for k, rec in enumerate(iter_struct_cell(self.depth_path, "DEPTH")):
            if k >= self.count:
                break
            field = list(rec)[-1]
            raw = np.asarray(rec.pop(field))
            del rec
            if raw.ndim != 2:
                raise DataError(self.depth_path, f"expected an HxW depth image, got shape {raw.shape}", record=f"frame {k}", field=field)
            mm = np.flip(raw, 1).astype(np.float32)  # un-mirror
            del raw
            ok = (mm >= DEPTH_MIN_MM) & (mm <= DEPTH_MAX_MM)  # also drops NaN
            depth_m = np.where(ok, mm / np.float32(1000.0), np.float32(0.0)).astype(np.float32, copy=False)  # exact-rounded
            del mm, ok
            rgb, rgb_t = None, float("nan")
            want = int(self.rgb_index[k])
            if want >= 0:
                while current is None or current[0] < want:  # colour indices only grow
                    current = next(rgb_iter, None)
                    if current is None:
                        raise DataError(self.rgb_paths[-1], "colour frames changed since the sequence was opened", record=f"frame {want}")
                rgb, rgb_t = current[1], float(self._rgb.t[want])  # type: ignore[union-attr]
            yaw, pitch = float(d.head[k, 0]), float(d.head[k, 1])
            yield RGBDFrame(
                index=k,
                t=float(d.t[k]),
                depth_m=depth_m,
                rgb=rgb,
                rgb_t=rgb_t,
                head_angles=d.head[k].copy(),
                camera_to_body=robot.camera_to_body(yaw, pitch),
                odom=d.odom[k].copy(),
                roll=float(d.rpy[k, 0]),
                pitch=float(d.rpy[k, 1]),
            )


def open_rgbd(root: str | Path, sequence: int, max_pair_gap_s: float = MAX_PAIR_GAP_S) -> RGBDStream | None:
    """Index `root/DEPTH_{sequence}.mat` and `root/RGB_{sequence}_{j}.mat` (metadata only)
    and pair every depth frame with the colour frame nearest in time.

    Returns None when the sequence has no DEPTH file (a warning if colour files exist
    alone). Raises DataError for corrupt files, missing fields, times that step back,
    numbering gaps in the RGB files, or colour that pairs with no depth frame at all.
    """
    root = Path(root)
    depth_path = root / f"DEPTH_{sequence}.mat"
    rgb_paths = _rgb_files(root, sequence)
    if not depth_path.is_file():
        if rgb_paths:
            warnings.warn(f"{root}: RGB_{sequence}_*.mat found but no DEPTH_{sequence}.mat: RGB-D ignored", stacklevel=2)
        return None
    depth = _index_files([depth_path], "DEPTH")
    rgb = _index_files(rgb_paths, "RGB") if rgb_paths else None
    rgb_index = np.full(depth.t.size, -1, dtype=int)
    if rgb is not None:
        near = nearest_index(rgb.t, depth.t)
        ok = np.abs(rgb.t[near] - depth.t) <= max_pair_gap_s
        if not ok.any():
            raise DataError(
                rgb_paths[0],
                f"no colour frame within {max_pair_gap_s} s of any depth frame: depth t {depth.t[0]:.3f}..{depth.t[-1]:.3f}, "
                f"colour t {rgb.t[0]:.3f}..{rgb.t[-1]:.3f} ({depth.t.size} depth, {rgb.t.size} colour frames cannot be paired)",
                field="t",
            )
        if not ok.all():
            warnings.warn(f"{depth_path}: {int((~ok).sum())} of {ok.size} depth frames have no colour frame within {max_pair_gap_s} s (rgb=None)", stacklevel=2)
        rgb_index = np.where(ok, near, -1)
    else:
        warnings.warn(f"{depth_path}: no RGB_{sequence}_*.mat files: depth frames come without colour", stacklevel=2)
    return RGBDStream(depth_path, rgb_paths, depth, rgb, rgb_index)
