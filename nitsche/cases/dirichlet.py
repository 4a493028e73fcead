"""Poisson's equation with Nitsche's Dirichlet condition (paper section 2).

    J(u) = int 1/2 kappa |grad u|^2 - f u,   g(u) = u - u_D = 0 on the boundary,
    lambda(u) = kappa du/dn,   alpha = alpha0 h / kappa.

Manufactured solution on (0,1)^2: u = sin(pi x) cos(pi y) + x^2 y, f = -kappa lap u.
"""
import jax.numpy as jnp
import numpy as np
from skfem import MeshTri, ElementTriP1, ElementTriP2

import nitsche as ni
from nitsche.meshes import refined
from nitsche.ops import dot, grad
from nitsche.case import POSITIVE
from nitsche.norms import exact_errors

NAME = "dirichlet"
SUMMARY = "Poisson with Nitsche's Dirichlet condition, manufactured solution (section 2)"
PARAMETERS = {
    "kappa": (2.0, "conductivity"),
    "alpha0": ("auto", "Nitsche parameter (alpha = alpha0 h / kappa, h = cell diameter)"),
}
RANGES = {"kappa": POSITIVE, "alpha0": POSITIVE}
DEGREES = (1, 2)
RATE = {1: 1.0, 2: 2.0}
OUTPUTS_FROM_PIECES = True  # errors: nitsche.norms.exact_errors, summed over the ranks' cells

PAPER = [
    dict(command="study", degree=1, levels=6, sets={}, fast=dict(levels=4)),
    dict(command="study", degree=2, levels=5, sets={}, fast=dict(levels=3)),
    dict(command="run", degree=2, level=3, sets={}, fast=dict(level=2)),
]


def exact(x, xp=np):
    return xp.sin(np.pi * x[0]) * xp.cos(np.pi * x[1]) + x[0] ** 2 * x[1]


def exact_grad(x):
    return np.array([np.pi * np.cos(np.pi * x[0]) * np.cos(np.pi * x[1]) + 2 * x[0] * x[1],
                     -np.pi * np.sin(np.pi * x[0]) * np.sin(np.pi * x[1]) + x[0] ** 2])


def load(x, kappa):
    """f = -kappa lap u."""
    return -kappa * (-2 * np.pi ** 2 * jnp.sin(np.pi * x[0]) * jnp.cos(np.pi * x[1]) + 2 * x[1])


def build(level, degree, p):
    mesh = refined(MeshTri.init_symmetric(), level + 1)
    u = ni.Field("u", mesh, ElementTriP1() if degree == 1 else ElementTriP2())

    def energy(u, x):
        return 0.5 * p.kappa * dot(grad(u), grad(u)) - load(x, p.kappa) * u

    boundary = ni.Equality(gap=lambda u, x: u - exact(x, jnp),
                           multiplier=lambda u, n: p.kappa * dot(grad(u), n),
                           scaling=ni.Scaling(p.alpha0, h_power=1, stiffness=p.kappa),
                           on=ni.facets(u, intorder=2 * degree + 2), name="dirichlet")
    return dict(fields=[u], energy=ni.Integral(energy, ni.cells(u, intorder=2 * degree + 2)),
                constraints=[boundary])


def errors(problem, result, p):
    e = exact_errors(problem.by_name["u"], result["u"], exact, exact_grad)
    e["energy"] = float(np.sqrt(p.kappa) * e["H1"])
    return e
