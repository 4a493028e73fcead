"""Linear solvers for the Newton systems, behind one interface.

`cholmod`: sparse Cholesky (CHOLMOD through scikit-sparse), symbolic analysis
once per pattern, numeric refactorization per Newton step.  `superlu`: SciPy's
sparse LU, the fallback when scikit-sparse is not installed.  `amg`: conjugate
gradients preconditioned by smoothed-aggregation algebraic multigrid (pyamg),
for large and 3D problems.
"""
import numpy as np
import scipy.sparse.linalg as spla

try:
    from sksparse.cholmod import analyze, CholmodNotPositiveDefiniteError
    HAVE_CHOLMOD = True
except ImportError:  # pragma: no cover - depends on the machine
    HAVE_CHOLMOD = False

AMG_THRESHOLD_3D = 150_000  # 'auto' switches to AMG-CG above this many unknowns in 3D


class IndefiniteHessian(RuntimeError):
    """The Newton matrix is not positive definite."""


class Cholmod:
    """Sparse Cholesky: symbolic analysis once, a numeric factorization per changed matrix."""
    name = "cholmod"

    def __init__(self):
        self.factor = self.factored = None

    def solve(self, A, b):
        A = A.tocsc()
        if self.factor is not None and np.array_equal(A.data, self.factored):
            return self.factor(b)  # same matrix as the last step (active set unchanged)
        try:
            if self.factor is None:
                self.factor = analyze(A)
            self.factored = None
            self.factor.cholesky_inplace(A)
            self.factored = A.data.copy()
        except CholmodNotPositiveDefiniteError as e:
            raise IndefiniteHessian(str(e))
        return self.factor(b)


class SuperLU:
    name = "superlu"

    def solve(self, A, b):
        x = spla.splu(A.tocsc()).solve(b)
        if not np.all(np.isfinite(x)):
            raise IndefiniteHessian("singular Newton matrix")
        return x


class AMGCG:
    """CG preconditioned by one V-cycle of smoothed-aggregation AMG.

    With `prepare(problem)` the near-nullspace of the aggregation is the rigid-body
    modes of every vector field and the constants of every scalar field (free dofs),
    which makes elasticity converge in a few iterations.  The hierarchy is reused
    across Newton steps (the Hessians differ only on the active contact set) and
    rebuilt when CG needs more than `rebuild_factor` times the iterations it needed
    right after the last build."""
    name = "amg"

    def __init__(self, rtol=1e-10, maxiter=2000, rebuild_factor=1.5):
        self.rtol, self.maxiter, self.rebuild_factor = rtol, maxiter, rebuild_factor
        self.B, self.ml, self.base_iterations = None, None, None
        self.iterations, self.setups = [], 0

    def prepare(self, problem):
        self.B = near_nullspace(problem)

    def _build(self, A):
        import pyamg
        B = self.B if self.B is not None and self.B.shape[0] == A.shape[0] else None
        self.ml = pyamg.smoothed_aggregation_solver(A, B=B, symmetry="symmetric")
        self.M, self.base_iterations = self.ml.aspreconditioner(cycle="V"), None
        self.setups += 1

    def _cg(self, A, b, x0=None, maxiter=None):
        count = [0]
        x, info = spla.cg(A, b, x0=x0, rtol=self.rtol, maxiter=maxiter or self.maxiter, M=self.M,
                          callback=lambda xk: count.__setitem__(0, count[0] + 1))
        return x, info, count[0]

    def solve(self, A, b):
        A = A.tocsr()
        if self.ml is None or self.ml.levels[0].A.shape != A.shape:
            self._build(A)
            x, info, its = self._cg(A, b)
        else:  # the previous hierarchy, for a bounded number of iterations
            limit = int(self.rebuild_factor * self.base_iterations) + 2
            x, info, its = self._cg(A, b, maxiter=limit)
            if info != 0:
                self._build(A)
                x, info, more = self._cg(A, b, x0=x)
                its, self.base_iterations = its + more, more
        if self.base_iterations is None:
            self.base_iterations = its
        self.iterations.append(its)
        if info != 0:
            raise RuntimeError(f"AMG-preconditioned CG did not converge in {self.maxiter} iterations")
        if not np.all(np.isfinite(x)) or b @ x <= 0 < b @ b:
            raise IndefiniteHessian("CG found a direction of non-positive curvature")
        return x


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
            comp, X = j % d, f.basis.doflocs
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


SOLVERS = {"cholmod": Cholmod, "superlu": SuperLU, "amg": AMGCG}


def make_solver(name="auto", n=0, dim=2):
    """A solver by name; 'auto' is CHOLMOD (SuperLU without scikit-sparse), AMG-CG for large 3D."""
    if name == "auto":
        if dim == 3 and n > AMG_THRESHOLD_3D:
            name = "amg"
        else:
            name = "cholmod" if HAVE_CHOLMOD else "superlu"
    if name not in SOLVERS:
        raise ValueError(f"unknown linear solver {name!r}; choose one of auto, {', '.join(SOLVERS)}")
    if name == "cholmod" and not HAVE_CHOLMOD:
        raise ValueError("solver 'cholmod' needs scikit-sparse (and libsuitesparse-dev); use 'superlu'")
    return SOLVERS[name]()
