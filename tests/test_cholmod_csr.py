"""Cholmod on the engine's CSR Newton matrices: the transpose's arrays, no conversion."""
import numpy as np
import pytest
import scipy.sparse as sp

from nitsche.linalg import HAVE_CHOLMOD, Cholmod, IndefiniteHessian, symmetric_csc

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


def two_fields(n, coupled):
    """Two Laplacians (fields u, v) with the coupling of a penalty 3 (u_i - v_i)^2 at the
    nodes `coupled` (a contact set), on the pattern of the coupling at every node (the
    structure a constraint's terms give on the whole surface), which holds exact zeros
    off `coupled`: one pattern for every contact set, as Newton's matrices share."""
    K = laplacian(n)
    N = K.shape[0]

    def assembled(c):
        C = sp.diags(c)
        return sp.csr_matrix(sp.bmat([[K + C, -C], [-C, K + C]]))
    P = assembled(np.ones(N))  # the pattern
    c = np.zeros(N)
    c[coupled] = 3.0
    rows = np.repeat(np.arange(2 * N), np.diff(P.indptr))
    values = np.asarray(assembled(c).tocsr()[rows, P.indices]).ravel()
    return sp.csr_matrix((values, P.indices, P.indptr), shape=P.shape)


def test_cholmod_factors_the_nonzero_entries_and_analyzes_again_only_when_they_grow():
    from nitsche.linalg import cholmod_factor
    n = 12
    N = n * n
    b = np.random.default_rng(1).normal(size=2 * N)
    A1 = two_fields(n, np.arange(0, N, 7))
    A2 = two_fields(n, np.arange(0, N, 14))  # fewer points coupled: within the analysis
    A3 = two_fields(n, np.arange(3, N, 5))   # others: a new analysis of the union
    A2 = sp.csr_matrix((A2.data, A1.indices, A1.indptr), shape=A1.shape)  # Newton's: one pattern
    A3 = sp.csr_matrix((A3.data, A1.indices, A1.indptr), shape=A1.shape)
    assert np.count_nonzero(A1.data) < A1.nnz  # explicit zeros in the pattern
    lin = Cholmod()
    for A, analyses in ((A1, 1), (A2, 1), (A3, 2), (A1, 2)):
        x = lin.solve(A, b)  # rtol 0: a factorization of each
        assert np.linalg.norm(A @ x - b) <= 1e-12 * np.linalg.norm(b)
        assert lin.analyses == analyses and lin.is_positive_definite(A)
    assert lin.factorizations == 4 and lin.is_positive_definite(A3)
    kept = lin.analyzed.kept
    assert N < kept.sum() < A1.nnz  # the never-coupled nodes' zeros are left out
    # a third of the nodes in contact: fill 2568 against 3219 with the whole coupling's pattern
    A = two_fields(n, np.arange(N // 3))
    lin_third = Cholmod()
    lin_third.solve(A, b)
    assert lin_third.factor.nnz < 0.85 * cholmod_factor(symmetric_csc(A), "default").nnz
    # CG preconditioned by the kept factor on a matrix of the same pattern
    z = lin.solve(A2, b, rtol=1e-10)
    assert np.linalg.norm(A2 @ z - b) <= 1e-10 * np.linalg.norm(b) and lin.analyses == 2


def test_2d_problems_are_ordered_by_amd_below_the_metis_threshold_and_by_metis_above():
    from nitsche.linalg import METIS_THRESHOLD_2D, make_solver
    assert make_solver("cholmod", METIS_THRESHOLD_2D, dim=2).ordering == "amd"
    assert make_solver("auto", METIS_THRESHOLD_2D + 1, dim=2).ordering == "metis"
    assert make_solver("cholmod", 1000, dim=3).ordering == "default"
    A = laplacian(30)  # METIS's ordering solves as AMD's does
    b = np.arange(A.shape[0], dtype=float)
    x = {o: Cholmod(ordering=o).solve(A, b) for o in ("amd", "metis")}
    assert np.allclose(x["metis"], x["amd"], rtol=1e-12, atol=1e-12)


def test_the_round_off_of_a_cancellation_is_left_out_of_the_factor_and_a_small_coupling_is_not():
    """The P1 Laplacian on right-angled triangles couples the two ends of each diagonal edge
    by 0, which an assembly may hold as round-off (~1e-17 sqrt(a_ii a_jj)): the factor of the
    matrix with that round-off is the five-point one's, while an entry of 1e-10
    sqrt(a_ii a_jj) is a coupling and kept."""
    from skfem import Basis, ElementTriP1, MeshTri, asm
    from skfem.models.poisson import laplace, mass
    basis = Basis(MeshTri().refined(4), ElementTriP1())
    M = asm(mass, basis)  # the nine-point pattern of the triangles' couplings, all nonzero
    K = asm(laplace, basis) + 1e-3 * sp.eye(M.shape[0])
    pattern = (abs(K) + M).tocsr()  # one pattern: every coupling stored
    P = sp.csr_matrix(pattern, copy=True)
    rows = np.repeat(np.arange(P.shape[0]), np.diff(P.indptr))
    P.data = np.asarray(K[rows, P.indices]).ravel()  # K on the nine-point pattern
    cancelled = P.data == 0  # the diagonal edges' couplings of the Laplacian ...
    assert cancelled.sum() > P.shape[0] // 2
    five = P.copy()
    five.eliminate_zeros()
    b = np.random.default_rng(2).normal(size=P.shape[0])
    fill = {}
    for name, scale in (("round-off", 1e-17), ("coupling", 1e-10)):
        A = P.copy()
        d = np.sqrt(A.diagonal())
        A.data[cancelled] = scale * d[rows[cancelled]] * d[A.indices[cancelled]]  # ... as round-off
        lin = Cholmod(ordering="amd")
        x = lin.solve(A, b)
        assert np.linalg.norm(A @ x - b) <= 1e-12 * np.linalg.norm(b)
        fill[name] = lin.factor.nnz
    lin = Cholmod(ordering="amd")
    lin.solve(five, b)
    assert fill["round-off"] == lin.factor.nnz < fill["coupling"]


def test_a_single_precision_factor_preconditions_cg_to_a_direct_solves_accuracy():
    """single=True: the factor in single precision, every solve by CG with it (rtol=0: to
    DIRECT_RTOL), the same solution as the double factor's direct solve; a later matrix by
    CG on the kept factor; is_positive_definite factors in double."""
    from nitsche.linalg import DIRECT_RTOL
    A = laplacian(60)
    b = np.random.default_rng(3).normal(size=A.shape[0])
    single, double = Cholmod(single=True), Cholmod()
    x, y = single.solve(A, b), double.solve(A, b)
    assert single.factor.dtype == np.float32 and double.factor.dtype == np.float64
    assert np.linalg.norm(A @ x - b) <= DIRECT_RTOL * np.linalg.norm(b)
    assert np.abs(x - y).max() <= 1e-10 * np.abs(y).max()
    assert 1 <= single.iterations[0] <= 6 and single.factored is None  # a single factor certifies nothing
    A2 = A.copy()
    rows = np.repeat(np.arange(A.shape[0]), np.diff(A.indptr))
    A2.data[(A2.indices == rows) & (rows % 90 == 0)] += 0.5
    z = single.solve(A2, b, rtol=1e-8)
    assert np.linalg.norm(A2 @ z - b) <= 1e-8 * np.linalg.norm(b) and single.factorizations == 1
    assert single.is_positive_definite(A2) and single.factor.dtype == np.float64 and single.factorizations == 2
    assert single.stats()["factor_precision"] == "single" and double.stats()["factor_precision"] == "double"
    with pytest.raises(IndefiniteHessian):
        Cholmod(single=True).solve(A - 1.0 * sp.eye(A.shape[0]), b)


def test_where_single_precision_does_not_serve_the_solver_factors_in_double():
    """A matrix singular once rounded to single precision (the factorization fails in it),
    and one whose condition number (about 6.5e8: the 1D Laplacian on 40,000 points) leaves
    CG with a single factor short of a direct solve's accuracy in 12 iterations: each solved
    to DIRECT_RTOL by a double factor, which the solver keeps from then on."""
    from nitsche.linalg import DIRECT_RTOL
    near = sp.csc_matrix(np.array([[1.0, 1 - 1e-9], [1 - 1e-9, 1.0]]))
    n = 40_000
    chain = sp.diags([-np.ones(n - 1), 2 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1]).tocsc()
    for A, factorizations in ((near, 1), (chain, 2)):  # (the single factorization failed; made, then CG)
        b = A @ np.ones(A.shape[0])
        lin = Cholmod(single=True)
        x = lin.solve(A, b)
        assert np.linalg.norm(A @ x - b) <= DIRECT_RTOL * np.linalg.norm(b)
        assert lin.factorizations == factorizations and not lin.single and lin.factor.dtype == np.float64
        assert lin.stats()["factor_precision"] == "double"


def test_large_problems_take_a_single_precision_factor():
    from nitsche.linalg import SINGLE_THRESHOLD, make_solver
    assert make_solver("cholmod", SINGLE_THRESHOLD + 1, dim=2).single
    assert not make_solver("auto", SINGLE_THRESHOLD, dim=2).single
    assert make_solver("cholmod", SINGLE_THRESHOLD + 1, dim=3).single


def test_cholmod_prints_nothing_where_a_matrix_is_not_positive_definite(capfd):
    """CHOLMOD's own warning ("not positive definite") is not printed: the solver reports it."""
    import ctypes
    A = laplacian(10) - 2.0 * sp.eye(100)
    assert not Cholmod().is_positive_definite(A)
    ctypes.CDLL(None).fflush(None)  # C's stdout buffer
    out, err = capfd.readouterr()
    assert "CHOLMOD" not in out + err
