"""Poisson-Signorini problem (paper section 3).

    J(u) = int 1/2 kappa |grad u|^2 - f u,
    on Gamma_C = {y = 0}:  g(u) = u - u_D >= 0,  lambda(u) = kappa du/dn >= 0,  alpha = alpha0 h / kappa,
    Nitsche's Dirichlet condition u = u_exact on the other sides.

Manufactured solution on (0,1)^2 (kappa = 1): u = 8 (x - 1/2)_+^3 - 8 y (1/2 - x)_+^3,
in contact for x < 1/2 (lambda = 8 kappa (1/2 - x)^3), separated for x > 1/2.
"""
import jax.numpy as jnp
import numpy as np
from skfem import MeshTri, ElementTriP1, ElementTriP2

import nitsche as ni
from nitsche.meshes import refined
from nitsche.ops import dot, grad
from nitsche.case import OneOf, POSITIVE
from nitsche.norms import exact_errors

NAME = "signorini"
SUMMARY = "Poisson-Signorini problem, contact on y = 0, manufactured solution (section 3)"
PARAMETERS = {
    "kappa": (1.0, "conductivity (the exact solution assumes 1)"),
    "alpha0": ("auto", "Nitsche parameter of both boundary terms (alpha = alpha0 h / kappa)"),
    "method": ("nitsche", "'nitsche' or 'penalty' on the contact boundary"),
}
RANGES = {"kappa": POSITIVE, "alpha0": POSITIVE, "method": OneOf(("nitsche", "penalty"))}
DEGREES = (1, 2)
RATE = {1: 1.0, 2: 2.0}
OUTPUTS_FROM_PIECES = True  # errors: nitsche.norms.exact_errors, summed over the ranks' cells

PAPER = [
    dict(command="study", degree=1, levels=6, sets={}, fast=dict(levels=4)),
    dict(command="study", degree=2, levels=5, sets={}, fast=dict(levels=3)),
    dict(command="study", degree=2, levels=5, sets={"method": "penalty"}, fast=dict(levels=3)),
    dict(command="run", degree=2, level=3, sets={}, fast=dict(level=2)),
]


def exact(x, xp=np):
    a, b = xp.maximum(x[0] - 0.5, 0.0), xp.maximum(0.5 - x[0], 0.0)
    return 8 * a ** 3 - 8 * x[1] * b ** 3


def exact_grad(x):
    a, b = np.maximum(x[0] - 0.5, 0.0), np.maximum(0.5 - x[0], 0.0)
    return np.array([24 * a ** 2 + 24 * x[1] * b ** 2, -8 * b ** 3])


def load(x, kappa):
    """f = -kappa lap u."""
    return -kappa * (48 * jnp.maximum(x[0] - 0.5, 0.0) - 48 * x[1] * jnp.maximum(0.5 - x[0], 0.0))


def build(level, degree, p):
    mesh = refined(MeshTri.init_symmetric(), level + 1)
    u = ni.Field("u", mesh, ElementTriP1() if degree == 1 else ElementTriP2())
    q = 2 * degree + 2
    flux = lambda u, n: p.kappa * dot(grad(u), n)

    def energy(u, x):
        return 0.5 * p.kappa * dot(grad(u), grad(u)) - load(x, p.kappa) * u

    contact_side = ni.facets(u, lambda x: x[1] < 1e-12, intorder=q)
    scaling = ni.Scaling(p.alpha0, h_power=1, stiffness=p.kappa)
    gap = lambda u: u.value  # u - u_D with u_D = 0
    if p.method == "nitsche":
        contact = ni.Inequality(gap=gap, multiplier=flux, scaling=scaling, on=contact_side,
                                name="contact")
    else:
        contact = ni.Penalty(gap=gap, scaling=scaling, on=contact_side, name="contact")
    dirichlet = ni.Equality(gap=lambda u, x: u - exact(x, jnp), multiplier=flux,
                            scaling=ni.Scaling(p.alpha0, h_power=1, stiffness=p.kappa),
                            on=ni.facets(u, lambda x: x[1] > 1e-12, intorder=q), name="dirichlet")
    return dict(fields=[u], energy=ni.Integral(energy, ni.cells(u, intorder=q)),
                constraints=[contact, dirichlet])


def errors(problem, result, p):
    e = exact_errors(problem.by_name["u"], result["u"], exact, exact_grad)
    e["energy"] = float(np.sqrt(p.kappa) * e["H1"])
    return e
