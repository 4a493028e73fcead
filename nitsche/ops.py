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


def lame(E, nu):
    """The Lame constants (mu, lambda) = (E / (2 (1 + nu)), E nu / ((1 + nu)(1 - 2 nu)))
    (3D and plane strain)."""
    return E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))


def deformation_gradient(u):
    """F = I + grad u of a displacement field."""
    G = u.grad
    return jnp.eye(G.shape[0]) + G


def current_normal(F, N):
    """n = cof(F) N / |cof(F) N|: the current unit normal of a surface whose reference normal
    is N (Nanson's formula; cof F = det(F) F^-T, written out in 2D and 3D)."""
    if F.shape == (2, 2):
        m = jnp.array([F[1, 1] * N[0] - F[1, 0] * N[1], -F[0, 1] * N[0] + F[0, 0] * N[1]])
    else:
        a = F.T  # the columns of F: cof(F) has the columns a_1 x a_2 cyclically
        m = N[0] * jnp.cross(a[1], a[2]) + N[1] * jnp.cross(a[2], a[0]) + N[2] * jnp.cross(a[0], a[1])
    return m / jnp.linalg.norm(m)


def surface_normal(T):
    """The unit normal of a curve or surface with tangents T (the columns, shape (d, d - 1)):
    (-t_y, t_x) / |t| in 2D, t_1 x t_2 / |t_1 x t_2| in 3D (outward for the current tangents
    F_2 t of nitsche.facet_tangents)."""
    m = jnp.array([-T[1, 0], T[0, 0]]) if T.shape[0] == 2 else jnp.cross(T[:, 0], T[:, 1])
    return m / jnp.linalg.norm(m)


def tangential_coordinates(T, d):
    """xi = (T^T T)^-1 T^T d: the coordinates along the tangents T (columns) of the orthogonal
    projection of d onto their span; with d = x_s - x_m, the first-order shift of the
    closest point x_m along the surface (zero where x_m is the closest point)."""
    return jnp.linalg.solve(T.T @ T, T.T @ d)


def axisymmetric_deformation_gradient(u, x):
    """F of an axisymmetric displacement (u_r, u_z) in (r, z) coordinates (x[0] = r > 0):
    the 3x3 matrix in the order (r, z, theta),

        F = [[1 + du_r/dr, du_r/dz, 0], [du_z/dr, 1 + du_z/dz, 0], [0, 0, 1 + u_r/r]],

    the last entry the hoop stretch of a ring of radius r."""
    F = jnp.zeros((3, 3)).at[:2, :2].set(deformation_gradient(u))
    return F.at[2, 2].set(1 + u.value[0] / x[0])


def det(F):
    """det F of a 2x2 or 3x3 matrix (written out: smooth, and cheap to differentiate)."""
    if F.shape == (2, 2):
        return F[0, 0] * F[1, 1] - F[0, 1] * F[1, 0]
    return jnp.dot(F[0], jnp.cross(F[1], F[2]))


def det_minus_one(F):
    """det F - 1 from H = F - I without cancellation: tr H + det H (2x2), tr H +
    ((tr H)^2 - tr H^2)/2 + det H (3x3); accurate where F is near I (small strains)."""
    H = F - jnp.eye(F.shape[0])
    tr = jnp.trace(H)
    if F.shape == (2, 2):
        return tr + det(H)
    return tr + 0.5 * (tr ** 2 - jnp.sum(H * H.T)) + det(H)


def neo_hookean(F, mu, lam):
    """The compressible neo-Hookean energy density
    W(F) = mu/2 (tr(F^T F) - d - 2 ln J) + lam/2 (ln J)^2,  J = det F,
    evaluated from H = F - I (tr(F^T F) - d = 2 tr H + H : H, ln J = log1p(det_minus_one(F))),
    so that small strains keep their relative accuracy (a large body's far field otherwise
    adds round-off of order 1e-16 mu |body| to J, which stalls Newton's energy line search);
    NaN or infinite for J <= 0: the line search steps back from inverted elements."""
    H = F - jnp.eye(F.shape[0])
    logJ = jnp.log1p(det_minus_one(F))
    return 0.5 * mu * (2 * jnp.trace(H) + jnp.sum(H * H) - 2 * logJ) + 0.5 * lam * logJ ** 2


def saint_venant_kirchhoff(F, mu, lam):
    """The Saint Venant-Kirchhoff energy density W(F) = mu E : E + lam/2 (tr E)^2 with the
    Green-Lagrange strain E = (F^T F - I) / 2 (linear elasticity's law on E; not
    polyconvex: it softens and loses its convexity in strong compression)."""
    E = 0.5 * (F.T @ F - jnp.eye(F.shape[0]))
    return mu * jnp.sum(E * E) + 0.5 * lam * jnp.trace(E) ** 2


def first_piola(W, F, *args):
    """P = dW/dF, the first Piola-Kirchhoff stress of an energy density W(F, *args)."""
    return jax.grad(W)(F, *args)
