"""Bad THOR input is rejected with a DataError naming the file, the record and the field."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.io

from slamlab.datasets.thor import load_thor
from slamlab.datasets.thor_write import (
    DepthRecord,
    RGBRecord,
    write_depth_mat,
    write_joint_mat,
    write_lidar_mat,
    write_rgb_mats,
    write_struct_cell,
)
from slamlab.errors import DataError

T0 = 1_426_800_000.0
N = 20


def lidar(root: Path, t: np.ndarray | None = None, scans: np.ndarray | None = None) -> None:
    t = T0 + np.arange(N) * 0.025 if t is None else t
    scans = np.full((len(t), 1081), 4.0, np.float32) if scans is None else scans
    write_lidar_mat(root / "train_lidar0.mat", t, np.zeros((len(t), 3)), np.zeros((len(t), 3)), scans)


def joint(root: Path, ts: np.ndarray | None = None, head: np.ndarray | None = None) -> None:
    ts = T0 - 0.01 + np.arange(60) * 0.01 if ts is None else ts
    head = np.zeros((2, len(ts))) if head is None else head
    scipy.io.savemat(root / "train_joint0.mat", {"ts": ts.reshape(1, -1), "head_angles": head, "rpy": np.zeros((3, len(ts)))})


def good(root: Path) -> None:
    lidar(root)
    joint(root)


def rec(i: int, fields: list[str]) -> dict:
    """A lidar record with the given field names (values by their usual meaning)."""
    vals = {"t": np.array([[T0 + i * 0.025]]), "pose": np.zeros((1, 3)), "res": np.array([[0.0044]]),
            "rpy": np.zeros((1, 3)), "scan": np.ones((1, 1081), np.float32)}  # fmt: skip
    return {f: vals.get(f, np.array([[7.0]])) for f in fields}


def raises(root: Path, *parts: str, **kw) -> DataError:
    with pytest.raises(DataError) as exc:
        load_thor(root, **kw)
    msg = str(exc.value)
    for p in parts:
        assert p in msg, f"{p!r} not in {msg!r}"
    return exc.value


def test_missing_folder_and_files(tmp_path: Path) -> None:
    raises(tmp_path / "nope", "nope", "not found")
    raises(tmp_path, "train_lidar0.mat", "not found", "test_lidar.mat")
    lidar(tmp_path)
    raises(tmp_path, "train_joint0.mat", "not found")


def test_truncated_and_corrupt_mat(tmp_path: Path) -> None:
    good(tmp_path)
    p = tmp_path / "train_lidar0.mat"
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])
    raises(tmp_path, "train_lidar0.mat", f"record {N // 2 - 1}", "truncated or corrupt")  # the first damaged record
    p.write_bytes(b"this is not a MATLAB file at all" * 10)
    raises(tmp_path, "train_lidar0.mat", "truncated or corrupt")


def test_missing_variables(tmp_path: Path) -> None:
    good(tmp_path)
    scipy.io.savemat(tmp_path / "train_lidar0.mat", {"scans": np.zeros((2, 2))})
    raises(tmp_path, "train_lidar0.mat", "field 'lidar'", "variable missing")
    lidar(tmp_path)
    scipy.io.savemat(tmp_path / "train_joint0.mat", {"head_angles": np.zeros((2, 5))})
    raises(tmp_path, "train_joint0.mat", "field 'ts'")
    scipy.io.savemat(tmp_path / "train_joint0.mat", {"ts": np.zeros((1, 5))})
    raises(tmp_path, "train_joint0.mat", "field 'head_angles'")


def test_wrong_shapes(tmp_path: Path) -> None:
    good(tmp_path)
    lidar(tmp_path, scans=np.ones((N, 1080), np.float32))
    raises(tmp_path, "train_lidar0.mat", "record 0", "field 'scan'", "1081")
    lidar(tmp_path)
    ts = T0 + np.arange(30) * 0.01
    joint(tmp_path, ts, head=np.zeros((30, 2)))
    raises(tmp_path, "train_joint0.mat", "field 'head_angles'", "2x30")
    joint(tmp_path, ts, head=np.zeros((3, 30)))
    raises(tmp_path, "train_joint0.mat", "field 'head_angles'")
    # A bad pose in one record names that record.
    records = [rec(i, ["t", "pose", "res", "rpy", "scan"]) for i in range(5)]
    records[3]["pose"] = np.zeros((1, 2))
    write_struct_cell(tmp_path / "train_lidar0.mat", "lidar", records)
    joint(tmp_path)
    raises(tmp_path, "record 3", "field 'pose'", "expected 3 values")


@pytest.mark.parametrize("nfields", [4, 7])
def test_records_with_wrong_field_count(tmp_path: Path, nfields: int) -> None:
    names = {4: ["t", "pose", "res", "scan"], 7: ["t", "a", "b", "pose", "res", "rpy", "scan"]}[nfields]
    write_struct_cell(tmp_path / "train_lidar0.mat", "lidar", [rec(i, names) for i in range(3)])
    joint(tmp_path)
    raises(tmp_path, "train_lidar0.mat", "record 0", f"has {nfields} fields", "expected 5 or 6")


def test_mixed_layouts_name_the_record(tmp_path: Path) -> None:
    records = [rec(i, ["t", "pose", "res", "rpy", "scan"]) for i in range(5)]
    records[4] = rec(4, ["t", "id", "pose", "res", "rpy", "scan"])
    # scipy needs equal field names per struct only within one struct: each record is its own.
    write_struct_cell(tmp_path / "train_lidar0.mat", "lidar", records)
    joint(tmp_path)
    # 5- and 6-field records are both valid by position: read fine.
    assert len(load_thor(tmp_path)) == 5
    records[2] = {"t": records[2]["t"], "scan": records[2]["scan"], "delta_pose": np.zeros((1, 3))}
    write_struct_cell(tmp_path / "train_lidar0.mat", "lidar", records)
    raises(tmp_path, "record 2", "different layout")


@pytest.mark.parametrize("ucsd", [False, True])
def test_non_finite_odometry_names_the_record(tmp_path: Path, ucsd: bool) -> None:
    # In the UCSD layout the poses are a running sum: one NaN would spoil every later pose.
    t = T0 + np.arange(N) * 0.025
    pose = np.zeros((N, 3))
    pose[5, 0] = np.nan
    write_lidar_mat(tmp_path / "train_lidar0.mat", t, pose, np.zeros((N, 3)),
                    np.full((N, 1081), 4.0, np.float32), ucsd_delta_pose=ucsd)
    joint(tmp_path)
    field = "delta_pose" if ucsd else "pose"
    with pytest.raises(DataError, match=rf"train_lidar0.mat: record 5, field '{field}'"):
        load_thor(tmp_path)


def test_empty_logs(tmp_path: Path) -> None:
    scipy.io.savemat(tmp_path / "train_lidar0.mat", {"lidar": np.empty((1, 0), dtype=object)})
    joint(tmp_path)
    raises(tmp_path, "train_lidar0.mat", "empty")
    lidar(tmp_path)
    scipy.io.savemat(tmp_path / "train_joint0.mat", {"ts": np.zeros((1, 0)), "head_angles": np.zeros((2, 0))})
    raises(tmp_path, "train_joint0.mat", "empty", "field 'ts'")


def test_time_steps_back(tmp_path: Path) -> None:
    t = T0 + np.arange(N) * 0.025
    t[17] = t[16] - 0.001
    lidar(tmp_path, t=t)
    joint(tmp_path)
    raises(tmp_path, "train_lidar0.mat", "record 17", "field 't'", "steps back")
    lidar(tmp_path)
    ts = T0 + np.arange(60) * 0.01
    ts[41] = ts[40] - 0.5
    joint(tmp_path, ts)
    raises(tmp_path, "train_joint0.mat", "sample 41", "field 'ts'", "steps back")


def test_lidar_and_joint_from_different_runs(tmp_path: Path) -> None:
    lidar(tmp_path)
    joint(tmp_path, T0 + 1000.0 + np.arange(60) * 0.01)
    raises(tmp_path, "train_joint0.mat", "not from the same run")


# ------------------------------------------------------------------------------- RGB-D


def kinect(root: Path, td: list[float], tr: list[float], fpf: int = 2) -> None:
    z3, z2 = np.zeros(3), np.zeros(2)
    write_depth_mat(root / "DEPTH_0.mat", [DepthRecord(t, np.full((4, 5), 1000, np.uint16), z3, z3, z2) for t in td])
    write_rgb_mats(root, 0, [RGBRecord(t, np.zeros((4, 5, 3), np.uint8), z3, z3, z2) for t in tr], frames_per_file=fpf)


def test_rgbd_times_that_cannot_be_paired(tmp_path: Path) -> None:
    good(tmp_path)
    kinect(tmp_path, [T0 + 0.1, T0 + 0.2], [T0 + 500.0, T0 + 500.1])
    raises(tmp_path, "RGB_0_1.mat", "cannot be paired", "2 depth, 2 colour")


def test_rgbd_times_step_back(tmp_path: Path) -> None:
    good(tmp_path)
    kinect(tmp_path, [T0 + 0.1, T0 + 0.2, T0 + 0.3], [T0 + 0.1, T0 + 0.2, T0 + 0.15], fpf=2)
    raises(tmp_path, "RGB_0_2.mat", "frame 0", "field 't'", "steps back")
    kinect(tmp_path, [T0 + 0.1, T0 + 0.3, T0 + 0.2], [T0 + 0.1, T0 + 0.2, T0 + 0.3])
    raises(tmp_path, "DEPTH_0.mat", "frame 2", "steps back")


def test_rgb_file_numbering_gap(tmp_path: Path) -> None:
    good(tmp_path)
    kinect(tmp_path, [T0 + 0.1, T0 + 0.2, T0 + 0.3], [T0 + 0.1, T0 + 0.2, T0 + 0.3], fpf=1)
    (tmp_path / "RGB_0_2.mat").unlink()
    raises(tmp_path, "RGB_0_2.mat", "not found", "RGB_0_3.mat exists")


def test_kinect_record_fields(tmp_path: Path) -> None:
    good(tmp_path)
    kinect(tmp_path, [T0 + 0.1], [T0 + 0.1])
    d = scipy.io.loadmat(tmp_path / "DEPTH_0.mat")["DEPTH"]
    r = d[0][0][0][0]
    fields = {n: r[n] for n in r.dtype.names}
    fields["head_angles"] = np.zeros((1, 3))
    write_struct_cell(tmp_path / "DEPTH_0.mat", "DEPTH", [fields])
    raises(tmp_path, "DEPTH_0.mat", "frame 0", "field 'head_angles'", "expected 2")
    del fields["head_angles"]
    write_struct_cell(tmp_path / "DEPTH_0.mat", "DEPTH", [fields])
    raises(tmp_path, "DEPTH_0.mat", "frame 0", "has 15 fields", "expected 16")


def test_truncated_depth_file(tmp_path: Path) -> None:
    good(tmp_path)
    kinect(tmp_path, [T0 + 0.1, T0 + 0.2, T0 + 0.3], [T0 + 0.1, T0 + 0.2, T0 + 0.3])
    p = tmp_path / "DEPTH_0.mat"
    data = p.read_bytes()
    p.write_bytes(data[: int(len(data) * 0.8)])
    raises(tmp_path, "DEPTH_0.mat", "frame 2", "truncated or corrupt")
    p.write_bytes(b"garbage" * 40)
    raises(tmp_path, "DEPTH_0.mat", "not a MATLAB")
