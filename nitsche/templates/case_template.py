"""__NAME__: an elastic block pressed onto a rigid floor (plane strain, frictionless).

A case module for `nitsche run __NAME__.py` / `nitsche study __NAME__.py`: edit build()
for your own problem.  The four ingredients of a constrained problem:

    J(u) = int 1/2 sigma(u) : eps(u)                 (energy; no body force)
    g(u) = u . (-n) + g0 >= 0   on the bottom       (the floor is g0 below the block)
    lambda(u) = -n . sigma(u) n                     (contact pressure, strong form)
    alpha = alpha0 h / E                            (scaling)

The top is moved down by `delta` (both components held), so no rigid motion is left.
"""
import jax.numpy as jnp
from skfem import ElementTriP1, ElementTriP2, ElementVector, MeshTri

import nitsche as ni
from nitsche.case import POISSON, POSITIVE
from nitsche.ops import dot, sym_grad

# The name on the command line and one line about the problem (optional for a file).
NAME = "__NAME__"
SUMMARY = "elastic block pressed onto a rigid floor, plane strain"

# Every physical and numerical parameter: {name: (default, help)}; `--set name=value`.
PARAMETERS = {
    "E": (1.0, "Young's modulus"),
    "nu": (0.3, "Poisson's ratio"),
    "delta": (0.01, "downward displacement of the top"),
    "g0": (0.0, "initial gap between the block and the floor"),
    "alpha0": ("auto", "Nitsche parameter (alpha = alpha0 h / E)"),
}
# Physical ranges, checked before anything is solved (optional).
RANGES = {"E": POSITIVE, "nu": POISSON, "alpha0": POSITIVE}
DEGREES = (1, 2)  # polynomial degrees build() accepts (--degree)
# RATE = {1: 1.0}  # expected energy-norm rate per degree, drawn in the study's plot (optional;
#                    here the corners of the top edge limit both degrees to about 2/3)


def stress(u, E, nu):
    """sigma(u) = 2 mu eps(u) + lambda tr(eps(u)) I (plane strain)."""
    mu, lam = E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))
    eps = sym_grad(u)
    return 2 * mu * eps + lam * jnp.trace(eps) * jnp.eye(2)


def build(level, degree, p):
    """The problem at `level` uniform refinements: fields, energy, constraints (`nitsche run`
    builds its finest level on a background thread beside the coarser ones: build only from
    its arguments, with no shared mutable state)."""
    mesh = MeshTri.init_tensor([0.0, 0.5, 1.0], [0.0, 0.25, 0.5]).refined(level + 1)
    element = ElementVector(ElementTriP1() if degree == 1 else ElementTriP2())
    u = ni.Field("u", mesh, element, fixed=lambda x: x[1] > 0.5 - 1e-12,
                 value=lambda x: [0 * x[0], -p.delta + 0 * x[0]])

    def energy(u):
        return 0.5 * jnp.sum(stress(u, p.E, p.nu) * sym_grad(u))

    floor = ni.Inequality(gap=lambda u, n: -dot(u, n) + p.g0,
                          multiplier=lambda u, n: -dot(n, dot(stress(u, p.E, p.nu), n)),
                          scaling=ni.Scaling(p.alpha0, h_power=1, stiffness=p.E),
                          on=ni.facets(u, lambda x: x[1] < 1e-12), name="floor")
    return dict(fields=[u], energy=energy, constraints=[floor])


# Optional hooks (see the shipped cases in nitsche/cases/ for more):
#   errors(problem, result, p) -> {name: error against an exact solution}
#   report(problem, result, p) -> {key: value} added to result.json
#   figures(problem, result, p, folder) -> [paths of the figures written into folder]
#   quantities(p) -> {name: density}: scalar densities of the fields, written into the VTU
#                    (vertex averages) and result.json ("quantities": min, max, mean)
def report(problem, result, p):
    """The total contact force on the floor: sum of W lambda_N over the contact points."""
    return dict(floor_force=result.constraints["floor"]["total_multiplier"])


def quantities(p):
    """The stress components and the von Mises stress (plane strain: s_zz = lambda tr eps)."""
    def sigma(u, i, j):
        return stress(u, p.E, p.nu)[i, j]

    def von_mises(u):
        s = stress(u, p.E, p.nu)
        szz = p.E * p.nu / ((1 + p.nu) * (1 - 2 * p.nu)) * jnp.trace(sym_grad(u))
        return jnp.sqrt(0.5 * ((s[0, 0] - s[1, 1]) ** 2 + (s[1, 1] - szz) ** 2
                               + (szz - s[0, 0]) ** 2) + 3 * s[0, 1] ** 2)
    return dict(sigma_xx=lambda u: sigma(u, 0, 0), sigma_yy=lambda u: sigma(u, 1, 1),
                sigma_xy=lambda u: sigma(u, 0, 1), von_mises=von_mises)
