"""Artifacts: TUM round trip, ROS map files, atomic writes."""

from __future__ import annotations

import json

import numpy as np
import pytest

from slamlab import artifacts
from slamlab.errors import DataError
from slamlab.frames import GridImage


def test_tum_round_trip_and_quaternion(tmp_path):
    t = np.array([1.5, 2.0, 2.25])
    poses = np.array([[0.0, 0.0, 0.0], [1.0, -2.0, np.pi / 2], [3.0, 4.0, -3.0]])
    artifacts.write_tum(tmp_path / "a.tum", t, poses)
    lines = (tmp_path / "a.tum").read_text().splitlines()
    assert lines[0].startswith("#")
    row = [float(v) for v in lines[2].split()]
    assert row[:4] == [2.0, 1.0, -2.0, 0.0]
    # yaw pi/2 -> qz = qw = sqrt(2)/2
    assert row[6] == pytest.approx(np.sqrt(0.5)) and row[7] == pytest.approx(np.sqrt(0.5))
    t2, p2 = artifacts.read_tum(tmp_path / "a.tum")
    np.testing.assert_allclose(t2, t)
    np.testing.assert_allclose(p2, poses, atol=1e-8)


def test_tum_text_is_deterministic():
    t = np.linspace(0, 1, 50)
    p = np.random.default_rng(1).normal(size=(50, 3))
    assert artifacts.tum_text(t, p) == artifacts.tum_text(t.copy(), p.copy())


def test_map_files_follow_map_server_convention(tmp_path):
    lo = np.zeros((4, 6), dtype=np.float32)
    lo[0, 0] = 5.0  # occupied, lowest-y row -> bottom row of the image
    lo[3, 5] = -5.0  # free, highest-y row -> top row of the image
    artifacts.write_map(tmp_path, GridImage(lo, 0.05, (-1.0, 2.0)))
    raw = (tmp_path / "map.pgm").read_bytes()
    header, pixels = raw[: len(b"P5\n6 4\n255\n")], raw[len(b"P5\n6 4\n255\n"):]
    assert header == b"P5\n6 4\n255\n"
    img = np.frombuffer(pixels, dtype=np.uint8).reshape(4, 6)
    assert img[3, 0] == 0 and img[0, 5] == 254 and img[1, 1] == 205
    yaml_text = (tmp_path / "map.yaml").read_text()
    assert "image: map.pgm" in yaml_text and "origin: [-1.000000, 2.000000, 0.0]" in yaml_text
    assert "resolution: 0.050000" in yaml_text
    back = artifacts.read_map(tmp_path)
    np.testing.assert_array_equal(back.data, lo)
    assert back.data.dtype == np.float32 and back.resolution_m == 0.05
    assert back.origin_xy == (-1.0, 2.0)
    # map.png: grey = 1 - P(occupied), top row = highest y, like the PGM
    from PIL import Image

    png = np.asarray(Image.open(tmp_path / "map.png").convert("L"))
    assert png.shape == (4, 6)
    assert png[3, 0] < 5 and png[0, 5] > 250 and abs(int(png[1, 1]) - 128) < 3  # occupied, free, unknown


def test_a_log_odds_file_without_its_arrays_names_the_file_and_the_array(tmp_path):
    path = tmp_path / "map_logodds.npz"
    np.savez_compressed(path, data=np.zeros((2, 2), np.float32), origin_xy=np.zeros(2))
    with pytest.raises(DataError, match=r"map_logodds\.npz: missing array\(s\) resolution_m \(need"):
        artifacts.read_logodds(path)


def test_atomic_write_leaves_nothing_on_failure(tmp_path):
    target = tmp_path / "x.json"
    with pytest.raises(RuntimeError):
        with artifacts.atomic_path(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("killed")
    assert list(tmp_path.iterdir()) == []


def test_json_writes_nan_as_null(tmp_path):
    artifacts.write_json(tmp_path / "m.json", {"a": float("nan"), "b": np.float32(1.5), "c": np.int64(3)})
    assert json.loads((tmp_path / "m.json").read_text()) == {"a": None, "b": 1.5, "c": 3}
