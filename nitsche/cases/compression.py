"""A compressible neo-Hookean half cylinder pressed onto a rigid plane: a load path.

Plane strain.  The body is the lower half of the disk of radius R, its flat top (y = 0)
clamped to a press moved down by c R t, t = 0..1 in `steps` steps (c: the compression);
its arc touches the rigid plane y = -R at the start.  The energy is

    W(F) = mu/2 (tr(F^T F) - 2 - 2 ln J) + lam/2 (ln J)^2,   F = I + grad u,  J = det F,

the contact is frictionless and written exactly for the plane (reference points X,
current height X_y + u_y):

    g = X_y + u_y + R >= 0,   lambda = e_y . P(F) N,   alpha = alpha0 h / E,

P = dW/dF the first Piola-Kirchhoff stress, N the reference outward normal: P N is the
traction the plane exerts on the body per reference length, and lambda its component
along the plane's normal e_y, the contact pressure (-sigma_nn for a flat contact).  Force balance: the press's vertical reaction equals the
contact force int lambda_N (a vertical translation changes g by 1 and nothing else).
"""
import numpy as np
import jax.numpy as jnp
from skfem import MeshTri, ElementTriP1, ElementTriP2, ElementVector

import nitsche as ni
from nitsche.case import Interval, POISSON, POSITIVE
from nitsche.ops import deformation_gradient, first_piola, lame, neo_hookean

NAME = "compression"
SUMMARY = "neo-Hookean half cylinder compressed onto a rigid plane in load steps (frictionless)"
PARAMETERS = {
    "E": (1.0, "Young's modulus"),
    "nu": (0.3, "Poisson's ratio"),
    "R": (1.0, "radius of the half cylinder (its height)"),
    "compression": (0.3, "the press's final displacement, relative to R"),
    "steps": (15, "load steps (cut in half where Newton fails, regrown after successes)"),
    "alpha0": ("auto", "Nitsche parameter (alpha = alpha0 h / E, h = cell diameter); the "
               "limits are those of the reference state, and where J_h loses its convexity on "
               "the deformed body (with 'auto' at about 20 % compression) the path halves alpha0"),
    "n": (8, "cells across the radius at level 0"),
}
RANGES = {"E": POSITIVE, "nu": POISSON, "R": POSITIVE, "compression": Interval(0.0, 0.9),
          "steps": Interval(1.0, closed_lo=True), "n": Interval(1.0, closed_lo=True)}
DEGREES = (1, 2)
OUTPUTS_FROM_PIECES = True  # report: the load path's records (the same on every rank)


def half_disk(R, n):
    """The lower half of the disk of radius R: the square-to-disk map (x sqrt(1 - y^2/2),
    y sqrt(1 - x^2/2)) of a tensor mesh of (-1, 1) x (-1, 0), scaled by R; boundaries
    'top' (y = 0) and 'arc'."""
    s = np.linspace(-1, 1, 2 * n + 1)
    m = MeshTri.init_tensor(s, s[:n + 1])
    x, y = m.p
    p = R * np.array([x * np.sqrt(1 - y ** 2 / 2), y * np.sqrt(1 - x ** 2 / 2)])
    m = MeshTri(p, m.t)
    return m.with_boundaries({"top": lambda x: x[1] > -1e-9 * R, "arc": lambda x: x[1] < -1e-9 * R})


def build(level, degree, p):
    mesh = half_disk(p.R, int(p.n)).refined(level)
    u = ni.Field("u", mesh, ElementVector(ElementTriP1() if degree == 1 else ElementTriP2()),
                 fixed={"top": "all"})
    mu, lam = lame(p.E, p.nu)
    energy = ni.Integral(lambda u: neo_hookean(deformation_gradient(u), mu, lam),
                         ni.cells(u, intorder=2 * degree))

    def gap(u, x):
        return x[1] + u.value[1] + p.R

    def multiplier(u, n):
        return jnp.dot(first_piola(neo_hookean, deformation_gradient(u), mu, lam), n)[1]

    contact = ni.Inequality(gap, multiplier, ni.Scaling(p.alpha0, h_power=1, stiffness=p.E),
                            ni.facets(u, "arc", intorder=2 * degree + 2), name="contact")
    return dict(fields=[u], energy=energy, constraints=[contact])


def path(problem, p):
    """t = 1/steps, ..., 1: the press (the top) moved down by compression R t."""
    f = problem.by_name["u"]
    top = f.dof_basis.get_dofs(f.mesh.boundaries["top"])

    def press(problem, t):
        values = np.zeros(f.ndofs)
        values[top.all("u^2")] = -p.compression * p.R * t
        problem.set_values("u", values)
    return dict(times=np.arange(1, int(p.steps) + 1) / int(p.steps), set_step=press)


def report(problem, result, p):
    """compression_reached: the press's displacement at the last converged step, over R."""
    steps = problem.path.steps if getattr(problem, "path", None) else []
    return dict(compression_reached=p.compression * max([s["time"] for s in steps if s["converged"]],
                                                        default=0.0))
