"""The graph's small linear algebra (`slam.graph.small_linalg`) agrees with NumPy's, and the
graph filter's trajectories are the same bits whichever OpenBLAS kernels the CPU gets."""

from __future__ import annotations

import numpy as np
import pytest
from cli_helpers import slamlab_cli

from slamlab.slam.graph.small_linalg import from_eig, mahalanobis_sq, matmul, rotate_covariances, solve, sym_eig


def _symmetric(rng: np.random.Generator, n: int) -> np.ndarray:
    """A random positive semi-definite n x n matrix with eigenvalues spread over many decades
    (a corridor match's covariance: ~1e-4 across, ~1e2 along)."""
    q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    return (q * 10.0 ** rng.uniform(-6, 3, size=n)) @ q.T


@pytest.mark.parametrize("n", [2, 3])
def test_sym_eig_agrees_with_numpy(n: int) -> None:
    rng = np.random.default_rng(n)
    cases = [_symmetric(rng, n) for _ in range(300)]
    cases += [np.diag(np.arange(n, 0, -1.0)), np.eye(n), np.zeros((n, n)), np.ones((n, n))]  # diagonal, repeated, rank 1
    for a in cases:
        w, v = sym_eig(a)
        ref = np.linalg.eigvalsh(a)
        scale = max(np.abs(ref).max(), 1e-300)
        assert np.all(np.diff(w) >= 0), "eigenvalues not ascending"
        np.testing.assert_allclose(w, ref, rtol=0, atol=1e-13 * scale)
        np.testing.assert_allclose(v.T @ v, np.eye(n), rtol=0, atol=1e-13)
        np.testing.assert_allclose(from_eig(w, v), a, rtol=0, atol=1e-13 * scale)


def test_solve_mahalanobis_products_agree_with_numpy() -> None:
    rng = np.random.default_rng(7)
    cov = np.array([_symmetric(rng, 3) + 1e-6 * np.eye(3) for _ in range(200)])
    d = rng.normal(size=(200, 3))
    ref = np.einsum("li,li->l", d, np.linalg.solve(cov, d[..., None])[..., 0])
    np.testing.assert_allclose(mahalanobis_sq(d, cov), ref, rtol=1e-7)
    # the leading axes are kept (verify's pairwise table is (n, n))
    assert mahalanobis_sq(d.reshape(10, 20, 3), cov.reshape(10, 20, 3, 3)).shape == (10, 20)
    np.testing.assert_allclose(solve(cov[0], d[0]), np.linalg.solve(cov[0], d[0]), rtol=1e-7)
    a, b = rng.normal(size=(3, 3)), rng.normal(size=(3, 2))
    np.testing.assert_allclose(matmul(a, b), a @ b, rtol=1e-14, atol=1e-15)
    rot = rng.normal(size=(200, 3, 3))
    np.testing.assert_allclose(rotate_covariances(rot, cov), rot @ cov @ rot.transpose(0, 2, 1), rtol=1e-12, atol=1e-12 * np.abs(cov).max())


def test_graph_same_bits_under_every_openblas_core(shared_data, tmp_path) -> None:
    """The Intel log's first 500 scans with the graph preset, once with the CPU's own OpenBLAS
    kernels and once with the generic SSE3 ones (`OPENBLAS_CORETYPE=Prescott`, what any
    x86-64 CPU can run): every trajectory and the loop table are the same bytes. With NumPy's
    `@`, `solve` and `eigh` in the covariances (before small_linalg) the smoothed trajectory
    and loops.csv differed here."""
    outputs = {}
    for core in ("", "Prescott"):
        out = tmp_path / (core or "native")
        r = slamlab_cli(["+experiment=lidar2d", "report=false", f"dataset.path={shared_data / 'carmen' / 'intel.clf.bz2'}",
                         "steps.max_scans=500", f"hydra.run.dir={out}"], cwd=tmp_path, env={"OPENBLAS_CORETYPE": core})
        assert r.returncode == 0, r.stderr[-2000:]
        outputs[core] = {name: (out / name).read_bytes() for name in ("trajectory.tum", "trajectory_causal.tum", "loops.csv")}
    assert b"accepted" in outputs[""]["loops.csv"], "no loop closure in the run: the test would not exercise the graph"
    for name in outputs[""]:
        assert outputs[""][name] == outputs["Prescott"][name], f"{name} differs between OpenBLAS kernels"
