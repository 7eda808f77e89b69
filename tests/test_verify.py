"""`slamlab-verify` as course staff use it: every result file counts, the preset and the
overrides are printed, and `--preset NAME` refuses runs that changed the preset."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from PIL import Image

from cli_helpers import slamlab_cli, verify_cli
from slamlab.run_compare import VOLATILE, compare_runs, first_metric_difference

pytestmark = pytest.mark.slow  # runs and re-runs the pipeline through the CLI

SHORT = ["dataset.duration_s=20", "particles=10", "steps.max_scans=200", "report=false"]


def slamlab(args: list[str], cwd: Path, cache: Path) -> subprocess.CompletedProcess:
    return slamlab_cli(args, cwd, cache)


def verify(args: list[str], cache: Path) -> subprocess.CompletedProcess:
    return verify_cli(args, cache)


@pytest.fixture(scope="module")
def run_and_rerun(sim_cache, tmp_path_factory) -> tuple[Path, Path, subprocess.CompletedProcess]:
    """A short simulated run with texture and its verified re-run (kept)."""
    root = tmp_path_factory.mktemp("verify")
    run = root / "run"
    assert slamlab([*SHORT, f"hydra.run.dir={run}"], root, sim_cache).returncode == 0
    proc = verify([str(run), "--keep", str(root / "rerun")], sim_cache)
    return run, root / "rerun", proc


def test_verify_prints_the_overrides_and_says_identical(run_and_rerun):
    run, _, proc = run_and_rerun
    assert proc.returncode == 0, proc.stdout + proc.stderr
    lines = proc.stdout.splitlines()
    assert lines[0] == "run made with: no preset; overrides: " + " ".join(SHORT)
    assert lines[-1].startswith(f"IDENTICAL: {run} (every result file")
    # the re-run shows progress like a run does, on stderr
    assert "SLAM 100% 200/200 scans" in proc.stderr


def test_verify_finds_a_block_blacked_out_in_the_map(run_and_rerun, tmp_path, sim_cache):
    run, _, _ = run_and_rerun
    edited = tmp_path / "edited"
    shutil.copytree(run, edited)
    header, pixels = (edited / "map.pgm").read_bytes().split(b"\n255\n", 1)
    w, h = (int(v) for v in header.split()[1:3])
    img = np.frombuffer(pixels, dtype=np.uint8).reshape(h, w).copy()
    img[:200, :200] = 0
    (edited / "map.pgm").write_bytes(header + b"\n255\n" + img.tobytes())
    proc = verify([str(edited)], sim_cache)
    assert proc.returncode == 1
    assert "first difference: map.pgm: " in proc.stdout and "pixels differ" in proc.stdout


@pytest.mark.parametrize("name", ["map.png", "texture.png", "texture_over_map.png"])
def test_every_image_counts(run_and_rerun, tmp_path, name):
    run, rerun, _ = run_and_rerun
    edited = tmp_path / "edited"
    shutil.copytree(run, edited)
    img = np.asarray(Image.open(edited / name)).copy()
    img[:200, :200] = 17  # not 0: a texture's unobserved cells are transparent black already
    Image.fromarray(img).save(edited / name)
    diff = compare_runs(edited, rerun)
    assert diff is not None and diff.startswith(f"{name}: ") and "pixels differ" in diff


def test_log_odds_point_clouds_tables_and_missing_files_count(run_and_rerun, tmp_path):
    run, rerun, _ = run_and_rerun
    assert compare_runs(run, rerun) is None

    def edited_copy() -> Path:
        d = tmp_path / f"e{len(list(tmp_path.iterdir()))}"
        shutil.copytree(run, d)
        return d

    d = edited_copy()
    with np.load(d / "map_logodds.npz") as z:
        arrays = {k: z[k].copy() for k in z.files}
    arrays["data"][5, 5] += 1.0
    np.savez_compressed(d / "map_logodds.npz", **arrays)
    assert compare_runs(d, rerun) == "map_logodds.npz 'data': 1 of %d values differ" % arrays["data"].size

    d = edited_copy()
    ply = bytearray((d / "floor.ply").read_bytes())
    ply[-5] ^= 0xFF
    (d / "floor.ply").write_bytes(bytes(ply))
    assert compare_runs(d, rerun).startswith("floor.ply: differs from byte")

    d = edited_copy()
    lines = (d / "steps.csv").read_text().splitlines(keepends=True)
    neff = lines[0].split(",").index("neff")
    row = lines[4].split(",")  # the header, then rows 0-3
    row[neff] = str(float(row[neff]) + 1.0)
    lines[4] = ",".join(row)
    (d / "steps.csv").write_text("".join(lines))
    assert compare_runs(d, rerun).startswith("steps.csv row 3")

    d = edited_copy()
    (d / "texture_odometry.png").unlink()
    assert compare_runs(d, rerun) == "texture_odometry.png written by the re-run but missing from the run"

    # a run made before 2026-11-27 also holds steps.parquet, the twin of its steps.csv: a
    # re-run without it still reproduces the run
    d = edited_copy()
    (d / "steps.parquet").write_bytes(b"PAR1 written by an earlier version PAR1")
    assert compare_runs(d, rerun) is None

    # timings are not results: a different step time or runtime is no difference
    d = edited_copy()
    m = json.loads((d / "metrics.json").read_text())
    m["runtime_s"] += 5.0
    m["peak_memory_mb"] += 100.0
    (d / "metrics.json").write_text(json.dumps(m))
    csv = pd.read_csv(d / "steps.csv", dtype=str)
    csv["step_time_s"] = "9.5"
    csv.to_csv(d / "steps.csv", index=False)
    assert compare_runs(d, rerun) is None


@pytest.fixture(scope="module")
def changed_grading_run(sim_cache, tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("grading")
    run = root / "run"
    proc = slamlab(["+experiment=grading", "particles=10", "steps.max_scans=300", "report=false",
                    f"hydra.run.dir={run}"], root, sim_cache)
    assert proc.returncode == 0, proc.stderr
    return run


def test_preset_refuses_a_run_with_changed_settings(changed_grading_run, sim_cache):
    proc = verify(["--preset", "grading", str(changed_grading_run)], sim_cache)
    assert proc.returncode == 1
    assert proc.stdout.splitlines() == [
        "run made with: preset grading; overrides: particles=10 steps.max_scans=300 report=false",
        f"NOT PRESET grading: {changed_grading_run}: the run changed the grading preset: "
        "particles=10 steps.max_scans=300 (only data and output paths may change)",
    ]
    assert "re-running" not in proc.stderr  # refused before spending a re-run on it


def test_preset_refuses_a_run_of_another_preset(changed_grading_run, sim_cache):
    proc = verify(["--preset", "sim", str(changed_grading_run)], sim_cache)
    assert proc.returncode == 1
    assert proc.stdout.splitlines()[-1].endswith(
        "the run was not made with +experiment=sim (it used +experiment=grading)")


def test_preset_cannot_be_fooled_by_editing_the_saved_overrides(changed_grading_run, tmp_path, sim_cache):
    forged = tmp_path / "forged"
    shutil.copytree(changed_grading_run, forged)
    (forged / ".hydra" / "overrides.yaml").write_text(yaml.safe_dump(["+experiment=grading"]))
    proc = verify(["--preset", "grading", str(forged)], sim_cache)
    assert proc.returncode == 1
    assert proc.stdout.splitlines()[-1].endswith(
        "the run's saved config differs from the grading preset: 'particles' is 10 in the run, 100 in the preset")


@pytest.mark.slow
def test_preset_accepts_a_faithful_grading_run(sim_cache, tmp_path):
    run = tmp_path / "run"
    proc = slamlab(["+experiment=grading", f"dataset.cache_dir={sim_cache / 'sim'}", "progress=off",
                    f"hydra.run.dir={run}"], tmp_path, sim_cache)
    assert proc.returncode == 0, proc.stderr
    proc = verify(["--preset", "grading", str(run)], sim_cache)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert proc.stdout.splitlines() == [
        f"run made with: preset grading; overrides: dataset.cache_dir={sim_cache / 'sim'} progress=off",
        f"IDENTICAL: {run} (the grading preset, every result file; timing and memory figures excepted)",
    ]


def test_metrics_differ_by_graph_timings_only_are_the_same_results():
    """The graph filter's seconds per part (and steps.csv's `optimise_s`) are timings, like
    `runtime_s`; its counts are results."""
    a = {"runtime_s": 1.0, "graph": {"accepted": 3, "search_s": 1.0, "screen_s": 0.1, "update_s": 0.2, "optimise_s": 0.3,
                                     "final_optimise_s": 0.4, "final_match_s": 0.5}, "relations": {"loop_min_dt_s": 30.0}}
    b = {"runtime_s": 2.0, "graph": {"accepted": 3, "search_s": 2.0, "screen_s": 0.2, "update_s": 0.3, "optimise_s": 0.4,
                                     "final_optimise_s": 0.5, "final_match_s": 0.6}, "relations": {"loop_min_dt_s": 30.0}}
    assert first_metric_difference(a, b) is None
    assert "graph.accepted" in first_metric_difference(a, {**b, "graph": {**b["graph"], "accepted": 4}})
    assert "loop_min_dt_s" in first_metric_difference(a, {**b, "relations": {"loop_min_dt_s": 20.0}})
    assert VOLATILE.search("optimise_s") and not VOLATILE.search("duration_s")


def test_a_run_made_before_a_run_level_key_existed_is_still_the_preset_at_that_keys_default(tmp_path):
    """A saved config without a run-level key added since (steps.odom_jump_m) re-runs at the
    key's schema default: the preset check reads it so, while a key the preset sets to
    something else stays a difference."""
    from omegaconf import OmegaConf

    from slamlab.provenance import compose_preset, preset_violation

    def saved_run(name: str, drop: str, set_to: tuple[str, object] | None = None) -> Path:
        """The grading preset's config saved without `drop` (dotted), `set_to` (dotted key, value) changed."""
        cfg = OmegaConf.to_container(compose_preset("grading", []), resolve=False)
        *parents, last = drop.split(".")
        node = cfg
        for part in parents:
            node = node[part]
        node.pop(last)
        if set_to:
            cfg["steps"][set_to[0]] = set_to[1]
        hydra = tmp_path / name / ".hydra"
        hydra.mkdir(parents=True)
        (hydra / "config.yaml").write_text(OmegaConf.to_yaml(OmegaConf.create(cfg)))
        (hydra / "overrides.yaml").write_text(yaml.safe_dump(["+experiment=grading"]))
        return tmp_path / name

    assert preset_violation(saved_run("old", "steps.odom_jump_m"), "grading") is None
    assert preset_violation(saved_run("old2", "steps.odom_jump_rad"), "grading") is None
    # a missing key the preset sets off its default (seed 2026; the schema's 0) is still a difference
    assert preset_violation(saved_run("seedless", "seed"), "grading") == (
        "the run's saved config differs from the grading preset: 'seed' is 0 in the run, 2026 in the preset")
    assert preset_violation(saved_run("changed", "steps.odom_jump_m", ("min_angle_rad", 0.3)), "grading") == (
        "the run's saved config differs from the grading preset: 'steps.min_angle_rad' is 0.3 in the run, 0.0 in the preset")
