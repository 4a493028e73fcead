"""Linear solvers for the Newton systems, behind one interface.

`cholmod`: sparse Cholesky (CHOLMOD through scikit-sparse 0.5 or later), symbolic
analysis once per pattern; the numeric factor of one Newton matrix preconditions CG on
the next ones (they differ only where the active set changed), and a new factorization
is made only when CG needs too many iterations; on large problems the factor is kept in
single precision, as CG's preconditioner only.  `superlu`: SciPy's
sparse LU, the fallback when scikit-sparse is not installed.  `amg`: conjugate
gradients preconditioned by smoothed-aggregation algebraic multigrid (pyamg),
for large and 3D problems.  Non-symmetric Newton matrices (residual terms: Coulomb
friction, theta != 1) take `superlu` (LU with partial pivoting) or `gmres` (GMRES
preconditioned by an incomplete LU, for large 3D problems).
"""
import ctypes
import functools
import hashlib
import os
import warnings
import weakref

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from . import threads
from .ordering import nested_dissection
from .pattern import index_type

try:
    from sksparse.cholmod import CholeskyFactor, CholmodError, CholmodNotPositiveDefiniteError, CholmodWarning
    HAVE_CHOLMOD = True
except ImportError:  # pragma: no cover - depends on the machine (or scikit-sparse < 0.5)
    HAVE_CHOLMOD = False

AMG_THRESHOLD_3D = 50_000  # 'auto' switches to AMG-CG above this many unknowns in 3D (P1 tetrahedra,
# membrane-solid: AMG-CG 0.5x CHOLMOD's CPU time at 71k and 149k, 0.8x at 27k)
METIS_THRESHOLD_2D = 300_000  # CHOLMOD orders 2D problems by METIS above this many unknowns, by AMD below
ROUNDOFF_ENTRY = 1e-14  # |a_ij| below this times sqrt(|a_ii a_jj|): the round-off of a cancellation (NonzeroPattern)
GEOMETRIC_THRESHOLD_2D = 50_000  # above this many unknowns in 2D (5000 in 3D): nested dissection
GEOMETRIC_THRESHOLD_3D = 5_000   # of the dofs' points (nitsche.ordering) where the solver has them
# (prepare), else the orderings above; but METIS up to METIS_KEPT_2D (its smaller factor keeps
# the 523k obstacle's peak at 1.5x the linear solve's)
METIS_KEPT_2D = 750_000
SINGLE_THRESHOLD = 100_000  # above this many unknowns CHOLMOD's factor is made in single precision,
# the preconditioner of CG (the two membranes' first 1M Newton matrix: the factorization 0.93
# against 1.54 s in double, a solve 0.090 against 0.139 s, the factor 342 against 597 MB; the
# same CG iterations per Newton step); the chains at 130k 5-11 % faster than in double, at 33k
# no faster
DIRECT_RTOL = 1e-12  # solve(rtol=0) with a single-precision factor: CG to this relative residual


class IndefiniteHessian(RuntimeError):
    """The Newton matrix is not positive definite (or is singular)."""


class NotSolved(RuntimeError):
    """An iterative solve did not reach its tolerance."""


def silence_cholmod():
    """CHOLMOD prints its warnings on stdout (a matrix not positive definite, an answer the
    solvers here expect and report): SuiteSparse's print function set to none (read from
    the loaded libsuitesparseconfig; nothing where /proc is missing)."""
    try:
        with open("/proc/self/maps") as fh:
            paths = {line.split()[-1] for line in fh if "libsuitesparseconfig" in line}
    except OSError:  # pragma: no cover - not Linux
        return
    for path in paths:
        ctypes.CDLL(path).SuiteSparse_config_printf_func_set(None)


if HAVE_CHOLMOD:
    silence_cholmod()


def cholmod_factor(A, ordering="amd", beta=0.0):
    """CHOLMOD's factor L L^T = P (A + beta I) P^T of the symmetric CSC matrix A (its lower
    triangle read), in A's precision; IndefiniteHessian where A + beta I is not positive
    definite."""
    try:
        factor = CholeskyFactor(A, lower=True, order=ordering)
        return factor.factorize(A, beta=beta)
    except CholmodNotPositiveDefiniteError as e:
        raise IndefiniteHessian(str(e))


def values_in(A, dtype):
    """The CSC matrix A with its values in dtype (A itself where they are; else the values
    alone copied, the index arrays shared)."""
    if A.dtype == dtype:
        return A
    return sp.csc_matrix((A.data.astype(dtype), A.indices, A.indptr), shape=A.shape, copy=False)


def factor_solve(factor, b):
    """x = A^-1 b with CHOLMOD's factor of A, in b's precision (the factor's dtype inside).
    CHOLMOD's solve warns where its rough reciprocal condition (min diag L / max diag L)^2 is
    below n eps: not an error here (the Newton solver tests its own residuals)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CholmodWarning)
        return factor.solve(b.astype(factor.dtype, copy=False)).astype(b.dtype, copy=False)


def positive_diagonal(A):
    """A matrix with a non-positive diagonal entry is not positive definite."""
    d = A.diagonal()
    if not np.all(d > 0):
        i = int(np.argmin(np.where(np.isfinite(d), d, -np.inf)))
        raise IndefiniteHessian(f"diagonal entry {i} of the Newton matrix is {d[i]:.3g}")


class Cholmod:
    """Sparse Cholesky with factor reuse.

    solve(A, b, rtol): the first matrix is factored (symbolic analysis once); a later
    matrix is solved by CG preconditioned with the last factor, to the relative
    residual rtol, when that takes at most `reuse_iterations` iterations (the Newton
    matrices of J_h differ only on the points whose active state changed, a
    low-rank change); otherwise, or when CG needed more than half of them, it is
    factored anew.  rtol=0 asks for a direct solve.

    single: the factor is made in single precision (half the factor's memory traffic in
    each solve, a cheaper factorization) and serves only as CG's preconditioner: a
    matrix just factored is solved by CG too, to rtol (DIRECT_RTOL for rtol=0).  Where
    single precision does not serve (the factorization fails in it, or CG with a fresh
    factor needs more than half of `reuse_iterations`: a condition number near 1/eps of
    single precision), the solver factors in double from then on.

    prune: the factorization is given the entries significant in some matrix factored so
    far on the same pattern (NonzeroPattern); a caller whose matrices hold only entries
    significant in some earlier matrix (Problem's Newton matrices: the problem keeps them)
    sets it False, and each matrix is factored on its own pattern as it is.

    keep_factored: a copy of the factored matrix's values is kept, for is_positive_definite's
    test without a new factorization and solve's test for that same matrix (a direct
    solve); a caller that will not ask is_positive_definite (newton where J_h is
    certified convex) sets it False, and saves the copy (one value per pattern entry:
    56 MB for the two membranes at 522k unknowns).  Only a double-precision factor
    certifies: is_positive_definite factors in double.

    The fill-reducing ordering: CHOLMOD's `ordering` method, or, with geometric=True and
    the free dofs' coordinates from prepare(problem) (`coordinates`: computed for each
    analysis, not held beside the factor), a geometric nested dissection
    (nitsche.ordering): the factor is then that of P A P^T (its lower triangle, read from
    A's), and a solve x = P^T L^-T L^-1 P b."""
    name = "cholmod"

    def __init__(self, reuse_iterations=25, ordering="default", geometric=False, single=False):
        self.symbolic = self.factor = self.factored = None  # the analysis; the numeric factor
        self.keep_factored, self.prune = True, True
        self.ordering, self.geometric, self.single = ordering, geometric, single
        self.coordinates = self.perm = None  # () -> the free dofs' points; the nested dissection's order
        self.reordered = None  # with perm: P A P^T's lower triangle, its values positions in A.data
        self.reuse_iterations, self.stale = reuse_iterations, False
        self.factorizations, self.iterations, self.analyses = 0, [], 0
        self.analyzed = None  # the NonzeroPattern of the symbolic analysis

    def prepare(self, problem):
        if self.geometric:
            self.coordinates = functools.partial(dof_coordinates, problem)

    def _analyze(self, A):
        """The symbolic analysis of A on the analyzed entries: ordered by CHOLMOD, or by
        nested dissection of the dofs' points (`reordered`: the permuted lower triangle's
        pattern, its entries' positions in A.data)."""
        given = self.analyzed.part(A)
        points = self.coordinates() if self.coordinates else None
        if points is None or len(points) != A.shape[0]:  # (points of another problem)
            self.perm = None
            self.symbolic = CholeskyFactor(given, lower=True, order=self.ordering)
        else:
            self.perm = nested_dissection(given, points)
            self.reordered = permuted_lower(given, self.perm)
            if not self.analyzed.all:
                kept = np.flatnonzero(self.analyzed.kept).astype(index_type(A.data.size))
                self.reordered.data = kept[self.reordered.data]
            self.symbolic = CholeskyFactor(self._given(A), lower=True, order="natural")
        self.analyses += 1

    def _given(self, A):
        """The matrix factored: A on the analyzed entries, reordered when perm is set."""
        if self.perm is None:
            return self.analyzed.part(A)
        R = self.reordered
        return sp.csc_matrix((A.data[R.data], R.indices, R.indptr), shape=A.shape, copy=False)

    def _solve(self, b):
        """x = A^-1 b with the factor of A (of P A P^T: x[perm] = (P A P^T)^-1 b[perm])."""
        try:
            if self.perm is None:
                return factor_solve(self.factor, b)
            x = np.empty_like(b)
            x[self.perm] = factor_solve(self.factor, b[self.perm])
            return x
        except CholmodError as e:  # a zero pivot the factorization let through
            raise IndefiniteHessian(str(e))

    def _factor(self, A, single=None):
        """A new numeric factor of A, from a copy of the symbolic analysis (a factor that
        scikit-sparse turned simplicial, as a build other than `make cholmod`'s does, would be
        factored again by CHOLMOD's slow simplicial method), in single precision where
        `single` (the solver's choice by default); the last factor is released first."""
        single = self.single if single is None else single
        self.factor = self.factored = None
        try:
            if self.analyzed is None or not self.analyzed.holds(A):
                self.analyzed = NonzeroPattern(A, self.analyzed, self.prune)
                self.symbolic = None
            if self.symbolic is None:
                self._analyze(A)  # (a matrix without entries is not positive definite)
            factor = self.symbolic.copy()
            with threads.factorization():
                factor.factorize(values_in(self._given(A), np.float32 if single else np.float64))
        except CholmodNotPositiveDefiniteError as e:
            if not single or self.symbolic is None:
                raise IndefiniteHessian(str(e))
            self.single = False  # perhaps not positive definite by round-off in single precision
            return self._factor(A)
        self.factor = factor
        self.factored = kept_values(A) if self.keep_factored and not single else None
        self.factorizations += 1
        self.stale = False

    def solve(self, A, b, rtol=0.0):
        A = symmetric_csc(A)
        if self.factored is not None and semidefinite_difference(A, self.factored, zero=True):
            return self._solve(b)  # same matrix as the factored one
        if self.factor is not None and rtol > 0 and not self.stale:
            x, its = pcg(A, b, self._solve, rtol, self.reuse_iterations)
            if x is not None:
                self.iterations.append(its)
                self.stale = its > self.reuse_iterations // 2
                return x
        self._factor(A)
        if self.factor.dtype == np.float64:
            return self._solve(b)
        x, its = pcg(A, b, self._solve, rtol or DIRECT_RTOL, self.reuse_iterations // 2)
        if x is None:  # a condition number beyond single precision's preconditioner
            self.single = False
            self._factor(A)
            return self._solve(b)
        self.iterations.append(its)
        return x

    def is_positive_definite(self, A):
        """Whether A is positive definite: True without a new factorization when A = F + D,
        F the factored matrix and D positive semidefinite (then A >= F > 0; see
        semidefinite_difference), else a new double-precision factorization of A (one
        numeric factorization: the symbolic analysis is kept)."""
        A = symmetric_csc(A)
        if self.factored is not None and semidefinite_difference(A, self.factored):
            return True
        try:
            self._factor(A, single=False)
        except IndefiniteHessian:
            return False
        return True

    def stats(self):
        return dict(factorizations=self.factorizations, cg_iterations=list(self.iterations),
                    analyses=self.analyses, factor_precision="single" if self.single else "double")


class NonzeroPattern:
    """The entries of a sparse pattern that the factorization is given: those significant in
    some matrix factored so far on it, and the diagonal (prune False: all of them).  The
    Hessians of J_h share one pattern (every term's element couplings; Problem's Newton
    matrices are already pruned, see Problem._admit), in which the terms of the points off
    the active set hold exact zeros (e.g. the coupling of two membranes off their contact
    set, half of the entries at 130k unknowns) and cancellations hold round-off (the
    diagonal edges of right-angled P1 triangles: |a_ij| ~ 1e-17 sqrt(a_ii a_jj)); their
    fill costs a factorization and every solve with it (two membranes at 130k: nnz(L) 14.2M
    with the zeros, 7.9M without; the obstacle's 9.67M with the round-off, 5.6M without).
    An entry is significant where |a_ij| > ROUNDOFF_ENTRY sqrt(|a_ii a_jj|); the factor is
    then that of a matrix within ROUNDOFF_ENTRY * (entries per row) of A after diagonal
    scaling, the accuracy of a factorization of A itself.  The kept entries only grow: a matrix with a significant
    entry outside them (a point entered the active set) makes a new symbolic analysis of the
    union."""

    def __init__(self, A, before=None, prune=True):
        self.arrays = (weakref.ref(A.indptr), weakref.ref(A.indices))  # (not held: see same_pattern)
        self.digest = pattern_digest(A)
        kept = significant(A) if prune else None
        if kept is not None and before is not None and before.same_pattern(A):
            kept = None if before.all else kept | before.kept  # (the union with the earlier ones)
        self.all = kept is None or bool(kept.all())
        self.kept = None if self.all else kept  # (None: all of them)
        if not self.all:  # (else part() is A itself)
            self.kept_indices = A.indices[kept]
            self.kept_indptr = np.concatenate([[0], np.cumsum(kept)])[A.indptr].astype(A.indptr.dtype)

    def same_pattern(self, A):
        """Whether A has the analyzed pattern: its index arrays themselves, or equal ones (by
        their digest: the analyzed arrays are not kept alive, so that a Newton matrix's
        structure that grew is freed once replaced, 35 MB of the two membranes at 1M)."""
        indptr, indices = (ref() for ref in self.arrays)
        return (A.indptr is indptr and A.indices is indices) or pattern_digest(A) == self.digest

    def holds(self, A):
        """Whether A has this pattern and no significant entry outside the kept entries."""
        return self.same_pattern(A) and (self.all or not np.any(significant(A) & ~self.kept))

    def part(self, A):
        """A on the kept entries (A itself where all are kept): the same matrix."""
        if self.all:
            return A
        return sp.csc_matrix((A.data[self.kept], self.kept_indices, self.kept_indptr),
                             shape=A.shape, copy=False)


def pattern_digest(A):
    """A digest of a compressed sparse matrix's shape and index arrays (equal patterns, equal
    digests; BLAKE2b: a collision is out of reach)."""
    h = hashlib.blake2b(repr((A.shape, A.indptr.dtype.str, A.indices.dtype.str)).encode(), digest_size=32)
    h.update(np.ascontiguousarray(A.indptr))
    h.update(np.ascontiguousarray(A.indices))
    return h.digest()


def row_blocks(indptr, entries=2 ** 20):
    """(first, end) of blocks of consecutive rows (columns of a CSC matrix) of about
    `entries` stored entries each, by the compressed pointers indptr."""
    cuts = np.unique(np.searchsorted(indptr, np.arange(0, indptr[-1], entries), side="right") - 1)
    return zip(cuts, np.append(cuts[1:], indptr.size - 1))


def significant(A, entries=2 ** 20):
    """Of each stored entry of a CSC matrix: on the diagonal, or |a_ij| > ROUNDOFF_ENTRY
    sqrt(|a_ii a_jj|) (not zero, nor the round-off of a cancellation); by blocks of columns
    of about `entries` entries (the temporaries of a block, not of the matrix)."""
    d = np.sqrt(np.abs(A.diagonal()))
    keep = np.empty(A.nnz, bool)
    for c0, c1 in row_blocks(A.indptr, entries):
        block = slice(A.indptr[c0], A.indptr[c1])
        columns = np.repeat(np.arange(c0, c1), np.diff(A.indptr[c0:c1 + 1]))
        rows = A.indices[block]
        keep[block] = is_significant(A.data[block], rows, columns, d)
    return keep


def is_significant(values, rows, columns, d):
    """Of entries a_ij (values at rows i, columns j): on the diagonal, or |a_ij| >
    ROUNDOFF_ENTRY d_i d_j, d = sqrt(|diag A|)."""
    scale = d[rows]
    scale *= d[columns]
    scale *= ROUNDOFF_ENTRY
    return (np.abs(values) > scale) | (rows == columns)


def permuted_lower(A, perm):
    """The lower triangle of P A P^T (P A P^T = A[perm][:, perm]) as CSC, taken from A's lower
    triangle (a CSC matrix: the triangle CHOLMOD reads), its values the positions in A.data
    (32-bit where they fit)."""
    new = np.empty(perm.size, dtype=np.int64)
    new[perm] = np.arange(perm.size)
    columns = column_indices(A)
    k = np.flatnonzero(A.indices >= columns)
    i, j = new[A.indices[k]], new[columns[k]]
    return sp.csc_matrix((k.astype(index_type(A.data.size)), (np.maximum(i, j), np.minimum(i, j))),
                         shape=A.shape)


def column_indices(A):
    """The column of every stored entry of a CSC matrix (its row: A.indices)."""
    return np.repeat(np.arange(A.shape[1]), np.diff(A.indptr))


def kept_values(A):
    """A CSC matrix equal to A that keeps a copy of A's values and A's own index arrays
    (the Newton matrices of a problem share theirs, and nothing writes into them): the
    factored matrix for semidefinite_difference, without a second copy of its pattern."""
    return sp.csc_matrix((A.data.copy(), A.indices, A.indptr), shape=A.shape, copy=False)


def symmetric_csc(A):
    """The symmetric matrix A in CSC form for CHOLMOD, which reads its lower triangle: a CSR
    matrix's transpose, the same arrays (no conversion, no copy; its lower triangle is A's
    upper one, equal to A's to round-off for a Hessian assembled symmetric to round-off)."""
    return A.T if A.format == "csr" else A.tocsc()


def semidefinite_difference(A, F, zero=False):
    """Whether D = A - F is positive semidefinite (zero: whether D = 0, False without a test
    where the patterns differ), A and F CSC matrices (A's pattern may have grown since F's:
    Problem's Newton matrices keep the entries significant so far).  Between Newton
    matrices of J_h, D is the change of the terms whose state changed (a point entering the
    active set adds the rank-one
    alpha (lambda' - g'/alpha)(lambda' - g'/alpha)^T), supported on the rows S of
    those points' dofs; D_SS + eps I is tested by a Cholesky factorization of that
    small block, eps = 1e-14 max |diag A|, the accuracy of a Cholesky test of A itself.
    False without a test when D is not small (more than 1/16 of the entries changed, e.g.
    a nonlinear energy): factoring A is then the cheaper test."""
    if np.array_equal(A.indptr, F.indptr) and np.array_equal(A.indices, F.indices):
        changed = np.flatnonzero(A.data != F.data)
        rows, columns, values = A.indices[changed], column_indices(A)[changed], A.data[changed] - F.data[changed]
    elif zero:
        return False
    else:
        D = (A - F).tocoo()
        changed = np.flatnonzero(D.data)
        rows, columns, values = D.row[changed], D.col[changed], D.data[changed]
    if values.size == 0 or zero:
        return values.size == 0
    if values.size > A.data.size // 16:
        return False
    S, local = np.unique(np.concatenate([rows, columns]), return_inverse=True)
    D = sp.csc_matrix((values, (local[:rows.size], local[rows.size:])), shape=(S.size, S.size))
    eps = 1e-14 * np.abs(A.diagonal()).max()
    try:
        cholmod_factor(D, beta=eps)
    except IndefiniteHessian:
        return False
    return True


def pcg(A, b, M, rtol, maxiter):
    """Preconditioned conjugate gradients from zero: (x, iterations) once
    |b - A x| <= rtol |b|, (None, maxiter) if not reached.  A direction of
    non-positive curvature raises IndefiniteHessian."""
    x, r = np.zeros_like(b), b.copy()
    if not r.any():
        return x, 0
    z = M(r)
    p, rz, stop = z.copy(), r @ z, rtol * np.linalg.norm(b)
    for it in range(1, maxiter + 1):
        Ap = A @ p
        curvature = p @ Ap
        if not curvature > 0:
            raise IndefiniteHessian("CG preconditioned by the previous factor found a direction "
                                    "of non-positive curvature")
        step = rz / curvature
        x += step * p
        r -= step * Ap
        if np.linalg.norm(r) <= stop:
            return x, it
        z = M(r)
        rz, rz_old = r @ z, rz
        p = z + (rz / rz_old) * p
    return None, maxiter


class SuperLU:
    name = "superlu"

    def __init__(self):
        self.factorizations = 0

    def stats(self):
        return dict(factorizations=self.factorizations)

    def solve(self, A, b, rtol=0.0):
        self.factorizations += 1
        try:
            x = spla.splu(A.tocsc()).solve(b)
        except RuntimeError as e:  # "Factor is exactly singular"
            raise IndefiniteHessian(f"singular Newton matrix ({e})")
        if not np.all(np.isfinite(x)):
            raise IndefiniteHessian("singular Newton matrix")
        return x

    def is_positive_definite(self, A):
        """Whether A is positive definite: the signs of the pivots of an LU without row
        pivoting (symmetric ordering, P A P^T = L D L^T, U = D L^T), by Sylvester's law."""
        self.factorizations += 1
        try:
            lu = spla.splu(A.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                           options=dict(SymmetricMode=True))
        except RuntimeError:  # a zero pivot: singular
            return False
        return bool(np.array_equal(lu.perm_r, lu.perm_c) and np.all(lu.U.diagonal() > 0))


class AMGCG:
    """CG preconditioned by one V-cycle of smoothed-aggregation AMG.

    With `prepare(problem)` the near-nullspace of the aggregation is the rigid-body
    modes of every vector field and the constants of every scalar field (free dofs),
    which makes elasticity converge in a few iterations.  The hierarchy is reused
    across Newton steps (the Hessians differ only on the active contact set): its finest
    level is set to each new matrix (`refresh`: S A S with the build's S; P, R and the
    coarser levels kept), and CG with it may take at most rebuild_factor * rate * d + slack
    iterations for d decades of residual reduction, rate the iterations per decade of the
    first whole solve with the current hierarchy, slack about one set-up's cost in CG
    iterations; past that limit the hierarchy is built on the new matrix and
    CG goes on from where it stopped (the next solve then measures rate: the few
    iterations that finish a solve do not).

    The hierarchy: pyamg's smoothed aggregation of the diagonally scaled matrix
    A' = S A S, S = diag(A)^-1/2 (candidates S^-1 B), and the preconditioner
    M r = S V(S r), V one V-cycle of A' (`vcycle`).  On A' the Jacobi prolongation
    smoother (I - omega / rho(D^-1 A) D^-1 A) T of A is Richardson's,
    (I - omega / rho(A') A') T', with rho(A') = rho(D^-1 A) from a symmetric Lanczos
    (`lanczos_largest`) instead of pyamg's restarted Arnoldi on D^-1 A; Gauss-Seidel
    is invariant under the scaling.  The candidates are taken as given (no relaxation
    sweeps to improve them: the rigid-body modes are already the near-nullspace); on
    the finest level the matrix itself is the strength of connection (the same
    aggregates as pyamg's symmetric measure at theta = 0, without computing it; the
    coarser levels, block matrices, keep that measure on their blocks).  The hierarchy
    is built in double precision and then kept and applied in `dtype` (single by
    default: half the memory traffic of each V-cycle; CG itself stays in double).
    pyamg_options: other keyword arguments of pyamg.smoothed_aggregation_solver instead."""
    name = "amg"
    SMOOTHER = ("block_gauss_seidel", {"sweep": "symmetric"})

    @staticmethod
    def options():
        """pyamg.smoothed_aggregation_solver's options (a new list each time: pyamg extends
        the per-level list it is given): Richardson on the scaled finest level, Jacobi below."""
        return dict(symmetry="symmetric", improve_candidates=None,
                    strength=[(None, {}), ("symmetric", {"theta": 0.0})],
                    smooth=[("richardson", {"omega": 4.0 / 3.0}), ("jacobi", {"omega": 4.0 / 3.0})],
                    presmoother=AMGCG.SMOOTHER, postsmoother=AMGCG.SMOOTHER)

    def __init__(self, rtol=1e-10, maxiter=2000, rebuild_factor=2.0, slack=20, pyamg_options=None,
                 dtype=np.float32):
        # a new hierarchy costs about 25 CG iterations (3D elasticity, P1 tetrahedra: 2.8 s
        # against 0.11 s CPU per iteration at 203k unknowns, 20.7 s against 0.78 s at 1.16M);
        # a refreshed one took a new one's iterations on the later Newton matrices at 203k
        # (3, 4, 5, 8, 19), at 1.16M 67 in all against 58 with a second set-up
        self.rtol, self.maxiter, self.rebuild_factor, self.slack = rtol, maxiter, rebuild_factor, slack
        self.pyamg_options, self.dtype = pyamg_options, np.dtype(dtype)  # pyamg_options None: options()
        self.B, self.ml, self.rate, self.s = None, None, None, None
        self.iterations, self.setups = [], 0

    def prepare(self, problem):
        self.B = near_nullspace(problem)

    def stats(self):
        return dict(amg_setups=self.setups, cg_iterations=list(self.iterations))

    def _build(self, A):
        import pyamg
        from pyamg.util.utils import scale_columns, scale_rows
        options = self.pyamg_options or self.options()
        s = 1.0 / np.sqrt(A.diagonal())
        scaled = scale_columns(scale_rows(type(A)((A.data.copy(), A.indices, A.indptr), shape=A.shape),
                                          s, copy=False), s, copy=False)
        scaled.rho = lanczos_largest(scaled)  # read by pyamg's spectral radius estimate
        B = self.B if self.B is not None and self.B.shape[0] == A.shape[0] else np.ones((A.shape[0], 1))
        self.ml = pyamg.smoothed_aggregation_solver(scaled, B=B / s[:, None], **options)
        del scaled
        self.s = s
        in_precision(self.ml, self.dtype, options.get("presmoother", self.SMOOTHER),
                     options.get("postsmoother", self.SMOOTHER))
        ml, dtype = self.ml, self.dtype
        self.M = spla.LinearOperator(A.shape, lambda r: s * vcycle(ml, (s * np.ravel(r)).astype(dtype)),
                                     dtype=np.float64)
        self.rate = None
        self.setups += 1

    def refresh(self, A):
        """The hierarchy's finest level set to S A S in its precision, S = diag(A_0)^-1/2 of
        the matrix A_0 it was built on (its smoother, Gauss-Seidel on a CSR level, reads the
        level's matrix at each sweep; P, R and the coarser levels are kept): M r = S V(S r) stays symmetric positive
        definite for a positive definite A, and its smoothing is that of A itself where A
        differs from A_0 (the contact's rows)."""
        from pyamg.util.utils import scale_columns, scale_rows
        scaled = scale_columns(scale_rows(type(A)((A.data.copy(), A.indices, A.indptr), shape=A.shape),
                                          self.s, copy=False), self.s, copy=False)
        self.ml.levels[0].A = type(A)((scaled.data.astype(self.dtype), A.indices, A.indptr),
                                      shape=A.shape)

    def _cg(self, A, b, tol, x0=None, maxiter=None):
        count = [0]
        x, info = spla.cg(A, b, x0=x0, rtol=tol, maxiter=maxiter or self.maxiter, M=self.M,
                          callback=lambda xk: count.__setitem__(0, count[0] + 1))
        return x, info, count[0]

    def is_positive_definite(self, A, iterations=40):
        """Whether A looks positive definite: LOBPCG (AMG-preconditioned, seeded start)
        estimates its smallest eigenvalue from above; an estimate <= 0 proves A is not
        positive definite, a positive one is evidence, not proof."""
        A = A.tocsr()
        try:
            positive_diagonal(A)
        except IndefiniteHessian:
            return False
        if self.ml is None or self.ml.levels[0].A.shape != A.shape:
            self._build(A)
        else:
            self.refresh(A)
        return bool(lowest_eigenvalue(A, self.M, iterations) > 0)

    def solve(self, A, b, rtol=0.0):
        A = A.tocsr()
        positive_diagonal(A)
        tol = max(rtol, self.rtol)  # Newton's forcing term, not below our own rtol
        decades = -np.log10(tol)
        x, its, stale = None, 0, False
        if self.ml is not None and self.ml.levels[0].A.shape == A.shape:
            limit = (int(self.rebuild_factor * self.rate * decades) + self.slack
                     if self.rate is not None else self.maxiter)  # (built by is_positive_definite or midway)
            self.refresh(A)
            x, info, its = self._cg(A, b, tol, maxiter=limit)
            stale = info != 0
        if x is None or stale:  # no hierarchy yet, or a stale one: build on A, go on from x
            self._build(A)
            x, info, fresh = self._cg(A, b, tol, x0=x)
            its += fresh
        if self.rate is None and not stale:
            self.rate = max(its, 1) / decades
        self.iterations.append(its)
        if info != 0:
            raise NotSolved(f"AMG-preconditioned CG did not converge in {self.maxiter} iterations")
        if not np.all(np.isfinite(x)) or b @ x <= 0 < b @ b:
            raise IndefiniteHessian("CG found a direction of non-positive curvature")
        return x


def lanczos_largest(A, steps=20):
    """The largest Ritz value of `steps` Lanczos steps (no reorthogonalization) on the
    symmetric A from a seeded start: an estimate from below of its largest eigenvalue
    (the extreme Ritz values converge first)."""
    v = np.random.default_rng(0).standard_normal(A.shape[0])
    v /= np.linalg.norm(v)
    v_old, alpha, beta = np.zeros_like(v), [], [0.0]
    for _ in range(min(steps, A.shape[0])):
        w = A @ v - beta[-1] * v_old
        alpha.append(w @ v)
        w -= alpha[-1] * v
        beta.append(np.linalg.norm(w))
        if beta[-1] <= 1e-12 * abs(alpha[-1]):
            break
        v_old, v = v, w / beta[-1]
    return float(np.linalg.eigvalsh(np.diag(alpha) + np.diag(beta[1:len(alpha)], 1)
                                    + np.diag(beta[1:len(alpha)], -1))[-1])


def in_precision(ml, dtype, presmoother, postsmoother):
    """The pyamg hierarchy ml with its operators A, P, R in dtype (the same sparsity
    arrays) and its smoothers set up again on them (block Gauss-Seidel's inverted
    diagonal blocks in dtype)."""
    from pyamg.relaxation.smoothing import change_smoothers
    for level in ml.levels:
        for name in ("A", "P", "R"):
            M = getattr(level, name, None)
            if M is not None and M.dtype != dtype:
                setattr(level, name, type(M)((M.data.astype(dtype), M.indices, M.indptr), shape=M.shape))
    change_smoothers(ml, presmoother, postsmoother)


def vcycle(ml, b):
    """One V-cycle of the pyamg hierarchy ml from zero on A_0 x = b (b in the hierarchy's
    precision): pre-smoothing, the correction P_k x_(k+1) with x_(k+1) the next level's
    cycle on R_k (b - A_k x) (the coarsest level: its solver), post-smoothing.  pyamg's
    own cycle (MultilevelSolver.solve) adds two residuals of the finest level to each
    application."""
    def cycle(k, b):
        level = ml.levels[k]
        if k == len(ml.levels) - 1:
            return np.asarray(ml.coarse_solver(level.A, b), dtype=b.dtype).ravel()
        x = np.zeros_like(b)
        level.presmoother(level.A, x, b)
        x += level.P @ cycle(k + 1, level.R @ (b - level.A @ x))
        level.postsmoother(level.A, x, b)
        return x
    return cycle(0, b)


class GMRES:
    """Restarted GMRES preconditioned by SuperLU's incomplete LU (spilu) of each matrix."""
    name = "gmres"

    def __init__(self, maxiter=2000, drop_tol=1e-4, fill_factor=10):
        self.maxiter, self.drop_tol, self.fill_factor = maxiter, drop_tol, fill_factor
        self.factorizations, self.iterations = 0, []

    def stats(self):
        return dict(factorizations=self.factorizations, gmres_iterations=self.iterations)

    def solve(self, A, b, rtol=0.0):
        A = A.tocsc()
        try:
            ilu = spla.spilu(A, drop_tol=self.drop_tol, fill_factor=self.fill_factor)
        except RuntimeError as e:
            raise IndefiniteHessian(f"singular Newton matrix ({e})")
        self.factorizations += 1
        count = [0]
        x, info = spla.gmres(A, b, M=spla.LinearOperator(A.shape, ilu.solve), rtol=max(rtol, 1e-12),
                             atol=0.0, restart=100, maxiter=self.maxiter,
                             callback=lambda _: count.__setitem__(0, count[0] + 1),
                             callback_type="pr_norm")
        self.iterations.append(count[0])
        if info != 0:
            raise NotSolved(f"GMRES did not reach {rtol:.1e} in {count[0]} iterations")
        return x


def lowest_eigenvalue(A, M, iterations=40):
    """An estimate from above of the smallest eigenvalue of the symmetric A: LOBPCG
    preconditioned by M from a seeded random start (a value <= 0 proves A is not positive
    definite; a positive one is evidence)."""
    X = np.random.default_rng(0).standard_normal((A.shape[0], 1))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # LOBPCG warns when it stops at maxiter
        return float(spla.lobpcg(A, X, M=M, largest=False, tol=1e-3, maxiter=iterations)[0][0])


def dof_coordinates(problem):
    """The free dofs' locations (free dofs, dim) from the fields' dof bases (a field of a
    lower dimension padded with zeros), None if a field's element has none."""
    fields = problem.fields
    if not all(hasattr(f.dof_basis, "doflocs") for f in fields):
        return None
    dim = max(f.dof_basis.doflocs.shape[0] for f in fields)
    X = np.zeros((problem.ndofs, dim))
    for f in fields:
        x = f.dof_basis.doflocs
        X[problem.offsets[f.name]:problem.offsets[f.name] + f.ndofs, :x.shape[0]] = x.T
    return X[problem.free]


def near_nullspace(problem):
    """Columns spanning the near-nullspace of the energy on the free dofs: for each
    vector Lagrange field its rigid-body modes (translations and rotations about the
    origin), for each scalar field the constant (other fields: zero there)."""
    from skfem import ElementVector
    cols = []
    for f in problem.fields:
        off, n, d = problem.offsets[f.name], f.ndofs, f.mesh.dim()
        if isinstance(f.element, ElementVector) and f.is_lagrange:
            j = np.arange(n)
            comp, X = j % d, f.dof_basis.doflocs
            for i in range(d):
                v = np.zeros(problem.ndofs)
                v[off + j[comp == i]] = 1.0
                cols.append(v)
            for a, b in ((0, 1), (1, 2), (0, 2))[:1 if d == 2 else 3]:
                v = np.zeros(problem.ndofs)
                v[off + j[comp == a]] = -X[b, comp == a]
                v[off + j[comp == b]] = X[a, comp == b]
                cols.append(v)
        else:
            v = np.zeros(problem.ndofs)
            v[off:off + n] = 1.0
            cols.append(v)
    return np.ascontiguousarray(np.array(cols).T[problem.free])


def describe():
    """Which direct solver is used and the BLAS it runs on (from the loaded libraries)."""
    if not HAVE_CHOLMOD:
        return "SciPy SuperLU (scikit-sparse 0.5 or later not installed)"
    try:
        with open("/proc/self/maps") as fh:
            libs = {line.split()[-1] for line in fh if "blas" in line}
        blas = "OpenBLAS" if any("openblas" in lib for lib in libs) else "reference BLAS"
    except OSError:
        blas = "BLAS unknown"
    return (f"CHOLMOD ({blas}, OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}, "
            f"factorizations on {threads.factorization_threads()} threads)")


SOLVERS = {"cholmod": Cholmod, "superlu": SuperLU, "amg": AMGCG, "gmres": GMRES}
NONSYMMETRIC = ("superlu", "gmres")


def make_solver(name="auto", n=0, dim=2, symmetric=True):
    """A solver by name; 'auto' is CHOLMOD (SuperLU without scikit-sparse), AMG-CG for large 3D;
    for a non-symmetric problem SuperLU's LU, GMRES-ILU for large 3D.
    CHOLMOD orders problems of more than GEOMETRIC_THRESHOLD_2D unknowns in 2D (_3D in 3D)
    by a nested dissection of the free dofs' points (nitsche.ordering; newton() gives them
    through prepare(problem)): near METIS's fill for AMD's analysis time.  Measured on K + M
    of P1 (benchmarks/ordering.py, CPU s of the analysis + one factorization, nnz(L);
    geometric / AMD / METIS): the obstacle's mesh at 130k 0.45 / 0.49 / 0.94 s, 7.6 / 9.7 /
    6.8M; 523k 2.0 / 2.8 / 4.4 s, 34.9 / 48.2 / 31.3M; 1M 3.5 / 3.5 / 8.5 s, 65.8 / 74.0 /
    64.5M (its factorization 2.3 / 3.0 / 2.9 s); tetrahedra at 55k 0.94 / 1.92 / 1.34 s,
    19.1 / 31.4 / 19.3M, at 6.9k 0.052 / 0.059 / 0.081 s; in 2D at 33k it ties with AMD
    (0.10 s, nnz(L) 1.6M against 2.0M) and below it AMD is cheaper.  From METIS_THRESHOLD_2D
    to METIS_KEPT_2D unknowns METIS stays: the chain at 523k is 13-15 % less CPU with the
    geometric order but its peak 69-95 MB higher (obstacle 1460 MB against 1365, above the
    1.5x of the linear solve's); at 1M the chain's solves take 7.6-8.0 s against 11.9-12.1
    s by METIS, the peak the same.  Without the points (a solver made without
    prepare) 2D problems are ordered by AMD up to METIS_THRESHOLD_2D unknowns and by METIS
    above it (a smaller factor than AMD's for a longer analysis: 2.4 s more at 523k, 5.1 s at
    1M), 3D ones by CHOLMOD's default (AMD, METIS when the fill is large).  A solver object
    (with solve, is_positive_definite, stats and name, e.g. nitsche.distributed's) is used
    as given.  Above SINGLE_THRESHOLD unknowns CHOLMOD's factor is made in single precision
    (Cholmod's `single`)."""
    if hasattr(name, "solve"):
        return name
    if not (isinstance(name, str) and (name == "auto" or name in SOLVERS)):
        raise ValueError(f"solver must be one of auto, {', '.join(SOLVERS)}, not {name!r}")
    if not symmetric:
        if name not in ("auto",) + NONSYMMETRIC:
            raise ValueError(f"solver={name!r} needs a symmetric Newton matrix; this problem has "
                             f"residual terms (Coulomb friction or theta != 1): use solver='auto', "
                             f"{' or '.join(repr(s) for s in NONSYMMETRIC)}")
        if name == "auto":
            name = "gmres" if dim == 3 and n > AMG_THRESHOLD_3D else "superlu"
        return SOLVERS[name]()
    if name == "gmres":
        raise ValueError("solver='gmres' is for non-symmetric problems (residual terms); this one "
                         "minimizes an energy: use 'auto', 'cholmod', 'superlu' or 'amg'")
    if name == "auto":
        if dim == 3 and n > AMG_THRESHOLD_3D:
            name = "amg"
        else:
            name = "cholmod" if HAVE_CHOLMOD else "superlu"
    if name == "cholmod" and not HAVE_CHOLMOD:
        raise ValueError("solver 'cholmod' needs scikit-sparse 0.5 or later (`make cholmod` builds it with "
                         "SuiteSparse 7); use 'superlu'")
    if name != "cholmod":
        return SOLVERS[name]()
    if dim == 2:
        return Cholmod(ordering="metis" if n > METIS_THRESHOLD_2D else "amd", single=n > SINGLE_THRESHOLD,
                       geometric=n > GEOMETRIC_THRESHOLD_2D and not METIS_THRESHOLD_2D < n <= METIS_KEPT_2D)
    return Cholmod(ordering="default", geometric=n > GEOMETRIC_THRESHOLD_3D, single=n > SINGLE_THRESHOLD)
