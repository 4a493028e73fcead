"""Cholmod on the engine's CSR Newton matrices: the transpose's arrays, no conversion."""
import numpy as np
import pytest
import scipy.sparse as sp

from nitsche.linalg import HAVE_CHOLMOD, Cholmod, symmetric_csc

pytestmark = pytest.mark.skipif(not HAVE_CHOLMOD, reason="scikit-sparse is not installed")


def laplacian(n, shift=0.1):
    """The 2D five-point Laplacian on an n x n grid plus shift I (symmetric positive definite)."""
    T = sp.diags([-np.ones(n - 1), 2 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1])
    return (sp.kronsum(T, T) + shift * sp.eye(n * n)).tocsr()


def test_symmetric_csc_of_a_csr_matrix_shares_its_arrays():
    A = laplacian(12)
    C = symmetric_csc(A)
    assert C.format == "csc" and np.shares_memory(C.data, A.data)
    assert abs(C - A).max() == 0.0  # A symmetric: its transpose is A
    B = A.tocsc()
    assert symmetric_csc(B) is not None and abs(symmetric_csc(B) - A).max() == 0.0


def test_cholmod_solves_csr_and_csc_alike_and_reuses_the_factor():
    A = laplacian(30)
    b = np.random.default_rng(0).normal(size=A.shape[0])
    lin_csr, lin_csc = Cholmod(), Cholmod()
    x = lin_csr.solve(A, b)
    y = lin_csc.solve(A.tocsc(), b)
    assert np.linalg.norm(A @ x - b) <= 1e-12 * np.linalg.norm(b)
    assert np.abs(x - y).max() <= 1e-13 * np.abs(y).max()
    # the same matrix again: the factor, no new factorization
    assert np.array_equal(lin_csr.solve(A.copy(), b), x) and lin_csr.factorizations == 1
    # a few diagonal entries larger (the same pattern): CG preconditioned by the factor
    A2 = A.copy()
    rows = np.repeat(np.arange(A.shape[0]), np.diff(A.indptr))
    A2.data[(A2.indices == rows) & (rows % 90 == 0)] += 0.5
    z = lin_csr.solve(A2, b, rtol=1e-8)
    assert lin_csr.factorizations == 1 and len(lin_csr.iterations) == 1
    assert np.linalg.norm(A2 @ z - b) <= 1e-8 * np.linalg.norm(b)
    assert lin_csr.is_positive_definite(A2) and lin_csr.factorizations == 1  # A2 - A >= 0
