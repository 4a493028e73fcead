"""Axisymmetric Hertz indentation: a rigid sphere pressed into an elastic half-space.

The body is the cylinder 0 < r < L, -H < z < 0 in the (r, z) half-plane; every integral
carries the weight 2 pi r (a ring of radius r), so the 2D model is the full 3D body.
The displacement is u = (u_r, u_z); the hoop strain u_r / r enters the energy.

    J(u)      = int 2 pi r [ mu (eps : eps + (u_r/r)^2) + lam/2 (tr eps + u_r/r)^2 ] dr dz
                (eps: the in-plane strain of (u_r, u_z))
    g(u)      = r^2 / (2R) - d - u_z >= 0  on the top z = 0   (the sphere, approximated by
                the paraboloid z = r^2/(2R) - d, has moved down by d)
    lambda(u) = -sigma_zz = -n . sigma(u) n  (contact pressure, strong form)
    alpha     = alpha0 h / E                 (alpha0 = 'auto': half the stability limit)

Supports: u_r = 0 on the axis r = 0 (a roller, fixed component "x"), u = 0 on the bottom.
Hertz (rigid sphere, elastic half-space, E* = E / (1 - nu^2)):
    F = 4/3 E* sqrt(R) d^(3/2),   a = sqrt(R d),   p(r) = p0 sqrt(1 - r^2/a^2).
The mesh is graded: cells of size a/n_fine up to 1.5 a, then growing geometrically to
L = H = `size` a: cheap in 2D, and the finite body (clamped at depth H) is stiffer than
a half-space by about 0.9 a/H in the force (measured: size 20, 40, 80, 320 give +4.3,
+2.2, +1.1, +0.34 %).
Run:  .venv/bin/python examples/axisymmetric_indentation.py
"""
import time

import jax.numpy as jnp
import numpy as np
from skfem import ElementTriP2, ElementVector, MeshTri

import nitsche as ni
from nitsche.ops import dot
from nitsche.meshes import graded
from nitsche.reactions import reactions


def main(level=0, E=1.0, nu=0.3, R=1.0, d=0.01, size=320.0, n_fine=6, growth=1.25, alpha0="auto",
         rtol=1e-12):
    t0 = time.perf_counter()
    a = np.sqrt(R * d)                         # Hertz contact radius
    L = H = size * a
    rs = graded(L, 1.5 * a, n_fine, growth)
    zs = -graded(H, 1.5 * a, n_fine, growth)[::-1]
    mesh = MeshTri.init_tensor(rs, zs).refined(level).with_boundaries({
        "axis": lambda x: x[0] < 1e-12, "bottom": lambda x: x[1] < -H + 1e-9 * H,
        "top": lambda x: x[1] > -1e-12})
    u = ni.Field("u", mesh, ElementVector(ElementTriP2()), fixed={"axis": "x", "bottom": "all"})

    mu, lam = E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))
    ring = lambda x: 2 * np.pi * x[0]          # the weight 2 pi r of every measure

    def strains(u, x):
        G = u.grad                             # G[i, j] = d u_i / d x_j, (r, z) coordinates
        eps = 0.5 * (G + G.T)                  # in-plane strain
        hoop = u.value[0] / x[0]               # eps_theta = u_r / r (r > 0 at the quadrature points)
        return eps, hoop

    def energy(u, x):
        eps, hoop = strains(u, x)
        tr = eps[0, 0] + eps[1, 1] + hoop
        return mu * (jnp.sum(eps * eps) + hoop ** 2) + 0.5 * lam * tr ** 2

    def pressure(u, x, n):
        eps, hoop = strains(u, x)              # in-plane stress: 2 mu eps + lam tr I
        sigma = 2 * mu * eps + lam * (eps[0, 0] + eps[1, 1] + hoop) * jnp.eye(2)
        return -dot(n, dot(sigma, n))

    sphere = ni.Inequality(gap=lambda u, x, n: x[0] ** 2 / (2 * R) - d - dot(u, n),
                           multiplier=pressure,
                           scaling=ni.Scaling(alpha0, h_power=1, stiffness=E),
                           on=ni.facets(u, "top", intorder=6, weight=ring), name="sphere")
    problem = ni.Problem([u], ni.Integral(energy, ni.cells(u, weight=ring)), [sphere])
    result = problem.minimize(rtol=rtol).check()

    c = result.constraints["sphere"]
    F = c["total_multiplier"]                  # sum of W lambda_N, W includes 2 pi r
    F_hertz = 4.0 / 3.0 * E / (1 - nu ** 2) * np.sqrt(R) * d ** 1.5
    v = problem.constraint_values(result.x)["sphere"]
    r, lam_N, W = v["x"][..., 0], v["multiplier"], v["W"]
    a_moment = np.sqrt(2.5 * (W * lam_N * r ** 2).sum() / F)  # Hertz: <r^2>_p = 2/5 a^2
    a_active = r[lam_N > 0].max()
    R_bottom = reactions(problem, result.x)["u"]["bottom"][1]
    return dict(unknowns=int(problem.free.size), cells=int(mesh.t.shape[1]),
                alpha0=float(problem.alpha0[problem.constraints[0].name].min()), newton_iterations=result.iterations,
                force=F, force_hertz=F_hertz, force_error=F / F_hertz - 1,
                radius_moment=float(a_moment), radius_active=float(a_active), radius_hertz=a,
                radius_error=float(a_moment / a - 1),
                peak_pressure=c["peak_multiplier"], peak_pressure_hertz=3 * F_hertz / (2 * np.pi * a ** 2),
                reaction_bottom=R_bottom, balance_error=abs(R_bottom - F) / F,
                max_penetration=result.max_violation, penetration_over_d=result.max_violation / d,
                seconds=time.perf_counter() - t0)


if __name__ == "__main__":
    for key, value in main().items():
        print(f"{key:>20}: {value:.6g}" if isinstance(value, float) else f"{key:>20}: {value}")
