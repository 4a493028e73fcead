"""Differential operators on jets, named as in the mathematics."""
import jax
import jax.numpy as jnp


def value(u):
    """u itself at the point."""
    return u.value


def grad(u):
    """grad u (for a vector field: grad[i, j] = d u_i / d x_j)."""
    return u.grad


def hess(u):
    """Hessian matrix of a scalar field (element-wise)."""
    return u.hess


def grad3(u):
    """Third derivatives d^3 u / dx_i dx_j dx_k (element-wise)."""
    return u.grad3


def lap(u):
    """Element-wise Laplacian: trace of the Hessian."""
    return jnp.trace(u.hess)


def dot(a, b):
    """a . b, contracting the last axis of a with the first of b."""
    return jnp.tensordot(jnp.asarray(a), jnp.asarray(b), axes=1)


def ddot(A, B):
    """A : B = sum_ij A_ij B_ij."""
    return jnp.sum(jnp.asarray(A) * jnp.asarray(B))


def sym_grad(u):
    """Strain eps(u) = (grad u + grad u^T) / 2 of a vector field."""
    G = u.grad
    return 0.5 * (G + G.T)


def div(u):
    """Divergence of a vector field."""
    return jnp.trace(u.grad)


def normal_derivative(u, n):
    """du/dn = grad u . n."""
    return jnp.dot(u.grad, n)


def tangent(n):
    """Unit tangent s = (-n_y, n_x) of a 2D facet with unit normal n (counter-clockwise
    along the boundary for the outward normal)."""
    return jnp.array([-n[1], n[0]])


def normal_component(v, n):
    """v . n: normal component of a vector (or first index of a tensor)."""
    return jnp.tensordot(n, jnp.asarray(v), axes=1)


def tangential_component(v, n):
    """v . s with s = tangent(n) (2D)."""
    return jnp.tensordot(tangent(n), jnp.asarray(v), axes=1)


def plus(s):
    """[s]_+ = max(s, 0); its derivative counts s = 0 as active."""
    return jnp.where(s >= 0, s, 0.0)


def deformation_gradient(u):
    """F = I + grad u of a displacement field."""
    G = u.grad
    return jnp.eye(G.shape[0]) + G


def det(F):
    """det F of a 2x2 or 3x3 matrix (written out: smooth, and cheap to differentiate)."""
    if F.shape == (2, 2):
        return F[0, 0] * F[1, 1] - F[0, 1] * F[1, 0]
    return jnp.dot(F[0], jnp.cross(F[1], F[2]))


def neo_hookean(F, mu, lam):
    """The compressible neo-Hookean energy density
    W(F) = mu/2 (tr(F^T F) - d - 2 ln J) + lam/2 (ln J)^2,  J = det F
    (NaN for J <= 0: the line search steps back from inverted elements)."""
    J = det(F)
    logJ = jnp.log(J)
    return 0.5 * mu * (jnp.sum(F * F) - F.shape[0] - 2 * logJ) + 0.5 * lam * logJ ** 2


def first_piola(W, F, *args):
    """P = dW/dF, the first Piola-Kirchhoff stress of an energy density W(F, *args)."""
    return jax.grad(W)(F, *args)
