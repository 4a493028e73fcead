"""The stability limit of alpha0: the inverse-estimate constant C_I of a multiplier.

J_h is convex when  alpha0 * sum_T int (alpha/alpha0) lambda(v)^2 < a(v, v)
for all v, i.e. alpha0 < 1/C_I with C_I the largest eigenvalue of the pencil
B v = mu K v (B from the multiplier term, K the Hessian of the energy).
C_I does not depend on h for shape-regular refinements, so a coarse mesh gives it.
"""
import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

DENSE_LIMIT = 3000
NEGLIGIBLE = 1e-8  # C_I below this: the multiplier does not depend on u (e.g. P1 Laplacian)


def largest_generalized_eigenvalue(B, K):
    """max v^T B v / v^T K v for symmetric B >= 0 and K >= 0 (K may have a kernel on
    which B vanishes; it is regularized by 1e-10 of its mean diagonal)."""
    n = K.shape[0]
    if B.nnz == 0 or abs(B).max() == 0:
        return 0.0
    shift = 1e-10 * K.diagonal().mean()
    Kr = (K + shift * sp.eye(n)).tocsc()
    if n <= DENSE_LIMIT:
        mu = float(sla.eigh(B.toarray(), Kr.toarray(), eigvals_only=True)[-1])
    else:
        solve = spla.factorized(Kr)
        op = spla.LinearOperator((n, n), matvec=lambda v: solve(B @ v))
        mu = float(np.real(spla.eigs(op, k=1, which="LR", tol=1e-3)[0][0]))  # 3 digits suffice
    return mu if mu > NEGLIGIBLE else 0.0
