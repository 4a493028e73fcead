"""Membrane obstacle problem (paper section 5.1).

    J(u) = int 1/2 T |grad u|^2 - f u,   g(u) = u - psi >= 0 in every cell,
    lambda(u) = -T lap_h u - f (element-wise),   alpha = alpha0 h^2 / T.

Default: the radially symmetric problem on (-2, 2)^2 with T = 1, f = 0,
psi = sqrt(1 - r^2) (r <= 1), -1 otherwise, exact solution
u = sqrt(1 - r^2) for r <= r*, -r*^2 ln(r/2) / sqrt(1 - r*^2) beyond, r* = 0.6979651482,
u = exact on the boundary.
"""
import jax.numpy as jnp
import numpy as np
from skfem import MeshTri, ElementTriP1, ElementTriP2

import nitsche as ni
from nitsche.meshes import refined
from nitsche.ops import dot, grad, lap
from nitsche.case import POSITIVE
from nitsche.norms import exact_errors

NAME = "obstacle"
SUMMARY = "membrane over an obstacle, exact radial solution on (-2,2)^2 (section 5.1)"
PARAMETERS = {
    "T": (1.0, "membrane tension"),
    "f": (0.0, "load per unit area (the exact solution needs f = 0)"),
    "alpha0": ("auto", "Nitsche parameter (alpha = alpha0 h^2 / T, h = cell diameter)"),
}
RANGES = {"T": POSITIVE, "alpha0": POSITIVE}
DEGREES = (1, 2)
RATE = {1: 1.0, 2: 1.5}
OUTPUTS_FROM_PIECES = True  # errors: nitsche.norms.exact_errors, summed over the ranks' cells

PAPER = [
    dict(command="run", degree=2, level=4, sets={}, fast=dict(level=2)),
    dict(command="study", degree=1, levels=7, sets={}, fast=dict(levels=4)),
    dict(command="study", degree=2, levels=6, sets={}, fast=dict(levels=4)),
]
R_STAR = 0.6979651482


def obstacle(x):
    """psi = sqrt(1 - r^2) for r < 1, -1 outside."""
    r2 = x[0] ** 2 + x[1] ** 2
    return jnp.where(r2 < 1.0, jnp.sqrt(jnp.maximum(1.0 - r2, 0.0)), -1.0)


def exact(x):
    r = np.maximum(np.sqrt(x[0] ** 2 + x[1] ** 2), 1e-300)
    outer = -R_STAR ** 2 * np.log(r / 2) / np.sqrt(1 - R_STAR ** 2)
    return np.where(r <= R_STAR, np.sqrt(np.maximum(1 - r ** 2, 0.0)), outer)


def exact_grad(x):
    r = np.maximum(np.sqrt(x[0] ** 2 + x[1] ** 2), 1e-300)
    dr = np.where(r <= R_STAR, -r / np.sqrt(np.maximum(1 - r ** 2, 1e-300)),
                  -R_STAR ** 2 / (r * np.sqrt(1 - R_STAR ** 2)))
    return np.array([dr * x[0] / r, dr * x[1] / r])


def build(level, degree, p):
    mesh = refined(MeshTri.init_symmetric().scaled((4.0, 4.0)).translated((-2.0, -2.0)), level + 2)
    u = ni.Field("u", mesh, ElementTriP1() if degree == 1 else ElementTriP2(),
                 fixed="boundary", value=exact)

    def energy(u):
        return 0.5 * p.T * dot(grad(u), grad(u)) - p.f * u

    contact = ni.Inequality(gap=lambda u, x: u - obstacle(x),
                            multiplier=lambda u: -p.T * lap(u) - p.f,
                            scaling=ni.Scaling(p.alpha0, h_power=2, stiffness=p.T),
                            on=ni.cells(u, intorder=2 * degree + 2), name="contact")
    return dict(fields=[u], energy=energy, constraints=[contact])


def errors(problem, result, p):
    if p.f != 0.0 or p.T != 1.0:
        return {}
    return exact_errors(problem.by_name["u"], result["u"], exact, exact_grad)
