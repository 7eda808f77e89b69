"""2 x 2 and 3 x 3 linear algebra in a fixed order of floating-point operations.

NumPy hands `@`, `linalg.solve` and `linalg.eigh` to OpenBLAS, which picks its kernels for
the CPU it runs on (`OPENBLAS_CORETYPE` names them). A match's covariance or a closure's
Mahalanobis test then differs in its last bits from one machine to another, and the pose
graph feeds every optimised pose back into the next match and the next test, so those bits
grow into another trajectory: on the Intel log the three OpenBLAS core types of an x86-64
CPU gave three different smoothed trajectories, and on the Freiburg hospital log one machine
closed the right-hand loop where another did not. The RBPF, which uses none of these, gives
the same bits under every core type.

The graph's covariances and tests use these functions instead: plain loops compiled by
numba without fast-math (no reassociation, no fused multiply-add), so the same inputs give
the same bits on any x86-64 CPU. `tests/test_small_linalg.py` checks them against NumPy and
runs the graph with the CPU's own OpenBLAS kernels and with the generic ones.
"""

from __future__ import annotations

import numba
import numpy as np

from slamlab.geometry import FloatArray

JACOBI_SWEEPS = 30  # a 3 x 3 converges in 4-6 sweeps; the cap only bounds a pathological input


@numba.njit(cache=True)
def matmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a @ b for small 2-D float64 arrays, each entry summed left to right."""
    n, m = a.shape
    p = b.shape[1]
    out = np.zeros((n, p))
    for i in range(n):
        for j in range(p):
            s = 0.0
            for k in range(m):
                s += a[i, k] * b[k, j]
            out[i, j] = s
    return out


@numba.njit(cache=True)
def sym_eig(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (ascending) and eigenvectors (columns) of a small symmetric matrix, by
    cyclic Jacobi rotations (only the upper triangle is read). a = v diag(w) v^T to a few
    units in the last place of the largest eigenvalue."""
    n = a.shape[0]
    m = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            m[i, j] = a[i, j] if j >= i else a[j, i]
    v = np.eye(n)
    for _ in range(JACOBI_SWEEPS):
        off = 0.0
        for p in range(n):
            for q in range(p + 1, n):
                off += abs(m[p, q])
        if off == 0.0:
            break
        for p in range(n):
            for q in range(p + 1, n):
                apq = m[p, q]
                if apq == 0.0:
                    continue
                # the rotation that zeroes m[p, q] (the smaller of the two angles: stable)
                theta = (m[q, q] - m[p, p]) / (2.0 * apq)
                t = 1.0 / (abs(theta) + np.sqrt(theta * theta + 1.0))
                if theta < 0.0:
                    t = -t
                c = 1.0 / np.sqrt(t * t + 1.0)
                s = t * c
                for k in range(n):  # m <- m J (columns p, q)
                    mkp = m[k, p]
                    mkq = m[k, q]
                    m[k, p] = c * mkp - s * mkq
                    m[k, q] = s * mkp + c * mkq
                for k in range(n):  # m <- J^T m (rows p, q)
                    mpk = m[p, k]
                    mqk = m[q, k]
                    m[p, k] = c * mpk - s * mqk
                    m[q, k] = s * mpk + c * mqk
                m[p, q] = 0.0
                m[q, p] = 0.0
                for k in range(n):
                    vkp = v[k, p]
                    vkq = v[k, q]
                    v[k, p] = c * vkp - s * vkq
                    v[k, q] = s * vkp + c * vkq
    w = np.empty(n)
    for i in range(n):
        w[i] = m[i, i]
    order = np.argsort(w, kind="mergesort")
    return w[order].copy(), v[:, order].copy()


@numba.njit(cache=True)
def from_eig(w: np.ndarray, v: np.ndarray) -> np.ndarray:
    """v diag(w) v^T, symmetric by construction (each entry summed over the eigenvalues in order)."""
    n = w.shape[0]
    out = np.zeros((n, n))
    for i in range(n):
        for j in range(i, n):
            s = 0.0
            for k in range(n):
                s += v[i, k] * w[k] * v[j, k]
            out[i, j] = s
            out[j, i] = s
    return out


@numba.njit(cache=True)
def solve(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """x with a x = b for one small square a (Gaussian elimination with partial pivoting)."""
    n = a.shape[0]
    m = a.copy()
    x = b.copy()
    for col in range(n):
        piv = col
        for r in range(col + 1, n):
            if abs(m[r, col]) > abs(m[piv, col]):
                piv = r
        if piv != col:
            for k in range(n):
                tmp = m[col, k]
                m[col, k] = m[piv, k]
                m[piv, k] = tmp
            tmp = x[col]
            x[col] = x[piv]
            x[piv] = tmp
        for r in range(col + 1, n):
            f = m[r, col] / m[col, col]
            for k in range(col, n):
                m[r, k] -= f * m[col, k]
            x[r] -= f * x[col]
    for r in range(n - 1, -1, -1):
        s = x[r]
        for k in range(r + 1, n):
            s -= m[r, k] * x[k]
        x[r] = s / m[r, r]
    return x


@numba.njit(cache=True)
def _mahalanobis_sq_rows(d: np.ndarray, cov: np.ndarray) -> np.ndarray:
    out = np.empty(d.shape[0])
    for i in range(d.shape[0]):
        x = solve(cov[i], d[i])
        s = 0.0
        for k in range(d.shape[1]):
            s += d[i, k] * x[k]
        out[i] = s
    return out


def mahalanobis_sq(d: FloatArray, cov: FloatArray) -> FloatArray:
    """d^T cov^-1 d over the leading axes: `d` (..., n), `cov` (..., n, n) -> (...)."""
    d = np.asarray(d, dtype=np.float64)
    cov = np.asarray(cov, dtype=np.float64)
    n = d.shape[-1]
    flat = _mahalanobis_sq_rows(np.ascontiguousarray(d.reshape(-1, n)), np.ascontiguousarray(cov.reshape(-1, n, n)))
    return flat.reshape(d.shape[:-1])


@numba.njit(cache=True)
def congruence(r: np.ndarray, a: np.ndarray) -> np.ndarray:
    """r a r^T for small square matrices (a covariance or an information matrix in other axes)."""
    return matmul(matmul(r, a), r.T.copy())


@numba.njit(cache=True)
def _rotate_rows(rot: np.ndarray, cov: np.ndarray) -> np.ndarray:
    out = np.empty_like(cov)
    for i in range(cov.shape[0]):
        out[i] = congruence(rot[i], cov[i])
    return out


def rotate_covariances(rot: FloatArray, cov: FloatArray) -> FloatArray:
    """rot cov rot^T for each of K pairs: `rot`, `cov` (K, n, n) -> (K, n, n)."""
    return _rotate_rows(np.ascontiguousarray(rot, dtype=np.float64), np.ascontiguousarray(cov, dtype=np.float64))
