"""A full disk while a run writes its files (issue 45): one line naming the file being
written and the device that is full, no traceback, no temporary file left."""

from __future__ import annotations

import errno
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from slamlab.io.atomic import TMP_MARK, DiskFullError, atomic_path, device_of, write_bytes


def test_a_write_that_finds_no_space_names_the_file_and_the_device(tmp_path):
    target = tmp_path / "map.pgm"
    with pytest.raises(DiskFullError) as info:
        with atomic_path(target) as tmp:
            tmp.write_bytes(b"half a map")
            raise OSError(errno.ENOSPC, "No space left on device", str(tmp))
    assert str(info.value) == f"no space left on {device_of(tmp_path)} while writing {target}"
    assert "mounted at" in str(info.value)
    assert list(tmp_path.iterdir()) == []  # neither the file nor its temporary name


def test_a_writer_that_only_says_it_failed_on_a_full_disk_is_a_full_disk(tmp_path, monkeypatch):
    """Open3D returns False; on a disk with no room left that is the reason."""
    full = os.statvfs_result((4096, 4096, 100, 0, 0, 10, 0, 0, 0, 255))
    monkeypatch.setattr(os, "statvfs", lambda p: full)
    with pytest.raises(DiskFullError, match="floor.ply"):
        with atomic_path(tmp_path / "floor.ply") as tmp:
            tmp.write_text("ply")
            raise OSError(f"Open3D could not write {tmp}")
    monkeypatch.undo()
    with pytest.raises(OSError, match="could not write") as other:  # with room left: not a full disk
        with atomic_path(tmp_path / "floor.ply"):
            raise OSError("Open3D could not write it")
    assert not isinstance(other.value, DiskFullError)
    write_bytes(tmp_path / "ok.bin", b"1")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ok.bin"]


def _can_mount_a_small_tmpfs(where: Path) -> bool:
    if shutil.which("unshare") is None:
        return False
    probe = subprocess.run(["unshare", "-rm", "sh", "-c", f"mount -t tmpfs -o size=64k tmpfs {where}"],
                           capture_output=True, text=True)
    return probe.returncode == 0


@pytest.mark.slow
def test_a_run_on_a_full_disk_says_so_in_one_line(tmp_path, sim_cache):
    """A real full disk: a 200 kB tmpfs (a private mount namespace, `unshare -rm`: no root
    needed where user namespaces are allowed) under the run folder."""
    disk = tmp_path / "disk"
    disk.mkdir()
    if not _can_mount_a_small_tmpfs(disk):
        pytest.skip("this system allows no private tmpfs mount (unshare -rm); the fault-injection tests above stand in")
    run = disk / "run"
    out = subprocess.run(["unshare", "-rm", "sh", "-c",
                          f"mount -t tmpfs -o size=200k tmpfs {disk} && ({sys.executable} -m slamlab.cli.app "
                          f"dataset.duration_s=10 particles=10 texture=none progress=off hydra.run.dir={run}; "
                          f"echo rc=$?; ls -A {run}; cat {run}/metrics.json)"],
                         capture_output=True, text=True, cwd=tmp_path,
                         env={**os.environ, "SLAMLAB_CACHE_DIR": str(sim_cache), "MPLBACKEND": "Agg"}, timeout=600)
    assert "rc=2" in out.stdout, out.stderr[-3000:]
    errors = [line for line in out.stderr.splitlines() if "[ERROR]" in line]
    assert "Traceback" not in out.stderr and "Logging error" not in out.stderr
    assert len(errors) == 2 and errors[1].endswith(f"run failed; details in {run}/metrics.json")
    assert f"no space left on tmpfs (mounted at {disk}) while writing {run}/" in errors[0]
    listing = out.stdout.split("rc=2", 1)[1]
    assert TMP_MARK not in listing
    assert '"status": "failed"' in listing and "no space left on tmpfs" in listing
