"""Signorini contact in 2D: an elastic block pressed onto a rigid cylinder (plane strain).

The block (0, W) x (0, B) is the right half of a symmetric problem: the symmetry line
x = 0 carries rollers (u_x = 0), the top y = B is moved down by delta by a frictionless
rigid plate (u_y = -delta, u_x free), and the bottom rests on a rigid cylinder of radius
R whose top touches the block at x = 0: the cylinder's surface is y = -x^2 / (2R).

    J(u)      = int mu eps(u) : eps(u) + lam/2 (tr eps(u))^2      (plane strain)
    g(u)      = x^2 / (2R) - u . n >= 0   on the bottom y = 0  (n = (0, -1): g = u_y + x^2/(2R))
    lambda(u) = -n . sigma(u) n          (contact pressure, strong form)
    alpha     = alpha0 h / E             (alpha0 = 'auto': half the stability limit)

Force balance: the force of the top plate (the reaction of its fixed u_y, from
nitsche.reactions) balances the contact force sum of W lambda_N, and the rollers on
x = 0 carry no net horizontal force (frictionless contact and plate).  The reactions of
'symmetry' and 'top' count the dofs each holds: the corner (0, B) gives its u_x to the
rollers and its u_y to the plate.
The contact half-width is compared with plane-strain Hertz, a = sqrt(4 P R / (pi E*)),
P = 2 x the half model's force per unit thickness; Hertz holds for a half-space and the
block is only B deep, but with a ~ B/6 the half-width agrees to about 1-3 %.
Run:  .venv/bin/python examples/signorini_2d.py
"""
import time

import jax.numpy as jnp
import numpy as np
from skfem import ElementTriP1, ElementTriP2, ElementVector, MeshTri

import nitsche as ni
from nitsche.ops import dot, sym_grad
from nitsche.reactions import reactions


def main(level=3, degree=1, E=1.0, nu=0.3, W=2.0, B=1.0, R=4.0, delta=0.01, alpha0="auto",
         rtol=1e-12):
    t0 = time.perf_counter()
    n = 4 * 2 ** level                                  # cells per unit length
    mesh = MeshTri.init_tensor(np.linspace(0, W, int(W * n) + 1),
                               np.linspace(0, B, int(B * n) + 1)).with_boundaries({
        "symmetry": lambda x: x[0] < 1e-12, "bottom": lambda x: x[1] < 1e-12,
        "top": lambda x: x[1] > B - 1e-12})
    element = ElementVector(ElementTriP1() if degree == 1 else ElementTriP2())
    # rollers on the symmetry line, the top plate prescribes u_y = -delta (u_x free)
    u = ni.Field("u", mesh, element, fixed={"symmetry": "x", "top": "y"},
                 value=lambda x: [0 * x[0], np.where(x[1] > B - 1e-12, -delta, 0.0)])

    mu, lam = E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))

    def stress(u):
        eps = sym_grad(u)
        return 2 * mu * eps + lam * (eps[0, 0] + eps[1, 1]) * jnp.eye(2)

    def energy(u):
        eps = sym_grad(u)
        return mu * jnp.sum(eps * eps) + 0.5 * lam * (eps[0, 0] + eps[1, 1]) ** 2

    cylinder = ni.Inequality(gap=lambda u, x, n: x[0] ** 2 / (2 * R) - dot(u, n),
                             multiplier=lambda u, n: -dot(n, dot(stress(u), n)),
                             scaling=ni.Scaling(alpha0, h_power=1, stiffness=E),
                             on=ni.facets(u, "bottom", intorder=2 * degree + 2), name="cylinder")
    problem = ni.Problem([u], energy, [cylinder])
    result = problem.minimize(rtol=rtol).check()

    c = result.constraints["cylinder"]
    force = c["total_multiplier"]                       # per unit thickness, half model
    R_ = reactions(problem, result.x)["u"]
    plate = R_["top"][1]                                # the plate's vertical force on the block
    v = problem.constraint_values(result.x)["cylinder"]
    x, lam_N, W_ = v["x"][..., 0], v["multiplier"], v["W"]
    # half-width: plane-strain Hertz p ~ sqrt(1 - x^2/a^2) has <x^2>_p = a^2 / 4
    half_width = 2 * np.sqrt((W_ * lam_N * x ** 2).sum() / force)
    P = 2 * force                                       # both halves
    a_hertz = np.sqrt(4 * P * R / (np.pi * E / (1 - nu ** 2)))
    return dict(unknowns=int(problem.free.size), alpha0=float(problem.alpha0[problem.constraints[0].name].min()),
                newton_iterations=result.iterations,
                contact_force=force, plate_force=plate, balance_error=abs(plate + force) / force,
                # the rollers hold u_x only; frictionless contact and plate: no net horizontal force
                roller_force_x=R_["symmetry"][0],
                contact_width=float(x[lam_N > 0].max()), half_width=float(half_width),
                half_width_hertz=float(a_hertz), half_width_error=float(half_width / a_hertz - 1),
                peak_pressure=c["peak_multiplier"], peak_pressure_hertz=float(2 * P / (np.pi * a_hertz)),
                max_penetration=result.max_violation, penetration_over_delta=result.max_violation / delta,
                seconds=time.perf_counter() - t0)


if __name__ == "__main__":
    for key, value in main().items():
        print(f"{key:>22}: {value:.6g}" if isinstance(value, float) else f"{key:>22}: {value}")
