"""CARMEN logs (`.clf`, optionally gzip/bzip2/xz compressed) as a `Sequence` of scans.

What is read (everything else is skipped; `ODOM` too unless RAWLASER1 scans need it):
- `FLASER n r1..rn x y theta odom_x odom_y odom_theta ipc_timestamp ipc_hostname logger_timestamp`
  (old front-laser message; `x y theta` is the laser pose, `odom_*` the robot pose).
- `ROBOTLASER1 laser_type start_angle fov angular_res max_range accuracy remission_mode
  n r1..rn m e1..em laser_pose_x laser_pose_y laser_pose_theta robot_pose_x robot_pose_y
  robot_pose_theta tv rv forward_safety_dist side_safety_dist turn_axis ipc_timestamp
  ipc_hostname logger_timestamp` (angles in rad). When a log has both, ROBOTLASER1 wins
  (newer tools write FLASER copies of the same scans) and a warning says so.
- `RAWLASER1 laser_type start_angle fov angular_res max_range accuracy remission_mode n r1..rn
  m e1..em ipc_timestamp ipc_hostname logger_timestamp`: the front laser's raw scans, with
  no pose. Read only when the log has neither of the above; each scan's robot pose is then
  the `ODOM x y theta tv rv accel ipc_timestamp ipc_hostname logger_timestamp` records on
  either side of it in the file, interpolated at its timestamp (the nearer one alone at the
  log's ends or when their clock does not move forward). RAWLASER2-4 (other lasers) are skipped.
- `PARAM name value`: `robot_frontlaser_offset` (m, forward), a front-laser maximum range
  (`robot_front_laser_max`, `robot_frontlaser_max`, `laser_front_laser_max_range`, ...),
  `laser_front_laser_fov` / `laser_front_laser_resolution` (deg, FLASER only).

Conventions, checked on the Intel and ACES logs of the Freiburg benchmark:
- Scans stay in FILE ORDER; `t` is the ipc_timestamp (Intel's clock steps back 631 times).
- `odom` is the robot pose (odom_x, odom_y, odom_theta / robot_pose_*).
- FLASER beam angles follow CARMEN's own reader (readlog.c): the first beam is at -90 deg
  and the step is 1 deg for n = 180 or 181, 0.5 deg for 360/361, 0.25 deg for 400/401,
  otherwise 180 deg / (n - 1). So n = 180 covers -90..+89 deg (the SICK's 181st beam was
  dropped) and n = 181 covers -90..+90 deg. The PARAMs above override fov/resolution.
- `lidar_to_body`: the laser pose minus the robot pose in each record, in the robot frame,
  when the records carry a consistent offset; otherwise `robot_frontlaser_offset` along x.
  Intel and ACES carry no offset (laser pose == robot pose in every record, PARAM 0.0),
  so their mount is the identity.
- No-return readings: ranges at or above the sensor maximum, <= 0, NaN or inf are
  `valid = False`. The maximum is, in order: the `max_range_m` argument; the record's own
  `max_range` (ROBOTLASER1); a max-range PARAM; else detected from the data: the largest
  reading counts as the "no return" value when it is a saturation plateau (>= 0.1 % of all
  readings, at least 2). Intel saturates at 81.83 m (2.8 % of readings), ACES at 50.00 m
  (0.8 %). A log without such a plateau keeps all finite positive readings.
"""

from __future__ import annotations

import builtins
import hashlib
import json
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from slamlab.datasets.bad_lines import BadLines
from slamlab.datasets.relations import DEFAULT_RELATIONS_TOL_S, relations_for_log
from slamlab.errors import DataError
from slamlab.frames import LazyScans, ScanFrame, ScanRows, Sequence, scan_times
from slamlab.geometry import rot_z, se2_between, trans, wrap_angle
from slamlab.io.compressed import read_text
from slamlab.config.datasets import CarmenDatasetConfig

_FLASER_TAIL = (
    "x", "y", "theta", "odom_x", "odom_y", "odom_theta",
    "ipc_timestamp", "ipc_hostname", "logger_timestamp",
)  # fmt: skip
_RL1_HEAD = (
    "laser_type", "start_angle", "fov", "angular_res", "max_range", "accuracy",
    "remission_mode", "num_readings",
)  # fmt: skip
_RL1_TAIL = (
    "laser_pose_x", "laser_pose_y", "laser_pose_theta",
    "robot_pose_x", "robot_pose_y", "robot_pose_theta",
    "tv", "rv", "forward_safety_dist", "side_safety_dist", "turn_axis",
    "ipc_timestamp", "ipc_hostname", "logger_timestamp",
)  # fmt: skip

_RAW_TAIL = ("ipc_timestamp", "ipc_hostname", "logger_timestamp")
_HEADED_TAILS = {"ROBOTLASER1": _RL1_TAIL, "RAWLASER1": _RAW_TAIL}  # the laser messages that share ROBOTLASER1's head
_ODOM_FIELDS = ("message", "x", "y", "theta", "tv", "rv", "accel", "ipc_timestamp", "ipc_hostname", "logger_timestamp")

_MAX_RANGE_PARAM = re.compile(r"^(robot|laser)_front_?laser_max(imum)?(_?range)?$")
_OFFSET_PARAM = "robot_frontlaser_offset"
_FOV_PARAM = "laser_front_laser_fov"
_RES_PARAM = "laser_front_laser_resolution"

# A saturation plateau: the largest reading repeats in at least this share of all readings.
_PLATEAU_FRACTION = 1e-3
# Laser-minus-robot offsets below this (m, rad) are print noise, i.e. "no offset recorded";
# offsets varying more than this across records are not a rigid mount.
_OFFSET_NOISE = 1e-3
_OFFSET_SPREAD = 1e-2


# ----------------------------------------------------------------------------- file access


def _log_stem(path: Path) -> str:
    """`intel.clf.bz2` -> `intel`."""
    name = path.name
    for suffix in (".gz", ".bz2", ".xz"):
        if name.lower().endswith(suffix):
            name = name[: -len(suffix)]
            break
    for suffix in (".clf", ".log"):
        if name.lower().endswith(suffix):
            name = name[: -len(suffix)]
            break
    return name


# ----------------------------------------------------------------------------- log parsing


@dataclass
class _Group:
    """Laser records of one message type and shape, gathered before one numpy conversion."""

    kind: str
    shape: tuple[int, ...]  # (n,) for FLASER, (n, m) for ROBOTLASER1 and RAWLASER1
    linenos: list[int] = field(default_factory=list)
    tokens: list[str] = field(default_factory=list)  # ROBOTLASER1, RAWLASER1: numeric tokens, row-major
    raw: list[str] = field(default_factory=list)  # FLASER: the lines themselves
    values: np.ndarray | None = None  # (L, width) float64 once converted


@dataclass
class _Param:
    value: str
    lineno: int


def _flaser_field(n: int, j: int) -> str:
    """Name of token j of a FLASER line with n readings."""
    if j == 0:
        return "message"
    if j == 1:
        return "num_readings"
    if j < n + 2:
        return f"range[{j - 2}]"
    return _FLASER_TAIL[min(j - n - 2, len(_FLASER_TAIL) - 1)]


def _rl1_field(n: int, m: int, j: int, tail: tuple[str, ...] = _RL1_TAIL) -> str:
    """Name of token j of a ROBOTLASER1 line with n readings and m remissions (of a
    RAWLASER1 line with `tail` = `_RAW_TAIL`: the same head, no poses)."""
    if j == 0:
        return "message"
    if j <= 8:
        return _RL1_HEAD[j - 1]
    if j < 9 + n:
        return f"range[{j - 9}]"
    if j == 9 + n:
        return "num_remissions"
    if j < 10 + n + m:
        return f"remission[{j - 10 - n}]"
    return tail[min(j - 10 - n - m, len(tail) - 1)]





def _count(path: Path, parts: list[str], j: int, name: str, record: str) -> int:
    """A non-negative integer count field (num_readings, num_remissions)."""
    if j >= len(parts):
        raise DataError(path, "missing", record=record, field=name)
    try:
        value = int(parts[j])
    except ValueError:
        raise DataError(path, f"expected a non-negative integer, got {parts[j]!r}", record=record, field=name) from None
    if value < 0:
        raise DataError(path, f"expected a non-negative integer, got {value}", record=record, field=name)
    return value


def _check_length(path: Path, parts: list[str], need: int, record: str, names, counts: str) -> None:
    if len(parts) == need:
        return
    if len(parts) < need:
        raise DataError(path, f"missing: the line has {len(parts)} values but {counts} needs {need}",
                        record=record, field=names(len(parts)))  # fmt: skip
    raise DataError(path, f"followed by {len(parts) - need} unexpected values ({counts} needs {need})",
                    record=record, field=names(need - 1))  # fmt: skip


def _add_headed(path: Path, groups: dict[tuple, _Group], bad: BadLines, parts: list[str], lineno: int) -> None:
    """A ROBOTLASER1 or RAWLASER1 line (`parts`: its tokens) into the group of its kind and
    shape; an unreadable one to `bad`. Both kinds have the same head and ranges and
    remissions; then their own tail (`_HEADED_TAILS`)."""
    kind = parts[0]
    tail = _HEADED_TAILS[kind]
    record = f"line {lineno} ({kind})"
    try:
        n = _count(path, parts, 8, "num_readings", record)
        m = _count(path, parts, 9 + n, "num_remissions", record)
        need = n + m + 10 + len(tail)
        _check_length(path, parts, need, record, lambda j: _rl1_field(n, m, j, tail),
                      f"num_readings={n}, num_remissions={m}")  # fmt: skip
    except DataError as exc:
        bad.add(lineno, exc)
        return
    g = groups.get((kind, n, m))
    if g is None:
        g = groups[(kind, n, m)] = _Group(kind, (n, m))
    g.linenos.append(lineno)
    g.tokens.extend(parts[1 : need - 2])  # every value but the host name, the last but one
    g.tokens.append(parts[need - 1])


def _scan_lines(path: Path, lines: list[str], bad: BadLines) -> tuple[dict[tuple, _Group], dict[str, _Param], list[int]]:
    """One pass over the log: group laser records by shape, collect PARAMs and the line
    numbers of ODOM records; unreadable laser lines go to `bad` (raised, or dropped and
    counted)."""
    groups: dict[tuple, _Group] = {}
    params: dict[str, _Param] = {}
    odom: list[int] = []
    for lineno, line in enumerate(lines, 1):
        first = line[:1]
        if first == "F" and line.startswith("FLASER"):
            # The bulk of a log: only peek at num_readings here, convert per group below.
            head = line.split(None, 2)
            if head[0] != "FLASER":
                continue
            key = ("FLASER", head[1] if len(head) > 1 else "")
            g = groups.get(key)
            if g is None:
                g = groups[key] = _Group("FLASER", ())
            g.linenos.append(lineno)
            g.raw.append(line)
        elif first == "R" and line.startswith(("ROBOTLASER1", "RAWLASER1")):
            parts = line.split()
            if parts[0] in _HEADED_TAILS:
                _add_headed(path, groups, bad, parts, lineno)
        elif first == "O" and line.split(None, 1)[0] == "ODOM":
            odom.append(lineno)
        elif first == "P" and line.startswith("PARAM"):
            parts = line.split()
            if parts[0] == "PARAM" and len(parts) >= 3:
                params[parts[1]] = _Param(parts[2], lineno)
    for g in groups.values():
        if g.kind == "FLASER":
            _convert_flaser(path, lines, g, bad)
    kept = [g for g in groups.values() if g.linenos]  # every line of a group may have been bad
    return {(g.kind, *g.shape, i): g for i, g in enumerate(kept)}, params, odom


def _convert_flaser(path: Path, lines: list[str], g: _Group, bad: BadLines) -> None:
    """Check the shape of a group of FLASER lines sharing one num_readings token and
    convert them in one C-level pass (np.loadtxt); bad lines go to `bad`."""
    try:
        n = _count(path, g.raw[0].split(), 1, "num_readings", f"line {g.linenos[0]} (FLASER)")
    except DataError as exc:  # the group's shared num_readings token: every line of it is bad
        for lineno in g.linenos:
            bad.add(lineno, DataError(path, exc.message, record=f"line {lineno} (FLASER)", field="num_readings"))
        g.linenos, g.raw = [], []
        return
    g.shape = (n,)
    # Token count by counting single spaces (C speed); split only lines spaced unusually.
    spaces = n + 10
    keep = []
    for i, (lineno, line) in enumerate(zip(g.linenos, g.raw)):
        if line.count(" ") != spaces or "  " in line or "\t" in line:
            try:
                _check_length(path, line.split(), n + 11, f"line {lineno} (FLASER)",
                              lambda j: _flaser_field(n, j), f"num_readings={n}")  # fmt: skip
            except DataError as exc:
                bad.add(lineno, exc)
                continue
        keep.append(i)
    _keep_rows(g, keep)
    # ranges, six pose values, ipc_timestamp; skip the host name; logger_timestamp.
    cols = [*range(2, n + 9), n + 10]
    while g.linenos:
        try:
            g.values = np.loadtxt(g.raw, dtype=np.float64, usecols=cols, comments=None, ndmin=2)
            break
        except ValueError as exc:
            _drop_bad_numbers(path, lines, g, str(exc), bad)
    g.raw = []


def _keep_rows(g: _Group, keep: list[int]) -> None:
    """Keep only rows `keep` (indices into the group's lines) of an unconverted group."""
    if len(keep) == len(g.linenos):
        return
    if g.raw:
        g.raw = [g.raw[i] for i in keep]
    if g.tokens:
        width = len(g.tokens) // len(g.linenos)
        g.tokens = [tok for i in keep for tok in g.tokens[i * width : (i + 1) * width]]
    g.linenos = [g.linenos[i] for i in keep]


def _to_numbers(path: Path, lines: list[str], g: _Group, bad: BadLines) -> np.ndarray:
    """The group's values as an (L, width) float64 array; lines that are not numbers go to `bad`."""
    if g.values is not None:
        return g.values
    while g.linenos:
        width = len(g.tokens) // len(g.linenos)
        try:
            return np.array(g.tokens, dtype=np.float64).reshape(len(g.linenos), width)
        except ValueError as exc:
            _drop_bad_numbers(path, lines, g, str(exc), bad)
    return np.zeros((0, 0))


def _drop_bad_numbers(path: Path, lines: list[str], g: _Group, numpy_message: str, bad: BadLines) -> None:
    """Slow path, only for a broken file: re-split the group's lines to name the bad field
    of each bad line, hand them to `bad` and keep the rest."""
    keep = []
    for i, lineno in enumerate(g.linenos):
        parts = lines[lineno - 1].split()
        if g.kind == "FLASER":
            n = g.shape[0]
            idx = [*range(2, n + 9), n + 10]
            names = lambda j: _flaser_field(n, j)  # noqa: E731
        else:
            n, m = g.shape
            tail = _HEADED_TAILS[g.kind]
            need = n + m + 10 + len(tail)
            idx = [*range(1, need - 2), need - 1]
            names = lambda j: _rl1_field(n, m, j, tail)  # noqa: E731
        wrong = next((j for j in idx if not _is_number(parts[j])), None)
        if wrong is None:
            keep.append(i)
        else:
            bad.add(lineno, DataError(path, f"expected a number, got {parts[wrong]!r}",
                                      record=f"line {lineno} ({g.kind})", field=names(wrong)))  # fmt: skip
    if len(keep) < len(g.linenos):
        _keep_rows(g, keep)
        return
    # numpy and float() disagree on some spelling: still say which file and group.
    raise DataError(path, f"cannot read the numbers: {numpy_message}",
                    record=f"lines {g.linenos[0]}-{g.linenos[-1]} ({g.kind})")  # fmt: skip


def _is_number(token: str) -> bool:
    try:
        float(token)
        return True
    except ValueError:
        return False


def _finite_rows(path: Path, g: _Group, values: np.ndarray, names: list[str], bad: BadLines) -> np.ndarray:
    """Rows whose poses and timestamps are finite (ranges may be NaN: those beams become
    invalid); the other rows go to `bad`."""
    wrong = ~np.isfinite(values)
    cells = np.argwhere(wrong)  # row-major: the first cell of each row is its first bad field
    for row, col in cells[np.unique(cells[:, 0], return_index=True)[1]]:
        bad.add(g.linenos[row], DataError(path, f"expected a finite number, got {values[row, col]}",
                                          record=f"line {g.linenos[row]} ({g.kind})", field=names[col]))  # fmt: skip
    return ~wrong.any(axis=1)


def _param_float(path: Path, params: dict[str, _Param], name: str) -> float | None:
    p = params.get(name)
    if p is None:
        return None
    try:
        value = float(p.value)
    except ValueError:
        raise DataError(path, f"expected a number, got {p.value!r}", record=f"line {p.lineno} (PARAM {name})",
                        field="param_value") from None  # fmt: skip
    if not np.isfinite(value):
        raise DataError(path, f"expected a finite number, got {p.value!r}", record=f"line {p.lineno} (PARAM {name})",
                        field="param_value")  # fmt: skip
    return value


def flaser_beam_angles(n: int, fov_deg: float | None = None, resolution_deg: float | None = None) -> np.ndarray:
    """Beam angles (rad, float32, CCW from the laser's +x) of an n-reading FLASER scan.

    CARMEN's convention: the first beam at -fov/2 (default -90 deg), then fixed steps of
    `resolution_deg` (default: 1 deg for n = 180/181, 0.5 for 360/361, 0.25 for 400/401,
    else 180/(n-1)). n = 180 thus spans -90..+89 deg, n = 181 spans -90..+90 deg.
    """
    if resolution_deg is None:
        resolution_deg = {180: 1.0, 181: 1.0, 360: 0.5, 361: 0.5, 400: 0.25, 401: 0.25}.get(n)
        if resolution_deg is None:
            resolution_deg = 180.0 / (n - 1) if n > 1 else 0.0
    start_deg = -0.5 * fov_deg if fov_deg is not None else -90.0
    return np.radians(start_deg + resolution_deg * np.arange(n)).astype(np.float32)


def _detect_no_return(blocks: list[np.ndarray]) -> float | None:
    """The saturation value of a laser (m) over every block of readings, or None when the
    data shows no plateau. Masks only: the readings are not copied (Intel's 2.5 M would be
    20 MB, at the parse's peak)."""
    usable = [np.isfinite(r) & (r > 0) for r in blocks]
    count = sum(int(np.count_nonzero(u)) for u in usable)
    if count == 0:
        return None
    top = max(float(np.max(r, where=u, initial=-np.inf)) for r, u in zip(blocks, usable))
    at_top = sum(int(np.count_nonzero((r >= top) & u)) for r, u in zip(blocks, usable))
    return top if at_top >= max(2, _PLATEAU_FRACTION * count) else None


def _mount(path: Path, laser: np.ndarray, robot: np.ndarray, offset_x: float | None) -> np.ndarray:
    """(4, 4) lidar-to-body transform, read-only, shared by all scans of the log.

    Uses the laser-minus-robot pose of the records when they carry a rigid offset, else
    the PARAM forward offset, else the identity.
    """
    off = se2_between(robot, laser)
    off[:, 2] = wrap_angle(off[:, 2])
    med = np.median(off, axis=0)
    if np.abs(off).max(initial=0.0) < _OFFSET_NOISE:
        T = trans(x=offset_x or 0.0)
    elif np.abs(off - med).max() < _OFFSET_SPREAD:
        T = trans(x=float(med[0]), y=float(med[1])) @ rot_z(float(med[2]))
    else:
        warnings.warn(
            f"{path}: laser and robot poses in the records differ by a varying amount "
            f"(not a rigid mount); using robot_frontlaser_offset = {offset_x or 0.0} m instead",
            stacklevel=4,
        )
        T = trans(x=offset_x or 0.0)
    T.flags.writeable = False
    return T


def _check_file(path: Path) -> None:
    """The errors `read_text` gives for a missing path or a folder (before hashing it)."""
    if not path.exists():
        raise DataError(path, "file not found")
    if not path.is_file():
        raise DataError(path, "not a regular file")


def _readonly(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


def load_carmen(
    path: str | Path,
    relations: str | Path | None = None,
    max_range_m: float | None = None,
    name: str | None = None,
    relations_time_tol_s: float = DEFAULT_RELATIONS_TOL_S,
    on_bad_line: str = CarmenDatasetConfig.on_bad_line,
    cache: bool = False,  # off for direct calls (tests read the parser); dataset=carmen turns it on
) -> Sequence:
    """Load a CARMEN log (`.clf`, `.clf.gz`, `.clf.bz2`, `.clf.xz`) as a `Sequence`.

    path: the log. relations: a relations file (default: `<stem>.relations` beside the log,
    e.g. `intel.clf.bz2` -> `intel.relations`, if it exists). max_range_m: readings at or
    above this (m) mean "no return" (default: the record's max_range, a PARAM, or the
    detected saturation value; see the module docstring). name: the sequence name
    (default: the file stem, `intel`). relations_time_tol_s: each relation stamp is matched
    to the scan nearest in time within this (s; published files may round stamps).
    on_bad_line: `error` stops at an unreadable laser line, `skip` drops it (one warning).
    cache: keep the parsed scans of a log of `CACHE_MIN_BYTES` or more under
    `SLAMLAB_CACHE_DIR/carmen/` (keyed by the file's sha256, the reading options and this
    reader's version) and read them from there next time: the same arrays, bit for bit,
    and the same warnings (the relations file is always read afresh).

    Scans come in file order with `t` = ipc_timestamp (s), `odom` = robot pose
    (m, m, rad), float32 ranges (m) and angles (rad); roll/pitch are 0. Arrays in the
    frames are read-only views into per-log blocks. `Sequence.max_range_m` is the sensor's
    no-return range. Negative, NaN and inf readings become invalid beams and raise one
    warning with their count. Raises DataError (file, line, field) for unreadable input.
    """
    if max_range_m is not None and not (np.isfinite(max_range_m) and max_range_m > 0):
        raise ValueError(f"max_range_m must be a positive number of metres, got {max_range_m}")
    path = Path(path)
    if cache:
        parsed = _parse_log_cached(path, max_range_m, on_bad_line)
    else:
        parsed = _parse_log(path, max_range_m, on_bad_line)
    scans = _frames(parsed)
    times = scan_times(scans)
    rel, rel_path = relations_for_log(path, _log_stem(path), relations, times, relations_time_tol_s)

    sources = [str(path)] + ([str(rel_path)] if rel_path is not None else [])
    seq = Sequence(
        name=name if name is not None else _log_stem(path),
        scans=scans,
        body_height_m=None,
        sources=sources,
        relations=rel,
    )
    if parsed.max_range_m > 0:  # else keep the Sequence default
        seq.max_range_m = parsed.max_range_m
    return seq


@dataclass
class _ScanBlock:
    """The laser records of one shape (message type, readings): L records of n beams, as
    contiguous read-only arrays, and each record's place among all scans in file order."""

    position: np.ndarray  # (L,) int64, index of each record in file order
    t: np.ndarray  # (L,) float64, ipc_timestamp (s)
    odom: np.ndarray  # (L, 3) float64, robot pose (m, m, rad)
    ranges: np.ndarray  # (L, n) float32 (m)
    valid: np.ndarray  # (L, n) bool
    angles: np.ndarray  # (n,) float32 (rad) shared by the records, or (L, n) per record
    mount: np.ndarray  # (4, 4) lidar-to-body transform (m)

    FIELDS = ("position", "t", "odom", "ranges", "valid", "angles", "mount")


@dataclass
class _ParsedLog:
    """What reading a log yields before relations are attached."""

    blocks: list[_ScanBlock]
    max_range_m: float  # the sensor's no-return range (m); 0 when unknown
    warnings: list[tuple[type[Warning], str]] = field(default_factory=list)  # cache only


@dataclass(frozen=True)
class _RecordFrame:
    """Record i of a log as a ScanFrame of views into its block's arrays (a class, not a
    closure, so that a Sequence pickles)."""

    blocks: list[_ScanBlock]
    block_of: np.ndarray  # (N,) record i is row row_of[i] of block block_of[i]
    row_of: np.ndarray
    times: np.ndarray  # (N,) s

    def __call__(self, i: int) -> ScanFrame:
        b = self.blocks[self.block_of[i]]
        k = int(self.row_of[i])
        return ScanFrame(
            index=i,
            t=float(self.times[i]),
            odom=b.odom[k],
            ranges=b.ranges[k],
            angles=b.angles[k] if b.angles.ndim == 2 else b.angles,
            valid=b.valid[k],
            lidar_to_body=b.mount,
        )

    def rows(self, records: np.ndarray) -> ScanRows | None:
        """Records `records` (file order) as `ScanRows` when they are consecutive rows of one
        block whose records share one beam-angle array (views, nothing copied); else None."""
        j = self.block_of[records]
        k = self.row_of[records]
        if len(records) == 0 or not (j == j[0]).all() or not np.array_equal(k, np.arange(k[0], k[0] + len(k))):
            return None
        b = self.blocks[int(j[0])]
        if b.angles.ndim != 1:
            return None
        rows = slice(int(k[0]), int(k[0]) + len(k))
        return ScanRows(ranges=b.ranges[rows], valid=b.valid[rows], angles=b.angles, lidar_to_body=b.mount)


def _frames(parsed: _ParsedLog) -> LazyScans:
    """The records in file order, each ScanFrame made on demand (`LazyScans`)."""
    n = sum(len(b.t) for b in parsed.blocks)
    block_of = np.empty(n, dtype=np.int32)
    row_of = np.empty(n, dtype=np.int64)
    times = np.empty(n)
    odom = np.empty((n, 3))
    for j, b in enumerate(parsed.blocks):
        block_of[b.position] = j
        row_of[b.position] = np.arange(len(b.t))
        times[b.position] = b.t
        odom[b.position] = b.odom
    times.flags.writeable = False
    odom.flags.writeable = False
    return LazyScans(_RecordFrame(parsed.blocks, block_of, row_of, times), np.arange(n), times, odom)


def _odometry_at(path: Path, lines: list[str], odom_lines: list[int], scan_lines: np.ndarray, t: np.ndarray, bad: BadLines) -> np.ndarray:
    """(L, 3) the robot's pose (m, m, rad) at each RAWLASER1 scan (on line `scan_lines`,
    timestamp `t` s): the ODOM records just before and just after it in the file, interpolated
    linearly at its time (the angle along the shorter way round), clamped to the two; the one
    there is at the log's ends, and the earlier one when their timestamps do not increase
    (a clock stepping back: the file's order holds). Unreadable ODOM lines go to `bad`."""
    values, kept = [], []
    for lineno in odom_lines:
        parts = lines[lineno - 1].split()
        record = f"line {lineno} (ODOM)"
        try:
            _check_length(path, parts, len(_ODOM_FIELDS), record, lambda j: _ODOM_FIELDS[min(j, len(_ODOM_FIELDS) - 1)], "ODOM")
            row = []
            for j in (1, 2, 3, 7):
                try:
                    v = float(parts[j])
                except ValueError:
                    raise DataError(path, f"expected a number, got {parts[j]!r}", record=record, field=_ODOM_FIELDS[j]) from None
                if not np.isfinite(v):
                    raise DataError(path, f"expected a finite number, got {parts[j]!r}", record=record, field=_ODOM_FIELDS[j])
                row.append(v)
        except DataError as exc:
            bad.add(lineno, exc)
            continue
        values.append(row)
        kept.append(lineno)
    if not kept:
        raise DataError(path, "RAWLASER1 scans carry no robot pose and no ODOM line of the log could be read",
                        record=f"{len(odom_lines)} ODOM lines")  # fmt: skip
    odom = np.array(values)  # (K, 4): x, y, theta, ipc_timestamp
    after = np.searchsorted(np.asarray(kept), scan_lines)  # the first ODOM record after each scan
    i0 = np.clip(after - 1, 0, len(kept) - 1)  # the one before (the first one for scans before any)
    i1 = np.clip(after, 0, len(kept) - 1)  # the one after (the last one for scans after all)
    t0, t1 = odom[i0, 3], odom[i1, 3]
    with np.errstate(invalid="ignore", divide="ignore"):
        f = np.where(t1 > t0, np.clip((t - t0) / (t1 - t0), 0.0, 1.0), 0.0)
    xy = odom[i0, :2] + f[:, None] * (odom[i1, :2] - odom[i0, :2])
    theta = odom[i0, 2] + f * wrap_angle(odom[i1, 2] - odom[i0, 2])  # a record's own angle as written at its time
    return np.column_stack([xy, theta])


def _parse_log(path: Path, max_range_m: float | None, on_bad_line: str) -> _ParsedLog:
    """Read and check the whole log (see `load_carmen`); warnings are issued as they arise."""
    text = read_text(path)
    # split("\n"), not splitlines(): that also breaks at \x0b, \x0c, \x1c-\x1e and \x85.
    lines = text.split("\n")
    if "\r" in text:
        lines = [line.rstrip("\r") for line in lines]
    del text  # 16 MB for Intel: not held through the parse
    ends_cleanly = not lines or lines[-1] == ""
    if ends_cleanly and lines:
        lines.pop()
    bad = BadLines(path, len(lines), on_bad_line, truncated=not ends_cleanly)
    groups, params, odom_lines = _scan_lines(path, lines, bad)
    for g in groups.values():  # numbers first: in skip mode a group may lose every line here
        g.values = _to_numbers(path, lines, g, bad)
    groups = {k: g for k, g in groups.items() if g.linenos}

    kinds = {key[0] for key in groups}
    if not groups:
        raise DataError(path, "no laser scans (FLASER, ROBOTLASER1 or RAWLASER1 lines) in the log",
                        record=f"{len(lines)} lines read")  # fmt: skip
    if kinds == {"FLASER", "ROBOTLASER1"}:
        n_fl = sum(len(g.linenos) for k, g in groups.items() if k[0] == "FLASER")
        warnings.warn(f"{path}: has ROBOTLASER1 and FLASER scans; using ROBOTLASER1, ignoring {n_fl} FLASER lines",
                      stacklevel=3)  # fmt: skip
        groups = {k: g for k, g in groups.items() if k[0] == "ROBOTLASER1"}
    if "RAWLASER1" in kinds and len(kinds) > 1:  # raw copies of scans the log also has with their poses
        n_raw = sum(len(g.linenos) for k, g in groups.items() if k[0] == "RAWLASER1")
        used = "ROBOTLASER1" if "ROBOTLASER1" in kinds else "FLASER"
        warnings.warn(f"{path}: has {used} and RAWLASER1 scans; using {used}, ignoring {n_raw} RAWLASER1 lines", stacklevel=3)
        groups = {k: g for k, g in groups.items() if k[0] != "RAWLASER1"}
    if "RAWLASER1" in kinds and len(kinds) == 1 and not odom_lines:
        raise DataError(path, "RAWLASER1 scans carry no robot pose and the log has no ODOM lines to take it from",
                        record=f"{len(lines)} lines read")  # fmt: skip

    offset_x = _param_float(path, params, _OFFSET_PARAM)
    fov_deg = _param_float(path, params, _FOV_PARAM)
    res_deg = _param_float(path, params, _RES_PARAM)
    param_max = None
    for pname in params:
        if _MAX_RANGE_PARAM.match(pname):
            param_max = _param_float(path, params, pname)

    # Parse every group first: the saturation value is a property of the whole log.
    parsed = []  # (group, ranges f64 (L, n), laser (L, 3), robot (L, 3), t (L,), record max or None, angles)
    for g in groups.values():
        a = _to_numbers(path, lines, g, bad)
        if g.kind == "FLASER":
            n = g.shape[0]
            keep = _finite_rows(path, g, a[:, n:], [f for f in _FLASER_TAIL if f != "ipc_hostname"], bad)
        else:
            n, m = g.shape
            keep = _finite_rows(path, g, a[:, :8], list(_RL1_HEAD), bad) & _finite_rows(
                path, g, a[:, n + m + 9 :], [f for f in _HEADED_TAILS[g.kind] if f != "ipc_hostname"], bad)
        if not keep.all():  # skip mode: drop the lines with a non-finite pose or time
            a, g.linenos = a[keep], [ln for ln, k in zip(g.linenos, keep) if k]
        if not g.linenos:
            continue
        if g.kind == "FLASER":
            tail = a[:, n:]  # x y theta odom_x odom_y odom_theta ipc logger
            ranges = a[:, :n]
            laser, robot, t = tail[:, 0:3], tail[:, 3:6], tail[:, 6]
            rec_max = None
            angles = _readonly(flaser_beam_angles(n, fov_deg, res_deg))
        else:
            head = a[:, :8]
            tail = a[:, n + m + 9 :]
            ranges = a[:, 8 : 8 + n]
            if g.kind == "ROBOTLASER1":
                laser, robot, t = tail[:, 0:3], tail[:, 3:6], tail[:, 11]
            else:  # RAWLASER1: the robot's pose from the ODOM records around each scan, the laser at its PARAM offset
                t = tail[:, 0]
                robot = _odometry_at(path, lines, odom_lines, np.asarray(g.linenos), t, bad)
                laser = robot
            rec_max = np.where(head[:, 4] > 0, head[:, 4], np.nan)
            ang = head[:, 1:2] + head[:, 3:4] * np.arange(n)
            # One shared angle array when every record has the same geometry (the usual case).
            angles = _readonly(ang[0].astype(np.float32)) if np.all(ang == ang[:1]) else _readonly(ang.astype(np.float32))
        parsed.append((g, ranges, laser, robot, t, rec_max, angles))
    bad.warn()
    if not parsed:
        raise DataError(path, "no readable laser scans: every FLASER / ROBOTLASER1 / RAWLASER1 line was bad",
                        record=f"{len(bad.skipped)} lines skipped")  # fmt: skip
    del lines, groups  # the text is parsed: free it before the arrays below are made

    fallback_max = max_range_m if max_range_m is not None else param_max
    with np.errstate(invalid="ignore"):
        if fallback_max is None:
            fallback_max = _detect_no_return([p[1] for p in parsed])
        impossible = sum(int(np.count_nonzero(~np.isfinite(p[1]) | (p[1] < 0))) for p in parsed)

    linenos = np.concatenate([np.asarray(p[0].linenos) for p in parsed])
    order = np.argsort(linenos, kind="stable")
    index_of = np.empty_like(order)
    index_of[order] = np.arange(order.size)  # position in file order of each parsed record
    blocks: list[_ScanBlock] = []
    seq_max = 0.0
    base = 0
    for g, ranges, laser, robot, t, rec_max, angles in parsed:
        L = ranges.shape[0]
        if max_range_m is not None:
            limit = np.full(L, float(max_range_m))
        elif rec_max is not None:
            limit = np.where(np.isnan(rec_max), np.inf if fallback_max is None else fallback_max, rec_max)
        else:
            limit = np.full(L, np.inf if fallback_max is None else fallback_max)
        with np.errstate(invalid="ignore"):
            valid = _readonly(np.isfinite(ranges) & (ranges > 0) & (ranges < limit[:, None]))
        finite_limit = limit[np.isfinite(limit)]
        if finite_limit.size:
            seq_max = max(seq_max, float(finite_limit.max()))
        else:
            r = ranges[valid]
            seq_max = max(seq_max, float(r.max()) if r.size else 0.0)
        blocks.append(_ScanBlock(
            position=index_of[base : base + L].astype(np.int64),
            t=_readonly(np.ascontiguousarray(t)),
            odom=_readonly(np.ascontiguousarray(robot)),
            ranges=_readonly(ranges.astype(np.float32)),
            valid=valid,
            angles=angles,
            mount=_mount(path, laser, robot, offset_x),
        ))  # fmt: skip
        base += L

    if impossible:
        warnings.warn(f"{path}: {impossible} negative, NaN or inf range readings dropped as invalid beams",
                      RuntimeWarning, stacklevel=3)  # fmt: skip
    return _ParsedLog(blocks, seq_max)


# ----------------------------------------------------------------------------- parse cache

# Logs at least this big (bytes on disk) are cached when asked: parsing a smaller one costs
# about as much as hashing and reading the entry back.
CACHE_MIN_BYTES = 256 << 10
# Bump when the parse's output for a given file and options changes (2: entries carry their
# arrays' checksums, which version 1's did not).
_CACHE_VERSION = 2
_CACHE_KIND = "carmen"


def _parse_log_cached(path: Path, max_range_m: float | None, on_bad_line: str) -> _ParsedLog:
    """`_parse_log`, through the on-disk cache (`load_carmen(cache=True)`)."""
    from slamlab.datasets import array_cache

    _check_file(path)
    if path.stat().st_size < CACHE_MIN_BYTES:
        return _parse_log(path, max_range_m, on_bad_line)
    options = {"max_range_m": max_range_m, "on_bad_line": on_bad_line, "numpy": np.__version__}
    key = hashlib.sha256(json.dumps([_CACHE_VERSION, array_cache.file_sha256(path), options]).encode()).hexdigest()
    entry = f"{_log_stem(path)}-{key[:24]}"
    hit = array_cache.read_entry(_CACHE_KIND, entry)
    # warnings name the file as it was given: an entry with warnings serves that name only
    if hit is not None and (not hit[1].get("warnings") or hit[1].get("path") == str(path)):
        parsed = _from_cache(*hit)
    else:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            parsed = _parse_log(path, max_range_m, on_bad_line)
        parsed.warnings = [(w.category, str(w.message)) for w in caught]
        if array_cache.write_entry(_CACHE_KIND, entry, *_to_cache(parsed, path)):
            # go on with what was written, as a later run would: the log's pages are then the
            # file's, given back after the check, not the parse's arrays on the heap (the
            # hospital's first run: 395 -> 380 MB at its peak). The same values (`tests/test_carmen_cache.py`)
            with warnings.catch_warnings():  # a first run of the same log replacing it meanwhile: keep the parse
                warnings.simplefilter("ignore")
                written = array_cache.read_entry(_CACHE_KIND, entry)
            if written is not None:
                parsed.blocks = _from_cache(*written).blocks
    for category, message in parsed.warnings:
        warnings.warn(message, category, stacklevel=3)
    return parsed


def _to_cache(parsed: _ParsedLog, path: Path) -> tuple[dict[str, np.ndarray], dict]:
    arrays = {f"{j}.{f}": getattr(b, f) for j, b in enumerate(parsed.blocks) for f in _ScanBlock.FIELDS}
    meta = {
        "path": str(path),
        "blocks": len(parsed.blocks),
        "max_range_m": parsed.max_range_m,
        "warnings": [[c.__name__, m] for c, m in parsed.warnings],
    }
    return arrays, meta


def _from_cache(arrays: dict[str, np.ndarray], meta: dict) -> _ParsedLog:
    blocks = [_ScanBlock(**{f: arrays[f"{j}.{f}"] for f in _ScanBlock.FIELDS}) for j in range(int(meta["blocks"]))]
    for b in blocks:
        for f in _ScanBlock.FIELDS:
            getattr(b, f).flags.writeable = False  # mapped read-only already; say so for all
    found = [(getattr(builtins, c, None), m) for c, m in meta["warnings"]]
    categories = [(c if isinstance(c, type) and issubclass(c, Warning) else UserWarning, m) for c, m in found]
    return _ParsedLog(blocks, float(meta["max_range_m"]), categories)
