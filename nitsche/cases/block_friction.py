"""An elastic block pressed and dragged on rigid ground: frictionless, Tresca or Coulomb
contact with any theta; the theta study (after Chouly, Hild and Renard).

    J(u) = int mu eps(u):eps(u) + lambda/2 tr(eps(u))^2   on the unit square (E = 1, nu = 0.3),
    the top moved by (top_x, top_y), the bottom y = 0 on the ground with the initial gap
    g0(x) = 0.02 (x - 0.4):
    g(u) = (-u.n + g0, -(u - u_old).t)   (normal gap, slip increment since the last step),
    lambda(u) = -(n.sigma(u) n, t.sigma(u) n),   alpha = alpha0 h / E,
    projected onto the non-negative reals (law=inequality: the normal part alone), the
    Tresca ball of radius s, or the Coulomb cone of radius F [lambda_n]_+.

The theta study (--set theta_study=true) solves the block for alpha0 from 1/400 to 400,
theta = 1, 0, -1, frictionless and Coulomb (F), at the run's level, and measures the
relative energy-norm error against theta = -1, alpha0 = 0.1 two levels finer: where each
variant breaks down (theta = 1 past its stability limit, theta = 0 for large alpha0,
theta = -1 never) is the figure theta_study.png.
"""
import os
import warnings

import jax.numpy as jnp
import numpy as np
from skfem import MeshTri, ElementTriP1, ElementVector

import nitsche as ni
from nitsche import partition
from nitsche.case import OneOf, POSITIVE
from nitsche.io import write_json
from nitsche.meshes import refined
from nitsche.ops import dot, tangent, sym_grad
from nitsche.study import prolongate

NAME = "block-friction"
SUMMARY = "elastic block pressed and dragged on rigid ground, any friction law and theta; theta study"
PARAMETERS = {
    "law": ("coulomb", "'inequality' (frictionless), 'tresca' or 'coulomb'"),
    "theta": (1, "Nitsche variant: 1 symmetric, 0 skew-symmetric, -1 non-symmetric"),
    "alpha0": (0.05, "Nitsche parameter (alpha = alpha0 h / E)"),
    "F": (0.3, "coulomb: friction coefficient"),
    "s": (0.01, "tresca: threshold"),
    "top_x": (0.02, "horizontal displacement of the top"),
    "top_y": (-0.03, "vertical displacement of the top (negative: pressed)"),
    "theta_study": (False, "also sweep alpha0 from 1/400 to 400 for theta 1, 0, -1 (figure)"),
}
RANGES = {"law": OneOf(("inequality", "tresca", "coulomb")), "theta": OneOf((1, 0, -1)),
          "alpha0": POSITIVE, "F": POSITIVE, "s": POSITIVE}
DEGREES = (1,)
PAPER = [dict(command="run", degree=1, level=3, sets={"theta_study": True}, fast=dict(level=2))]

E, NU = 1.0, 0.3
MU, LAM = E / (2 * (1 + NU)), E * NU / ((1 + NU) * (1 - 2 * NU))
STUDY_ALPHA0 = [1 / 400, 1 / 100, 1 / 25, 1 / 5, 1, 5, 25, 100, 400]
STUDY_THETAS = (1, 0, -1)
STUDY_LAWS = ("inequality", "coulomb")
OUTPUTS_FROM_PIECES = True  # report: the combined constraint report; the theta study: rank 0's own


def sigma(u):
    """sigma(u) = 2 mu eps(u) + lambda tr(eps(u)) I (plane strain)."""
    e = sym_grad(u)
    return 2 * MU * e + LAM * (e[0, 0] + e[1, 1]) * jnp.eye(2)


def energy(u):
    e = sym_grad(u)
    tr = e[0, 0] + e[1, 1]
    return MU * jnp.sum(e * e) + 0.5 * LAM * tr * tr


def g0(x):
    return 0.02 * (x[0] - 0.4)


def gap(u, u_old, n, x):
    """(normal gap to the rigid ground y = 0, slip increment of the ground relative to u)."""
    return jnp.stack([-dot(u, n) + g0(x), -dot(u - u_old, tangent(n))])


def multiplier(u, n):
    traction = dot(sigma(u), n)
    return -jnp.stack([dot(n, traction), dot(tangent(n), traction)])


def block(law, theta, top=(0.02, -0.03), level=2, alpha0=0.05, threshold=0.01, friction=0.3):
    """The problem: the unit square at `level`, its top moved by `top`."""
    spec = parts(law, theta, top, level, alpha0, threshold, friction)
    return ni.Problem(spec["fields"], spec["energy"], spec["constraints"])


def parts(law, theta, top, level, alpha0, threshold, friction):
    """Fields, energy and constraint of the block (see the module docstring)."""
    m = refined(MeshTri.init_symmetric(), level)
    u = ni.Field("u", m, ElementVector(ElementTriP1()), fixed=lambda x: x[1] > 1 - 1e-12,
                 value=lambda x: np.stack([top[0] + 0 * x[0], top[1] + 0 * x[0]]))
    bottom = ni.facets(u, lambda x: x[1] < 1e-12)
    scaling = ni.Scaling(alpha0, 1, E)
    if law == "tresca":
        c = ni.Tresca(gap, multiplier, scaling, bottom, threshold=threshold, theta=theta)
    elif law == "coulomb":
        c = ni.Coulomb(gap, multiplier, scaling, bottom, friction=friction, theta=theta)
    else:
        c = ni.Inequality(lambda u, n, x: -dot(u, n) + g0(x), lambda u, n: -dot(n, dot(sigma(u), n)),
                          scaling, bottom, theta=theta)
    return dict(fields=[u, ni.history(u)], energy=energy, constraints=[c])


def build(level, degree, p):
    return parts(p.law, p.theta, (p.top_x, p.top_y), level, p.alpha0, p.s, p.F)


def theta_study(level, fine, top=(0.02, -0.03)):
    """Rows (law, theta, alpha0, converged, iterations, relative energy-norm error against
    theta = -1, alpha0 = 0.1 at level `fine`)."""
    rows = []
    for law in STUDY_LAWS:
        reference = block(law, -1, top, fine, 0.1)
        ref = reference.minimize(maxiter=60).check()
        K = reference.energy_matrix()
        norm = np.sqrt(ref.x @ (K @ ref.x))
        for theta in STUDY_THETAS:
            for a in STUDY_ALPHA0:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")  # alpha0 above the limit: part of the study
                    problem = block(law, theta, top, level, a)
                    result = problem.minimize(maxiter=60)
                e = prolongate(problem, result.x, reference) - ref.x
                rows.append(dict(law=law, theta=theta, alpha0=a, converged=result.converged,
                                 iterations=result.iterations,
                                 error=float(np.sqrt(e @ (K @ e)) / norm) if result.converged else None))
    return rows


def plot_theta_study(rows, path, title=""):
    from nitsche.plot import save_figure  # first: it selects the Agg backend
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(10, 4), sharey=True)
    for ax, law in zip(axes, STUDY_LAWS):
        for theta, style, size in zip(STUDY_THETAS, ("o-", "s--", "^:"), (10, 7, 4)):
            pts = [(r["alpha0"], r["error"]) for r in rows if r["law"] == law and r["theta"] == theta
                   and r["error"] is not None]
            if pts:  # hollow markers of decreasing size: coinciding curves stay visible
                ax.loglog(*zip(*pts), style, ms=size, mfc="none", label=f"theta = {theta}")
        ax.set_xlabel("alpha0")
        ax.set_title("frictionless" if law == "inequality" else "Coulomb, F = 0.3")
        ax.grid(alpha=0.3, which="both")
        ax.legend()
    axes[0].set_ylabel("relative energy-norm error (missing: Newton failed)")
    return save_figure(fig, path, title)


def figures(problem, result, p, folder):
    """With theta_study: the sweep at this level against two levels finer (whole problems
    that rank 0 solves by itself under mpirun)."""
    if not p.theta_study or folder is None:
        return []
    level = problem.setup.level
    with partition.local(None):
        rows = theta_study(level, level + 2, (p.top_x, p.top_y))
    data = write_json(os.path.join(folder, "theta_study.json"),
                      dict(level=level, reference_level=level + 2, rows=rows))
    path = plot_theta_study(rows, os.path.join(folder, "theta_study.png"),
                            f"theta study: block at level {level}, reference level {level + 2}")
    return [path, data]


def report(problem, result, p):
    return dict(friction_force=result.constraints[problem.constraints[0].name].get(
        "total_tangential_traction"))
