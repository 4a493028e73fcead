"""Contact of two membranes (paper section 6.1), P1 and P2 triangles.

    Omega = (0,1)^2, u1 the lower membrane (tension mu1, load f1), u2 the upper one
    (mu2, f2), initial gap d, u1 = u2 = 0 on the boundary;

    J(u1, u2) = int 1/2 mu1 |grad u1|^2 + 1/2 mu2 |grad u2|^2 - f1 u1 - f2 u2,
    in every cell:  g = u2 + d - u1 >= 0,
    lambda = f1 + mu1 lap_h u1 on the less stiff membrane 1 (mu1 <= mu2), element-wise
    (= f1 for P1),
    alpha = alpha0 h^2 / mu1,  h = cell diameter.

method=penalty replaces the Nitsche terms by the penalty int [-g]_+^2 / (2 eps),
eps = penalty_alpha0 h^s / mu1, s = penalty_power.  For P1, s = 2 is optimal (and
the same as Nitsche: lambda_h = f1 is a constant, so Nitsche is a penalty with a
shifted gap).  The penalty is not consistent: its constraint violation is
eps * lambda = O(h^s), and for P2 the O(h^2)-type accuracy of Nitsche needs s > 2;
the default ('auto') is s = 2 for P1 and s = 3 for P2.  Measured with P2 (levels 2, 3,
4; penalty_alpha0 = 0.1): the energy-norm distance between the penalty and the Nitsche
solutions is 2.1e-3, 6.0e-4, 2.2e-4 for s = 2 (35-45 % of the discretization error
|u_k - I u_(k-1)|_E = 4.8e-3, 1.7e-3, 6.3e-4, and a constraint violation 15x that of
Nitsche), but 3.7e-4, 9.6e-5, 3.7e-5 for s = 3 (6-8 %, violation as small as Nitsche's).
The price is conditioning: the Jacobian's condition number grows like h^-s instead of
h^-2 (measured slopes -2.00 for Nitsche, -2.95 for the penalty with s = 3, P2).

Base mesh: MeshTri().refined(2) (4 x 4 squares, each cut into two triangles);
level N = N further uniform refinements.

Beyond the engine's report this case adds the contact area, the peak contact
pressure and the condition number of the Newton Jacobian (free dofs, at the
solution) to result.json and to every row of study.json; a study also solves the
other method at each level (compare=true) so that both condition numbers are
recorded, and draws them against h (condition.png).
"""
import os

import numpy as np
from skfem import MeshTri, ElementTriP1, ElementTriP2

import nitsche as ni
from nitsche import partition
from nitsche.meshes import refined
from nitsche.conditioning import condition_number, fitted_slope
from nitsche.case import NONNEGATIVE, OneOf, POSITIVE, ParameterError
from nitsche.ops import dot, grad, lap

NAME = "two-membrane"
SUMMARY = "two membranes in contact, gap d, on the unit square (section 6.1)"
PARAMETERS = {
    "mu1": (1.0, "tension of the lower membrane (the less stiff one, mu1 <= mu2)"),
    "mu2": (2.0, "tension of the upper membrane"),
    "f1": (1.0, "load on the lower membrane (positive: upward)"),
    "f2": (-1.0, "load on the upper membrane (negative: downward)"),
    "d": (0.05, "initial gap between the membranes"),
    "alpha0": ("auto", "Nitsche parameter (alpha = alpha0 h^2 / mu1, h = cell diameter)"),
    "method": ("nitsche", "'nitsche' or 'penalty'"),
    "penalty_power": ("auto", "power s of h in eps = penalty_alpha0 h^s / mu1 ('auto': 2 for P1, 3 for P2)"),
    "penalty_alpha0": (0.1, "penalty parameter factor (eps = penalty_alpha0 h^s / mu1)"),
    "compare": (True, "study: also solve the other method at each level (both condition numbers)"),
}
# under mpirun: the contact summary is the engine's combined report, the Jacobian (for its
# condition number) the ranks' Hessians summed on rank 0, the figure's cell pressures collected
OUTPUTS_FROM_PIECES = True
METHODS = ("nitsche", "penalty")
RANGES = {"mu1": POSITIVE, "mu2": POSITIVE, "d": NONNEGATIVE, "alpha0": POSITIVE,
          "method": OneOf(METHODS), "penalty_power": POSITIVE,
          "penalty_alpha0": POSITIVE}
DEGREES = (1, 2)
RATE = {1: 1.0, 2: 1.5}   # P2: the multiplier jumps at the free boundary, u in H^{5/2-eps}
PAPER = [
    # figure 1: the membranes and the contact pressure
    dict(command="run", degree=2, levels=None, level=4, sets={}, fast=dict(level=2)),
    # figure 2: convergence, P1 and P2
    dict(command="study", degree=1, levels=7, level=None, sets={}, fast=dict(levels=4)),
    # figure 2 (P2) and figure 3: condition numbers of Nitsche and penalty with P2
    dict(command="study", degree=2, levels=6, level=None, sets={}, fast=dict(levels=4)),
]


def penalty_power(p, degree):
    """The power s of h in the penalty parameter: 2 for P1, 3 for P2 unless set."""
    if p.penalty_power == "auto":
        return 2 if degree == 1 else 3
    return int(p.penalty_power)


def check(p):
    """Membrane 1 carries the multiplier: it must be the less stiff one; s an integer."""
    if p.mu1 > p.mu2:
        raise ParameterError(f"parameters mu1={p.mu1:g} > mu2={p.mu2:g}: membrane 1 must be the "
                             "less stiff one (the multiplier is taken from it); swap them")
    if p.penalty_power != "auto" and float(p.penalty_power) != round(float(p.penalty_power)):
        raise ParameterError(f"parameter penalty_power={p.penalty_power!r} must be a positive "
                             "integer or 'auto'")


def build(level, degree, p):
    mesh = refined(MeshTri(), level + 2)
    element = ElementTriP1() if degree == 1 else ElementTriP2()  # one object: one basis for both
    u1 = ni.Field("u1", mesh, element, fixed="boundary")
    u2 = ni.Field("u2", mesh, element, fixed="boundary")

    def energy(u1, u2):
        return (0.5 * p.mu1 * dot(grad(u1), grad(u1)) + 0.5 * p.mu2 * dot(grad(u2), grad(u2))
                - p.f1 * u1 - p.f2 * u2)

    def gap(u1, u2):
        return u2 + p.d - u1

    on = ni.cells(u1, intorder=2 * degree + 2)
    if p.method == "nitsche":
        contact = ni.Inequality(gap=gap, multiplier=lambda u1: p.f1 + p.mu1 * lap(u1),
                                scaling=ni.Scaling(p.alpha0, h_power=2, stiffness=p.mu1),
                                on=on, name="contact")
    else:
        contact = ni.Penalty(gap=gap, on=on, name="contact",
                             scaling=ni.Scaling(p.penalty_alpha0, h_power=penalty_power(p, degree),
                                                stiffness=p.mu1))
    return dict(fields=[u1, u2], energy=energy, constraints=[contact])


# -- quantities for result.json and study.json --------------------------------------

def contact_summary(result):
    c = result.constraints["contact"]
    return dict(contact_area=c["contact_measure"], peak_contact_pressure=c["peak_multiplier"],
                total_contact_force=c["total_multiplier"], contact_kind=c["kind"],
                contact_alpha0=c["alpha0"])


def conditioning(problem, result):
    """The condition number of the Newton Jacobian (free dofs) at the solution: of the whole
    matrix, the ranks' parts summed on rank 0 (nitsche.partition.summed_matrix) under mpirun."""
    A = partition.summed_matrix(problem.newton_system(result.x)[2])
    c = partition.first(None if A is None else condition_number(A))
    return dict(condition_number=c["cond"], jacobian_lambda_min=c["lambda_min"],
                jacobian_lambda_max=c["lambda_max"], condition_method=c["method"])


def report(problem, result, p):
    out = dict(method=p.method, contact_penalty_power=penalty_power(p, problem_degree(problem))
               if p.method == "penalty" else None)
    out.update(contact_summary(result))
    out.update(conditioning(problem, result))
    return out


def problem_degree(problem):
    return problem.setup.degree


def companion(problem, result):
    """The other method at the same level and parameters, solved from this solution."""
    from nitsche.cases import get
    _, level, degree, p = problem.setup
    other = vars(p).copy()
    other["method"] = "penalty" if p.method == "nitsche" else "nitsche"
    case = get(NAME)
    q = case.parameters(other)
    prob = case.problem(level, degree, q)
    res = prob.minimize(result.x)
    return prob, res


def study_extra(problem, result, row):
    _, level, degree, p = problem.setup
    row["method"] = p.method
    row.update(contact_summary(result))
    row.update(conditioning(problem, result))
    row[f"condition_number_{p.method}"] = row["condition_number"]
    if p.method == "penalty":
        row["penalty_power"] = penalty_power(p, degree)
    if p.compare:
        prob, res = companion(problem, result)
        other = "penalty" if p.method == "nitsche" else "nitsche"
        if not res.converged:
            row[f"condition_number_{other}"] = None
            row[f"{other}_reason"] = res.reason
            return
        row[f"condition_number_{other}"] = conditioning(prob, res)["condition_number"]
        row[f"{other}_newton_iterations"] = res.iterations
        row[f"{other}_max_violation"] = res.max_violation
        row[f"{other}_contact_area"] = res.contact_measure
        if other == "penalty":
            row["penalty_power"] = penalty_power(p, degree)


# -- figures ------------------------------------------------------------------------

SURFACE_TRIANGLES = 20_000  # finer meshes' 3D surfaces: drawn from 100 x 100 bin means


def surface(ax, tri, w, **style):
    """The surface of vertex values w over the triangulation, in a 3D axes; on a mesh of
    more than SURFACE_TRIANGLES triangles (more than the picture resolves: seconds of
    drawing each) the surface of their means in 100 x 100 bins (nitsche.plot.binned_mean)."""
    if tri.triangles.shape[0] <= SURFACE_TRIANGLES:
        return ax.plot_trisurf(tri, w, **style)
    from nitsche.plot import binned_mean
    Z, (x0, x1, y0, y1) = binned_mean(tri.x, tri.y, w, np.ones_like(w), most=100, per_bin=1)
    X, Y = np.meshgrid(x0 + (np.arange(Z.shape[1]) + 0.5) * (x1 - x0) / Z.shape[1],
                       y0 + (np.arange(Z.shape[0]) + 0.5) * (y1 - y0) / Z.shape[0])
    return ax.plot_surface(X, Y, Z, **style)


def cell_pressure(problem, x):
    """The contact pressure's mean over each cell (the ranks' own cells collected)."""
    v = problem.constraint_values(x)["contact"]
    on = next(c.on for c in problem.constraints if c.name == "contact")
    return partition.collected(on.cells, (v["multiplier"] * v["W"]).sum(1) / v["W"].sum(1),
                               on.mesh.nelements)


def figures(problem, result, p, outdir):
    """Figure 1: both membranes in one 3D picture, and the contact pressure."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.tri as mtri
    from nitsche.io import vertex_values
    from nitsche.plot import cell_colours, write_figure

    parts = problem.split(result.x)
    f1, f2 = problem.by_name["u1"], problem.by_name["u2"]
    mesh = f1.mesh
    tri = mtri.Triangulation(mesh.p[0], mesh.p[1], mesh.t.T)
    w1 = vertex_values(f1, parts["u1"])
    w2 = vertex_values(f2, parts["u2"]) + p.d
    per_cell = cell_pressure(problem, result.x)
    if outdir is None:  # a rank other than 0 under mpirun: its part is in per_cell
        return []
    summary = contact_summary(result)
    _, level, degree, _ = problem.setup

    fig = plt.figure(figsize=(12.5, 5.2))
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    surface(ax, tri, w1, cmap="Blues", linewidth=0.1, edgecolor=(0, 0, 0, 0.15), alpha=0.95)
    surface(ax, tri, w2, cmap="Oranges", linewidth=0.1, edgecolor=(0, 0, 0, 0.15), alpha=0.55)
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_zlabel("deflection")
    ax.view_init(elev=18, azim=-60)
    ax.set_title("lower membrane $u_1$ (blue), upper membrane $u_2 + d$ (orange)")

    ax = fig.add_subplot(1, 2, 2)
    im = cell_colours(ax, tri, np.ma.masked_where(per_cell <= 0, per_cell), cmap="magma_r")
    ax.triplot(tri, color=(0, 0, 0, 0.06), linewidth=0.3)
    fig.colorbar(im, ax=ax, shrink=0.85, label="contact pressure $\\lambda_h$ (cell mean)")
    ax.set_aspect("equal")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_title(f"contact region: area {summary['contact_area']:.4f}, "
                 f"peak pressure {summary['peak_contact_pressure']:.3f}")
    fig.suptitle(f"two membranes, {p.method}, P{degree}, level {level}")
    fig.tight_layout()
    path = os.path.join(outdir, "membranes.png")
    return [write_figure(fig, path, dpi=120, bbox_inches="tight")]  # the 3D panel's labels reach outside


def study_figures(rows, p, degree, outdir):
    """Figure 3: condition numbers of Nitsche and penalty against h, fitted slopes."""
    from nitsche.plot import write_figure  # first: it selects the Agg backend
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.8, 4.4))
    s = penalty_power(p, degree)
    series = {m: [(r["h"], r[f"condition_number_{m}"]) for r in rows
                  if r.get(f"condition_number_{m}")] for m in ("nitsche", "penalty")}
    # P1: lap_h u1 = 0, so Nitsche differs from penalty only by the active set (lambda = f1)
    equal = (len(series["nitsche"]) == len(series["penalty"]) > 0
             and np.allclose(series["nitsche"], series["penalty"], rtol=2e-2))
    plotted = False
    for method, style, label in (("nitsche", "o-", "Nitsche, $\\alpha = \\alpha_0 h^2/\\mu_1$"),
                                 ("penalty", "s--", f"penalty, $\\epsilon = \\epsilon_0 h^{s}/\\mu_1$")):
        pts = series[method]
        if len(pts) < 1:
            continue
        h, c = map(np.array, zip(*pts))
        slope = fitted_slope(h, c)
        label += f": slope {slope:.2f}" if slope is not None else ""
        if equal and method == "penalty":
            label += "\n(on the Nitsche curve: for P1 $\\Delta_h u_1 = 0$, the same Jacobian\nbut for the active set)"
        ax.loglog(h, c, style, mfc="none" if method == "penalty" else None,
                  ms=9 if method == "penalty" else 5, label=label)
        plotted = True
    if not plotted:
        plt.close(fig)
        return []
    ax.set_xlabel("h (cell diameter)")
    ax.set_ylabel("condition number of the Jacobian (free dofs)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(loc="lower left", fontsize=8)  # the curves fall from the upper left
    ax.set_title(f"two membranes, P{degree}: conditioning")
    fig.tight_layout()
    path = os.path.join(outdir, "condition.png")
    write_figure(fig, path, dpi=120)
    return [path]
