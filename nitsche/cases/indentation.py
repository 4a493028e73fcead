"""A rigid sphere indents a compressible neo-Hookean block deeply: a load path, axisymmetric
or in 3D.

The block is the cylinder 0 < r < L, -L < z < 0 (L = size R) in (r, z) coordinates; every
measure carries the weight 2 pi r, so the 2D model is the 3D body.  Its energy is

    W(F) = mu/2 (tr(F^T F) - 3 - 2 ln J) + lam/2 (ln J)^2,   J = det F,

F the axisymmetric deformation gradient (the hoop stretch 1 + u_r/r).  Rollers on the axis
(u_r = 0), the bottom clamped.  The sphere of radius R touches the top z = 0 at the axis at
the start and is moved down by d = depth R t at the times t = (k/steps)^2 (the contact
radius grows about evenly); d is a run-time parameter of the problem, so the whole path
compiles once.  Contact in the current configuration (nitsche.obstacles):

    g = phi(X + u, d) = |X + u - (0, R - d)| - R >= 0,   lambda = n_phi . P(F) N,
    alpha = alpha0 h / E,

n_phi the sphere's outward normal at the current point, P = dW/dF, N the reference normal.
Hertz (small depth, half-space, E* = E / (1 - nu^2)): F = 4/3 E* R^(1/2) d^(3/2), contact
radius a = sqrt(R d).  The mesh is graded: at level 0 cells of diameter `grading` times
their distance from the first contact point, at least `grading` a_1 / 2 (a_1 Hertz's radius
at the first step); each level halves them (level 2, the command line's default, is the
shipped mesh: a quarter of the distance).  Force balance: the bottom's vertical
reaction equals the contact force, the vertical resultant int lambda_N (-n_phi . e_z) (a
vertical translation changes g by n_phi . e_z and the energy by nothing; the axis and the
free side carry no vertical force), up to int alpha (lambda_N - lambda) Dlambda[e_z].

geometry=3d: the same block and sphere in (x, y, z), a quarter of it, 0 < x, y < L, in
tetrahedra graded by the same rule (red-green refinement), u_x = 0 on x = 0 and u_y = 0 on
y = 0, the bottom clamped, F = I + grad u; the forces reported are the whole block's (4 times
the quarter's).
"""
import json
import os
from itertools import combinations

import numpy as np
from skfem import ElementTetP1, ElementTetP2, ElementTriP1, ElementTriP2, ElementVector, MeshTet, MeshTri

import nitsche as ni
from nitsche import partition
from nitsche.case import Interval, OneOf, POISSON, POSITIVE
from nitsche.obstacles import contact, normal, sphere, translated
from nitsche.ops import axisymmetric_deformation_gradient, deformation_gradient, lame, neo_hookean
from nitsche.quantities import quantity

NAME = "indentation"
SUMMARY = "rigid sphere pressed deep into a neo-Hookean block in load steps, axisymmetric or 3D, vs Hertz"
PARAMETERS = {
    "E": (1.0, "Young's modulus"),
    "nu": (0.3, "Poisson's ratio"),
    "R": (1.0, "the sphere's radius"),
    "depth": (0.3, "the final indentation depth, relative to R"),
    "steps": (12, "load steps: depths depth R (k/steps)^2 (cut in half where Newton fails)"),
    "size": (20.0, "the block's radius and height, relative to R"),
    "grading": (1.0, "cell diameter over the distance from the first contact point at level 0 "
                "(halved by each level)"),
    "alpha0": ("0.2*limit", "Nitsche parameter (alpha = alpha0 h / E, h = cell diameter); "
               "the limits are those of the reference state"),
    "geometry": ("axisymmetric", "axisymmetric: the (r, z) model; 3d: a quarter of the block in "
                 "tetrahedra with symmetry conditions (--level 0 --set steps=6: 4218 unknowns, "
                 "about 4 minutes on 2 loaded cores; each level has about 8 times the cells)"),
}
RANGES = {"E": POSITIVE, "nu": POISSON, "R": POSITIVE, "depth": Interval(0.0, 0.9),
          "steps": Interval(1.0, closed_lo=True), "size": Interval(2.0),
          "grading": Interval(0.0, 2.0, closed_hi=True), "geometry": OneOf(("axisymmetric", "3d"))}
DEGREES = (2, 1)
PAPER = [dict(command="run", degree=2, level=2, fast=dict(level=1))]
OUTPUTS_FROM_PIECES = True  # the contact force summed over the ranks' facets, the rest the path's records
HERTZ_DEPTH = 0.01  # depths d <= HERTZ_DEPTH R count as the small-depth end in reports
AXISYMMETRIC = os.path.join(os.path.dirname(__file__), "data", "indentation_axisymmetric.json")


def graded(mesh, grading, h_min):
    """mesh refined (red-green) until every cell's diameter is at most max(grading rho,
    h_min), rho the distance of its centroid from the origin."""
    while True:
        p = mesh.p[:, mesh.t]
        rho = np.linalg.norm(p.mean(axis=1), axis=0)
        diameter = np.max([np.linalg.norm(p[:, i] - p[:, j], axis=0)
                           for i, j in combinations(range(p.shape[1]), 2)], axis=0)
        coarse = np.flatnonzero(diameter > np.maximum(grading * rho, h_min))
        if coarse.size == 0:
            return mesh
        mesh = mesh.refined(coarse)


def graded_block(L, grading, h_min):
    """(0, L) x (-L, 0) in triangles, graded; boundaries 'axis' (r = 0), 'bottom', 'top' and
    'side'."""
    mesh = graded(MeshTri.init_tensor(np.linspace(0, L, 3), np.linspace(-L, 0, 3)), grading, h_min)
    tol = 1e-9 * L
    return mesh.with_boundaries({"axis": lambda x: x[0] < tol, "bottom": lambda x: x[1] < -L + tol,
                                 "top": lambda x: x[1] > -tol, "side": lambda x: x[0] > L - tol})


def graded_quarter(L, grading, h_min):
    """(0, L)^2 x (-L, 0) in tetrahedra, graded; boundaries 'x0' (x = 0), 'y0' (y = 0),
    'bottom', 'top' and 'side' (x = L or y = L)."""
    mesh = graded(MeshTet.init_tensor(np.linspace(0, L, 3), np.linspace(0, L, 3), np.linspace(-L, 0, 3)),
                  grading, h_min)
    tol = 1e-9 * L
    return mesh.with_boundaries({"x0": lambda x: x[0] < tol, "y0": lambda x: x[1] < tol,
                                 "bottom": lambda x: x[2] < -L + tol, "top": lambda x: x[2] > -tol,
                                 "side": lambda x: (x[0] > L - tol) | (x[1] > L - tol)})


def first_depth(p):
    return p.depth * p.R / int(p.steps) ** 2


def ring(x):
    return 2 * np.pi * x[0]


def solid(p):
    """True for geometry=3d."""
    return p.geometry == "3d"


def symmetry(p):
    """The whole block's forces over those of the model: 4 for the quarter, 1 axisymmetric
    (whose measures carry 2 pi r)."""
    return 4.0 if solid(p) else 1.0


def obstacle(p):
    """The sphere moved down by d: phi(y, d) = |y - (0, R - d)| - R (y = (r, z)), or
    |y - (0, 0, R - d)| - R in 3D."""
    dim = 3 if solid(p) else 2
    return translated(sphere(np.eye(dim)[-1] * p.R, p.R), -np.eye(dim)[-1])


def build(level, degree, p):
    h_min = 0.5 * p.grading * np.sqrt(p.R * first_depth(p))
    if solid(p):  # graded by the rule of level `level` directly (uniform 3D refinements are 8x)
        scale = 0.5 ** level
        mesh = graded_quarter(p.size * p.R, p.grading * scale, h_min * scale)
        element = ElementTetP1() if degree == 1 else ElementTetP2()
        fixed, weight = {"x0": "x", "y0": "y", "bottom": "all"}, None
    else:
        mesh = graded_block(p.size * p.R, p.grading, h_min).refined(level)
        element = ElementTriP1() if degree == 1 else ElementTriP2()
        fixed, weight = {"axis": "x", "bottom": "all"}, ring
    u = ni.Field("u", mesh, ElementVector(element), fixed=fixed)
    mu, lam = lame(p.E, p.nu)

    def W(F):
        return neo_hookean(F, mu, lam)

    if solid(p):
        energy = ni.Integral(lambda u: W(deformation_gradient(u)), ni.cells(u, intorder=2 * degree))
    else:
        energy = ni.Integral(lambda u, x: W(axisymmetric_deformation_gradient(u, x)),
                             ni.cells(u, intorder=2 * degree, weight=ring))
    gap, pressure = contact(obstacle(p), W, parameters=("d",), axisymmetric=not solid(p))
    sphere_contact = ni.Inequality(gap, pressure, ni.Scaling(p.alpha0, h_power=1, stiffness=p.E),
                                   ni.facets(u, "top", intorder=2 * degree + 2, weight=weight),
                                   name="sphere")
    return dict(fields=[u], energy=energy, constraints=[sphere_contact], parameters={"d": 0.0})


def path(problem, p):
    """t = (k/steps)^2, k = 1..steps: the sphere moved down by d = depth R t."""
    def indent(problem, t):
        problem.set_parameters(d=p.depth * p.R * t)
    return dict(times=(np.arange(1, int(p.steps) + 1) / int(p.steps)) ** 2, set_step=indent)


def hertz(p, d):
    """Hertz's force 4/3 E* R^(1/2) d^(3/2), E* = E / (1 - nu^2)."""
    return 4.0 / 3.0 * p.E / (1 - p.nu ** 2) * np.sqrt(p.R) * np.asarray(d) ** 1.5


def force_depth(problem, p):
    """Per accepted step: the depth d, the contact force (its vertical resultant
    int lambda_N (-n_phi . e_z), pushing the block down; summed over the ranks' facets),
    the bottom's reaction (pushing it up), Hertz's force and the contact force's relative
    difference to it."""
    ball, on, whole = obstacle(p), problem.constraints[0].on, symmetry(p)
    z = "z" if solid(p) else "y"  # the vertical: the last coordinate
    rows = []
    for k, s in enumerate(problem.path.steps[:len(problem.path.results)]):
        x = problem.path.at(problem, k)
        d = problem.state()[0]["d"]
        n_z = quantity(problem, x, lambda u, x, d: normal(ball, x + u.value, d)[-1], on=on)[0]
        v = problem.constraint_values(x)["sphere"]
        force = whole * float(partition.summed(-(v["W"] * v["multiplier"] * n_z).sum()))
        reaction = whole * s["reactions"]["u"]["bottom"][f"reaction_{z}"]
        rows.append(dict(depth=d, force=force, reaction=reaction,
                         hertz=float(hertz(p, d)), hertz_difference=float(force / hertz(p, d) - 1),
                         iterations=s["iterations"]))
    return rows


def axisymmetric(p, d):
    """The axisymmetric model's contact force at depths d (an array), from its shipped run
    (AXISYMMETRIC: `nitsche run indentation`, level 2, P2), F / (E R^2) interpolated as
    (d / R)^(3/2) times a piecewise linear function of d / R, NaN outside its depths; None
    unless nu and size are those of that run."""
    with open(AXISYMMETRIC) as f:
        ref = json.load(f)
    depth, force = np.array(ref["depth_over_R"]), np.array(ref["force_over_E_R2"])
    x = np.asarray(d, dtype=float) / p.R
    if p.nu != ref["nu"] or p.size != ref["size"]:
        return None
    inside = (x >= depth[0] * (1 - 1e-9)) & (x <= depth[-1] * (1 + 1e-9))
    return np.where(inside, p.E * p.R ** 2 * x ** 1.5 * np.interp(x, depth, force / depth ** 1.5), np.nan)


def report(problem, result, p):
    """force_depth (per step), depth_reached (over R), the contact force at the last step
    and the largest difference to Hertz at depths up to HERTZ_DEPTH R; in 3D also
    axisymmetric_difference, the largest relative difference of the contact force to the
    axisymmetric model's at the depths its shipped run covers (None where it applies nowhere)."""
    rows = force_depth(problem, p)
    small = [abs(r["hertz_difference"]) for r in rows if r["depth"] <= HERTZ_DEPTH * p.R * (1 + 1e-9)]
    out = dict(force_depth=rows, depth_reached=rows[-1]["depth"] / p.R if rows else 0.0,
               force=rows[-1]["force"] if rows else None,
               hertz_difference_small_depth=max(small) if small else None)
    if solid(p):
        F = axisymmetric(p, [r["depth"] for r in rows]) if rows else None
        differences = [] if F is None else \
            [abs(r["force"] / f - 1) for r, f in zip(rows, F) if np.isfinite(f)]
        out["axisymmetric_difference"] = float(max(differences)) if differences else None
    return out


def figures(problem, result, p, folder):
    """force_depth.png: the contact force and the bottom's reaction against the depth with
    Hertz's force, and the contact force over Hertz's (log depth)."""
    import matplotlib.pyplot as plt
    from nitsche.plot import save_figure
    rows = force_depth(problem, p)
    if folder is None:  # a rank other than 0 under mpirun: its part is in the rows above
        return []
    d = np.array([r["depth"] for r in rows]) / p.R
    fig, (ax, rel) = plt.subplots(1, 2, figsize=(10, 4.2))
    ax.plot(np.r_[0, d], [0.0] + [r["force"] for r in rows], "o-", ms=4, label="contact force")
    ax.plot(d, [r["reaction"] for r in rows], "x", ms=6, label="bottom reaction")
    fine = np.linspace(0, d[-1], 200) * p.R
    ax.plot(fine / p.R, hertz(p, fine), "k--", lw=1, label="Hertz $4/3\\, E^* R^{1/2} d^{3/2}$")
    reference = axisymmetric(p, fine[1:]) if solid(p) else None
    if reference is not None:
        ax.plot(fine[1:] / p.R, reference, "C2:", lw=1.5, label="axisymmetric model (level 2)")
        rel.semilogx(fine[1:] / p.R, reference / hertz(p, fine[1:]), "C2:", lw=1.5)
    ax.set_xlabel("depth d / R")
    ax.set_ylabel("force")
    ax.legend()
    rel.semilogx(d, [r["force"] / r["hertz"] for r in rows], "o-", ms=4, color="C0")
    rel.axhline(1.0, color="k", ls="--", lw=1)
    rel.set_xlabel("depth d / R")
    rel.set_ylabel("contact force / Hertz")
    for a in (ax, rel):
        a.grid(alpha=0.3, which="both")
    path = os.path.join(folder, "force_depth.png")
    model = "3D quarter" if solid(p) else "axisymmetric"
    return [save_figure(fig, path, f"indentation: neo-Hookean block (nu = {p.nu:g}, {model}), rigid sphere")]
