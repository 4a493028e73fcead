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

from .conditioning import start_vector

DENSE_LIMIT = 3000
NEGLIGIBLE = 1e-8  # C_I below this: the multiplier does not depend on u (e.g. P1 Laplacian)
REGULARIZATION = 1e-10  # the shift of K, relative to its mean diagonal
SHIFT_SHARE = 0.5  # an eigenvector whose v^T K_s v is mostly shift lies in the kernel of K


class SingularEnergy(ValueError):
    """K is singular (or indefinite) on a direction where B is not zero: C_I is undefined."""


def largest_generalized_eigenvalue(B, K):
    """max v^T B v / v^T K v for symmetric B >= 0 and K >= 0.

    K may have a kernel on which B vanishes: it is regularized, K_s = K + s I with s =
    1e-10 of its mean diagonal, and the maximizer v stays away from that kernel.  Where
    B does not vanish on the kernel, mu ~ v^T B v / s is an artefact of the shift: then
    v^T K_s v is mostly s |v|^2, and SingularEnergy is raised (also when K is zero or
    indefinite)."""
    n = K.shape[0]
    if B.nnz == 0 or abs(B).max() == 0:
        return 0.0
    shift = REGULARIZATION * K.diagonal().mean()
    if not shift > 0:
        raise SingularEnergy("K has no positive diagonal")
    Ks = (K + shift * sp.eye(n)).tocsc()
    try:
        if n <= DENSE_LIMIT:
            w, v = sla.eigh(B.toarray(), Ks.toarray(), subset_by_index=[n - 1, n - 1])
            mu, v = float(w[0]), v[:, 0]
        else:
            lu = spla.splu(Ks, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                           options=dict(SymmetricMode=True))  # P K_s P^T = L D L^T
            if not np.all(lu.U.diagonal() > 0):  # the pivots D have the signs of K_s's eigenvalues
                raise SingularEnergy("K_s has a pivot <= 0: K is indefinite")
            op = spla.LinearOperator((n, n), matvec=lambda v: lu.solve(B @ v))
            w, v = spla.eigs(op, k=1, which="LR", tol=1e-3, v0=start_vector(n))  # 3 digits suffice
            mu, v = float(np.real(w[0])), np.real(v[:, 0])
    except (np.linalg.LinAlgError, RuntimeError) as e:  # K_s not positive definite, or singular
        raise SingularEnergy(str(e)) from None
    if mu <= NEGLIGIBLE:
        return 0.0
    energy = float(v @ (Ks @ v))
    if not 0 < shift * float(v @ v) <= SHIFT_SHARE * energy:
        raise SingularEnergy(f"the eigenvector's K_s-energy {energy:.3g} is mostly the shift")
    return mu
