"""Contact of two clamped Kirchhoff plates (paper section 6.3), Morley elements.

    J(u1, u2) = sum_i  int D_i/2 [(1 - nu) hess u_i : hess u_i + nu (lap u_i)^2] - f_i u_i
                (element-wise: Morley is non-conforming),
    in every cell:  g = d - u1 + u2 >= 0   (plate 2 lies d above plate 1),
    lambda = f1 - D1 lap^2 u1 on the less stiff plate 1 (D1 <= D2), element-wise; Morley is
    quadratic, so lap^2 u1 = 0 and lambda_h = f1,
    alpha = alpha0 h^4 / D1  (h = cell diameter; lambda does not depend on u, so J_h is
    convex for every alpha0 and 'auto' takes the cap 0.1).

Both plates are clamped (u = du/dn = 0 on the boundary).  Plate 1 is pushed up
by f1 > 0, plate 2 down by f2 < 0; they touch in a small patch at the centre.
The Morley spaces of successive levels are not nested: the successive
difference is computed from both Hessians at the fine-cell centroids
(`difference`), the broken energy norm of the difference.
"""
import os

import numpy as np
from skfem import MeshTri, ElementTriMorley

import nitsche as ni
from nitsche import partition
from nitsche.case import NONNEGATIVE, PLATE_POISSON, POSITIVE, ParameterError
from nitsche.ops import hess

NAME = "plate-plate"
SUMMARY = "two clamped Kirchhoff plates in contact, Morley elements (section 6.3)"
PARAMETERS = {
    "D1": (1.0, "bending stiffness of the lower plate (the less stiff one, D1 <= D2)"),
    "D2": (2.0, "bending stiffness of the upper plate"),
    "nu": (0.3, "Poisson ratio of both plates"),
    "f1": (10.0, "load on the lower plate (positive: upward)"),
    "f2": (-10.0, "load on the upper plate (negative: downward)"),
    "d": (0.01, "initial gap between the plates"),
    "alpha0": ("auto", "Nitsche parameter (alpha = alpha0 h^4 / D1, h = cell diameter)"),
}
RANGES = {"D1": POSITIVE, "D2": POSITIVE, "nu": PLATE_POISSON, "d": NONNEGATIVE, "alpha0": POSITIVE}
DEGREES = (2,)          # Morley: non-conforming quadratics
RATE = {2: 1.0}
PAPER = [dict(command="study", degree=2, levels=6, level=None, sets={}),
         dict(command="run", degree=2, levels=None, level=4, sets={})]
OUTPUTS_FROM_PIECES = True  # report and figure: sums, maxima and contact points over the ranks


def bending(H, D, nu):
    """Bending energy density D/2 [(1 - nu) H:H + nu (tr H)^2] of a Hessian H."""
    tr = H[0, 0] + H[1, 1]
    return 0.5 * D * ((1 - nu) * (H ** 2).sum(axis=(0, 1)) + nu * tr ** 2)


def check(p):
    """Plate 1 carries the multiplier: it must be the less stiff one."""
    if p.D1 > p.D2:
        raise ParameterError(f"parameters D1={p.D1:g} > D2={p.D2:g}: plate 1 must be the less "
                             "stiff one (the multiplier is taken from it); swap them")


def build(level, degree, p):
    mesh = MeshTri().refined(level + 2)
    u1 = ni.Field("u1", mesh, ElementTriMorley(), fixed="boundary")
    u2 = ni.Field("u2", mesh, ElementTriMorley(), fixed="boundary")
    u1.bending, u2.bending = (p.D1, p.nu), (p.D2, p.nu)  # read by `difference`

    def energy(u1, u2):
        return (bending(hess(u1), p.D1, p.nu) + bending(hess(u2), p.D2, p.nu)
                - p.f1 * u1 - p.f2 * u2)

    def multiplier(u1):
        # f1 - D1 lap^2 u1 on each cell; the bi-Laplacian of a quadratic vanishes
        return p.f1 - p.D1 * 0.0 * u1.value

    contact = ni.Inequality(gap=lambda u1, u2: p.d - u1.value + u2.value,
                            multiplier=multiplier,
                            scaling=ni.Scaling(p.alpha0, h_power=4, stiffness=p.D1),
                            on=ni.cells(u1, intorder=4), name="contact")
    return dict(fields=[u1, u2], energy=ni.Integral(energy, ni.cells(u1, intorder=2)),
                constraints=[contact])


def difference(coarse_problem, coarse_x, problem, x):
    """Broken energy norm of u_h - u_H: both Hessians (constant per triangle) at the
    centroids of the fine cells, weighted by the cell areas."""
    mesh = problem.fields[0].mesh
    centroids = mesh.p[:, mesh.t].mean(axis=1)
    a, b = mesh.p[:, mesh.t[1]] - mesh.p[:, mesh.t[0]], mesh.p[:, mesh.t[2]] - mesh.p[:, mesh.t[0]]
    area = 0.5 * np.abs(a[0] * b[1] - a[1] * b[0])
    fine, coarse = problem.split(x), coarse_problem.split(coarse_x)
    total = 0.0
    for f in problem.fields:
        H = f.jets_at(fine[f.name], centroids)["hess"] - \
            coarse_problem.by_name[f.name].jets_at(coarse[f.name], centroids)["hess"]
        total += float(np.sum(area * 2 * bending(H, *f.bending)))
    return float(np.sqrt(total))


def vertex_values(problem, x):
    out = {}
    for f in problem.fields:
        out[f.name] = problem.split(x)[f.name][f.dof_basis.nodal_dofs[0]]
    return out


def contact_area(v):
    """The measure of the points where lambda_N > 0 (summed over the ranks' cells); v the
    contact constraint's values (Problem.constraint_values)."""
    return float(partition.summed((v["W"] * (v["multiplier"] > 0)).sum()))


def contact_points(v):
    """The points where lambda_N > 0 and lambda_N there (all ranks' points, gathered), in
    the order of their coordinates; v as for contact_area."""
    xq, lam = v["x"].reshape(-1, 2), v["multiplier"].ravel()
    xq, lam = partition.gathered(xq[lam > 0]), partition.gathered(lam[lam > 0])
    order = np.lexsort((xq[:, 0], xq[:, 1]))
    return xq[order], lam[order]


def report(problem, result, p):
    """The plates' deflections at the centre; the contact area, the total contact force and
    the largest penetration (over the ranks' cells)."""
    v = problem.constraint_values(result.x)["contact"]
    vals = vertex_values(problem, result.x)
    centre = np.argmin(np.hypot(*(problem.fields[0].mesh.p - 0.5)))
    return dict(centre_u1=float(vals["u1"][centre]), centre_u2=float(vals["u2"][centre]),
                contact_area=contact_area(v),
                total_contact_force=float(partition.summed((v["W"] * v["multiplier"]).sum())),
                max_penetration=float(partition.largest(np.maximum(-v["g"], 0).max(initial=0.0))))


def study_extra(problem, result, row):
    row.update(report(problem, result, None))


def figures(problem, result, p, outdir):
    """Fig. 7: both deflected plates (plate 2 shifted by the gap d) and the contact region."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.tri as mtri
    from nitsche.plot import write_figure
    v = problem.constraint_values(result.x)["contact"]
    (xq, lam), area = contact_points(v), contact_area(v)
    if outdir is None:  # a rank other than 0 under mpirun: its part is in the data above
        return []
    mesh = problem.fields[0].mesh
    tri = mtri.Triangulation(mesh.p[0], mesh.p[1], mesh.t.T)
    vals = vertex_values(problem, result.x)
    fig = plt.figure(figsize=(14, 4.4))
    ax = fig.add_subplot(1, 3, 1, projection="3d")
    ax.plot_trisurf(tri, vals["u1"], cmap="Blues", linewidth=0, alpha=0.9)
    ax.plot_trisurf(tri, vals["u2"] + p.d, cmap="Oranges", linewidth=0, alpha=0.6)
    ax.set_title("plate 1 (below) and plate 2 + d (above)")
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_zlabel("deflection")
    ax2 = fig.add_subplot(1, 3, 2)
    on_line = np.isclose(mesh.p[1], 0.5)
    o = np.argsort(mesh.p[0, on_line])
    ax2.plot(mesh.p[0, on_line][o], vals["u1"][on_line][o], label="$u_1$")
    ax2.plot(mesh.p[0, on_line][o], vals["u2"][on_line][o] + p.d, label="$u_2 + d$")
    ax2.set_xlabel("x  (y = 1/2)")
    ax2.set_ylabel("deflection")
    ax2.set_title("deflections along y = 1/2")
    ax2.legend()
    ax3 = fig.add_subplot(1, 3, 3)
    sc = ax3.scatter(xq[:, 0], xq[:, 1], c=lam, s=6, cmap="magma")
    fig.colorbar(sc, ax=ax3, shrink=0.8, label=r"contact pressure $\lambda_N$")
    ax3.set_xlim(0, 1)
    ax3.set_ylim(0, 1)
    ax3.set_aspect("equal")
    ax3.set_xlabel("x")
    ax3.set_ylabel("y")
    ax3.set_title(f"contact region, area {area:.4g}")
    fig.tight_layout()
    return [write_figure(fig, os.path.join(outdir, "plate_plate.png"), dpi=120)]
