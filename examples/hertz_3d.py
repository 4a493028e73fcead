"""3D Hertz contact: a rigid paraboloid pressed into an elastic block (quarter model).

The block is (0, L) x (0, L) x (-H, 0), trilinear hexahedra (Q1) on a graded tensor
mesh; the paraboloid z = r^2 / (2R) - d (r^2 = x^2 + y^2) has moved down by d.
Only the quarter x, y > 0 is modelled: the symmetry planes x = 0 and y = 0 carry
rollers (u_x = 0 and u_y = 0: fixed components), the bottom z = -H is clamped.

    J(u)      = int mu eps(u) : eps(u) + lam/2 (tr eps(u))^2       (linear elasticity)
    g(u)      = r^2 / (2R) - d - u . n >= 0   on the top z = 0  (n = (0, 0, 1))
    lambda(u) = -n . sigma(u) n                (contact pressure, strong form)
    alpha     = alpha0 h / E                   (alpha0 = 'auto': half the stability limit)

Hertz (rigid paraboloid, elastic half-space, E* = E / (1 - nu^2)):
    F = 4/3 E* sqrt(R) d^(3/2),   a = sqrt(R d),   p0 = 3 F / (2 pi a^2).
The computed force is 4 x the quarter's sum of W lambda_N.  Two effects separate it from
Hertz: the discretization (cells of a / n_fine in the contact zone) and the finite block
(clamped at depth H = `size` a: stiffer than a half-space by about 0.9 a / H, measured with
the axisymmetric tutorial: +2.2 % at size 40).  The contact integral uses 2 x 2 Gauss
points per quadrilateral facet (contact_order=2): with 3 x 3 the Q1 surface cannot follow
that many pointwise constraints and lambda_N oscillates (peak 3x Hertz, holes in the
contact patch).
Run:  .venv/bin/python examples/hertz_3d.py
"""
import time

import jax.numpy as jnp
import numpy as np
from skfem import ElementHex1, ElementVector, MeshHex

import nitsche as ni
from nitsche.ops import dot, sym_grad
from nitsche.meshes import graded
from nitsche.reactions import reactions


def main(E=1.0, nu=0.3, R=1.0, d=0.01, size=40.0, n_fine=6, growth=1.5, alpha0="auto", rtol=1e-12,
         contact_order=2):
    t0 = time.perf_counter()
    a = np.sqrt(R * d)                                   # Hertz contact radius
    L = H = size * a
    xs = graded(L, 1.5 * a, n_fine, growth)              # fine cells a/(n_fine/1.5) up to 1.5 a
    zs = -graded(H, 1.5 * a, n_fine, growth)[::-1]
    mesh = MeshHex.init_tensor(xs, xs, zs).with_boundaries({
        "symmetry_x": lambda x: x[0] < 1e-12, "symmetry_y": lambda x: x[1] < 1e-12,
        "bottom": lambda x: x[2] < -H + 1e-9 * H, "top": lambda x: x[2] > -1e-12})
    # intorder=2: 2x2x2 Gauss points, exact for the Q1 stiffness on boxes
    u = ni.Field("u", mesh, ElementVector(ElementHex1()), intorder=2,
                 fixed={"symmetry_x": "x", "symmetry_y": "y", "bottom": "all"})

    mu, lam = E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))

    def energy(u):
        eps = sym_grad(u)
        tr = eps[0, 0] + eps[1, 1] + eps[2, 2]
        return mu * jnp.sum(eps * eps) + 0.5 * lam * tr ** 2

    def pressure(u, n):
        eps = sym_grad(u)
        sigma = 2 * mu * eps + lam * (eps[0, 0] + eps[1, 1] + eps[2, 2]) * jnp.eye(3)
        return -dot(n, dot(sigma, n))

    indenter = ni.Inequality(
        gap=lambda u, x, n: (x[0] ** 2 + x[1] ** 2) / (2 * R) - d - dot(u, n),
        multiplier=pressure,
        scaling=ni.Scaling(alpha0, h_power=1, stiffness=E),
        on=ni.facets(u, "top", intorder=contact_order), name="indenter")
    problem = ni.Problem([u], energy, [indenter])
    result = problem.minimize(rtol=rtol).check()

    c = result.constraints["indenter"]
    F = 4 * c["total_multiplier"]                        # four quarters
    F_hertz = 4.0 / 3.0 * E / (1 - nu ** 2) * np.sqrt(R) * d ** 1.5
    v = problem.constraint_values(result.x)["indenter"]
    r2 = v["x"][..., 0] ** 2 + v["x"][..., 1] ** 2
    lam_N, W = v["multiplier"], v["W"]
    a_moment = np.sqrt(2.5 * (W * lam_N * r2).sum() / (W * lam_N).sum())  # <r^2>_p = 2/5 a^2
    a_area = np.sqrt(4 * c["contact_measure"] / np.pi)   # quarter contact area -> radius
    R_bottom = 4 * reactions(problem, result.x)["u"]["bottom"][2]
    return dict(unknowns=int(problem.free.size), cells=int(mesh.t.shape[1]),
                alpha0=float(problem.alpha0[problem.constraints[0].name].min()), newton_iterations=result.iterations,
                force=F, force_hertz=F_hertz, force_error=F / F_hertz - 1,
                radius_moment=float(a_moment), radius_area=float(a_area), radius_hertz=a,
                radius_error=float(a_moment / a - 1), radius_area_error=float(a_area / a - 1),
                peak_pressure=c["peak_multiplier"], peak_pressure_hertz=3 * F_hertz / (2 * np.pi * a ** 2),
                reaction_bottom=R_bottom, balance_error=abs(R_bottom - F) / F,
                max_penetration=result.max_violation, penetration_over_d=result.max_violation / d,
                seconds=time.perf_counter() - t0)


if __name__ == "__main__":
    for key, value in main().items():
        print(f"{key:>20}: {value:.6g}" if isinstance(value, float) else f"{key:>20}: {value}")
