"""Differential operators on jets, named as in the mathematics."""
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
