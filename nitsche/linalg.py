"""Linear solvers for the Newton systems, behind one interface.

`cholmod`: sparse Cholesky (CHOLMOD through scikit-sparse), symbolic analysis
once per pattern, numeric refactorization per Newton step.  `superlu`: SciPy's
sparse LU, the fallback when scikit-sparse is not installed.  `amg`: conjugate
gradients preconditioned by smoothed-aggregation algebraic multigrid (pyamg),
for large and 3D problems.
"""
import numpy as np
import scipy.sparse as sp
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
    name = "cholmod"

    def __init__(self):
        self.factor = None

    def solve(self, A, b):
        A = A.tocsc()
        try:
            if self.factor is None:
                self.factor = analyze(A)
            self.factor.cholesky_inplace(A)
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
    name = "amg"

    def __init__(self, rtol=1e-10, maxiter=2000):
        self.rtol, self.maxiter = rtol, maxiter

    def solve(self, A, b):
        import pyamg
        ml = pyamg.smoothed_aggregation_solver(A.tocsr(), symmetry="symmetric")
        x, info = spla.cg(A, b, rtol=self.rtol, maxiter=self.maxiter,
                          M=ml.aspreconditioner(cycle="V"))
        if info != 0:
            raise RuntimeError(f"AMG-preconditioned CG did not converge in {self.maxiter} iterations")
        return x


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
