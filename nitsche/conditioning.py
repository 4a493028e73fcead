"""Condition numbers of Newton Jacobians (2-norm).

For a symmetric matrix cond = max |lambda| / min |lambda|; for a general one
cond = sigma_max / sigma_min.  Small matrices are done exactly with dense
eigenvalues (singular values); beyond `dense_limit` the extreme eigenvalues are
estimated with ARPACK: the largest in magnitude directly, the smallest by
shift-invert about 0 (one sparse LU factorization), from a seeded start vector: the
estimates are the same run to run.
"""
import functools

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .linalg import (HAVE_CHOLMOD, METIS_THRESHOLD_2D, IndefiniteHessian, cholmod_factor, factor_solve,
                     symmetric_csc)

DENSE_LIMIT = 500
SEED = 0
# Lanczos vectors of the shift-invert for the smallest eigenvalue: the inverse separates it
# well, so 8 (9 solves at 130k unknowns, ARPACK's default 20 took 21) give it to ~1e-13
SHIFT_INVERT_NCV = 8
# ARPACK's relative residual for the largest eigenvalue (singular value).  The top of a
# stiffness spectrum clusters (relative gaps ~ h^2), so a residual of 1e-5 took 1071 Lanczos
# steps (26 s) on the two membranes at 522k unknowns; at 1e-3 101 steps (2.3 s), the Ritz
# value (a lower bound of lambda_max) 1.7e-4 below the 1e-5 one (8e-5 at 130k)
TOL_MAX = 1e-3


def start_vector(n):
    """ARPACK's start vector, seeded (ARPACK's own is random): reproducible estimates."""
    return np.random.default_rng(SEED).standard_normal(n)


def _is_symmetric(A, rtol=1e-10):
    d = A - A.T
    big = abs(A).max() if A.nnz else 0.0
    return (abs(d).max() if d.nnz else 0.0) <= rtol * max(big, 1e-300)


def condition_number(A, dense_limit=DENSE_LIMIT, tol=1e-5, tol_max=TOL_MAX):
    """dict(cond, lambda_min, lambda_max, method, size) of a square matrix A.

    lambda_min / lambda_max are the eigenvalues of smallest and largest magnitude
    (symmetric A, signed: a negative lambda_min reveals an indefinite matrix) or
    the extreme singular values (non-symmetric A); ARPACK's relative residual tolerances:
    tol for the smallest, tol_max for the largest (see TOL_MAX)."""
    A = nonzero_entries(A)
    n = A.shape[0]
    if A.shape != (n, n) or n == 0:
        raise ValueError(f"condition_number needs a non-empty square matrix, got shape {A.shape}")
    symmetric = _is_symmetric(A)
    if n <= dense_limit:
        M = A.toarray()
        if symmetric:
            w = sla.eigvalsh(M)
            a = np.abs(w)
            lo, hi, method = w[np.argmin(a)], w[np.argmax(a)], "dense eigenvalues"
        else:
            s = sla.svdvals(M)
            lo, hi, method = s[-1], s[0], "dense singular values"
    elif symmetric:
        hi = spla.eigsh(A, k=1, which="LM", tol=tol_max, v0=start_vector(n), return_eigenvectors=False)[0]
        inverse = cholesky_inverse(A)
        lo = spla.eigsh(A if inverse is not None else A.tocsc(), k=1, sigma=0.0, which="LM", tol=tol,
                        ncv=min(SHIFT_INVERT_NCV, n - 1),
                        v0=start_vector(n), OPinv=inverse, return_eigenvectors=False)[0]
        method = "ARPACK (shift-invert for the smallest" + (", by a Cholesky factor)" if inverse else ")")
    else:
        hi = spla.svds(A, k=1, which="LM", tol=tol_max, v0=start_vector(n), return_singular_vectors=False)[0]
        lu = spla.splu(A.tocsc())
        inv = spla.LinearOperator((n, n), matvec=lu.solve, rmatvec=lambda v: lu.solve(v, trans="T"),
                                  dtype=float)
        lo = 1.0 / spla.svds(inv, k=1, which="LM", tol=tol, v0=start_vector(n),
                             return_singular_vectors=False)[0]
        method = "ARPACK singular values (inverse by sparse LU)"
    lo, hi = float(lo), float(hi)
    cond = abs(hi) / abs(lo) if lo != 0 else np.inf
    return dict(cond=float(cond), lambda_min=lo, lambda_max=hi, method=method, size=int(n))


def nonzero_entries(A):
    """A new CSR matrix of A's non-zero entries, A left as it is.  A Newton matrix's
    structure holds the exact zeros of terms inactive at this point (the two membranes'
    coupling off their contact set: half of its entries at 522k unknowns): the same
    matrix, half the work of each product and of the factor's fill; only the non-zero
    entries are copied (not all of them first)."""
    A = sp.csr_matrix(A, dtype=float)  # (A itself where it is a CSR matrix of floats)
    keep = A.data != 0
    before = np.zeros(A.nnz + 1, A.indptr.dtype)  # the non-zero entries before each one
    np.cumsum(keep, dtype=A.indptr.dtype, out=before[1:])
    return sp.csr_matrix((A.data[keep], A.indices[keep], before[A.indptr]), shape=A.shape)


def cholesky_inverse(A):
    """A^-1 as a LinearOperator applying CHOLMOD's factor of the symmetric A (the
    shift-invert of ARPACK about 0 for the smallest eigenvalue: at 130k unknowns in 2D a
    fraction of the time and memory of the sparse LU it does otherwise), ordered as the
    Newton solver orders a 2D problem without points: AMD, METIS above
    METIS_THRESHOLD_2D unknowns (the two membranes' Jacobian at 522k: nnz(L) 29.2M against
    AMD's 39.0M, 1 s more); None when A is not positive definite or scikit-sparse is
    missing.  A CSR matrix is factored as its transpose (CSC, no copy: A is symmetric)."""
    if not HAVE_CHOLMOD:
        return None
    try:
        factor = cholmod_factor(symmetric_csc(A), "metis" if A.shape[0] > METIS_THRESHOLD_2D else "amd")
    except IndefiniteHessian:
        return None
    return spla.LinearOperator(A.shape, matvec=functools.partial(factor_solve, factor), dtype=float)


def jacobian_condition(problem, x, **options):
    """Condition number of the Newton Jacobian of a Problem at x, restricted to the
    free unknowns (the matrix Newton's method solves with)."""
    return condition_number(problem.newton_system(x)[2], **options)


def fitted_slope(h, values, skip_coarse=None):
    """Least-squares slope of log(values) against log(h); the coarsest point is left
    out (pre-asymptotic) when there are at least 4 points, unless skip_coarse says
    how many to leave out.  None with fewer than 2 usable points."""
    h, v = np.asarray(h, float), np.asarray(values, float)
    order = np.argsort(-h)
    h, v = h[order], v[order]
    keep = np.isfinite(v) & (v > 0) & (h > 0)
    h, v = h[keep], v[keep]
    skip = (1 if h.size >= 4 else 0) if skip_coarse is None else int(skip_coarse)
    h, v = h[skip:], v[skip:]
    if h.size < 2:
        return None
    return float(np.polyfit(np.log(h), np.log(v), 1)[0])
