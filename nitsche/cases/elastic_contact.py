"""Two-body linearised elastic contact, plane strain, frictionless (paper section 5.2).

    J(u1, u2) = sum_i int_{Omega_i} 1/2 sigma_i(u_i) : eps(u_i),
    on Gamma (facets of body 1):  g = (u2 - u1) . n1 + g0 >= 0,
    lambda = -n1 . sigma_1(u1) n1 (body 1 = the less stiff body),  alpha = alpha0 h / E1,
    h = diameter of the body-1 cell owning the facet.

The interface measure pairs body 1's contact facets with body 2's: on non-matching
meshes it integrates over their supermesh (exact for polynomial densities, the contact
patch test to round-off), on matching meshes at the facets' own quadrature points
(supermesh=false: at body 1's quadrature points always, exact only for matching meshes).

setup=punch (default): Omega1 = (0,1)^2 (E1 = 1), Omega2 = (0,1) x (1,2)
(E2 = 10), nu = 0.3, u1 = 0 on y = 0, u2 = (0, tilt (x - 0.6)) on y = 2 (a tilted rigid
punch), sides traction free: partial contact.

setup=hertz (the analytical check): plane-strain Hertz contact of a parabolic profile
g0(x) = x^2 / (2R) on a flat, half model x > 0 with symmetry u_x = 0 on x = 0.
Body 1 = (0,L) x (-L,0) clamped at the bottom, body 2 = (0,L) x (0,L/2), stiff, its
top pushed down by delta.  Hertz: for the load P per unit thickness (both halves),
a = sqrt(4 P R / (pi E*)), p0 = 2 P / (pi a), p(x) = p0 sqrt(1 - x^2/a^2),
1/E* = (1 - nu1^2)/E1 + (1 - nu2^2)/E2; P is the computed contact force.
"""
import os
from dataclasses import replace

import jax.numpy as jnp
import numpy as np
from skfem import MeshTri, ElementTriP1, ElementTriP2, ElementVector, CellBasis

import nitsche as ni
from nitsche import partition
from nitsche.case import Interval, OneOf, POISSON, POSITIVE, ParameterError
from nitsche.meshes import graded, refined
from nitsche.ops import dot, lame, sym_grad
from nitsche.supermesh import interface_report

NAME = "elastic-contact"
SUMMARY = "two elastic bodies in frictionless contact, plane strain; Hertz check (section 5.2)"
# under mpirun the hooks take the interface's points gathered (a line), the reactions summed,
# the von Mises stresses of the ranks' own cells (largest; the figure's cell means collected)
OUTPUTS_FROM_PIECES = True
PARAMETERS = {
    "setup": ("punch", "'punch' (tilted rigid punch, docs/elastic.md) or 'hertz' (analytical check)"),
    "E1": (1.0, "Young's modulus of body 1 (lower, less stiff: carries the multiplier)"),
    "E2": (10.0, "Young's modulus of body 2 (upper, stiffer)"),
    "nu1": (0.3, "Poisson's ratio of body 1"),
    "nu2": (0.3, "Poisson's ratio of body 2"),
    "alpha0": ("auto", "Nitsche parameter (alpha = alpha0 h / E1, h = cell diameter)"),
    "tilt": (0.1, "punch: u2_y = tilt (x - x0) on y = 2"),
    "x0": (0.6, "punch: the point of the top edge that does not move"),
    "matching": (True, "matching interface meshes (False: body 2 has 3/4 the cells (punch), "
                       "a shifted grading (hertz))"),
    "supermesh": (True, "integrate the interface on the supermesh of both traces where the "
                        "meshes do not match (False: at body 1's facet quadrature points)"),
    "R": (2.0, "hertz: radius of the parabolic profile g0 = x^2 / (2R)"),
    "delta": (0.01, "hertz: downward displacement of body 2's top"),
    "L": (2.0, "hertz: width of the half model and depth of body 1"),
    "curved": (False, "hertz: body 2's bottom is the parabola y = x^2/(2R) itself (paired "
                      "along the normal on the supermesh) instead of a flat face with the "
                      "gap g0"),
    "hx": (0.025, "hertz: cell width at the contact (x < 0.1 L), relative to L"),
    "hy": (0.025, "hertz: thickness of the cell layers at the interface (y within 0.05 L), "
                  "relative to L"),
    "growth": (1.3, "hertz: ratio of neighbouring cell sizes away from the contact"),
}
RANGES = {"setup": OneOf(("punch", "hertz")), "E1": POSITIVE, "E2": POSITIVE, "nu1": POISSON,
          "nu2": POISSON, "alpha0": POSITIVE, "R": POSITIVE, "L": POSITIVE, "hx": POSITIVE,
          "hy": POSITIVE, "growth": Interval(1.0, closed_lo=True)}
DEGREES = (1, 2)
RATE = {1: 1.0, 2: 1.0}  # punch: limited by corner and free-boundary singularities


def check(p):
    """Hertz: body 2 is pushed down (delta > 0) by less than the depth of body 1."""
    if p.setup == "hertz" and not 0 < p.delta < p.L:
        raise ParameterError(f"parameter delta={p.delta!r} (hertz: downward displacement of "
                             f"body 2's top) must lie in (0, L = {p.L:g}); set --set delta=...")


def stress(u, E, nu):
    """sigma(u) = 2 mu eps + lambda tr(eps) I (plane strain)."""
    mu, lam = lame(E, nu)
    eps = sym_grad(u)
    return 2 * mu * eps + lam * jnp.trace(eps) * jnp.eye(2)


def elastic(E, nu):
    mu, lam = lame(E, nu)

    def energy(u):
        eps = sym_grad(u)
        tr = eps[0, 0] + eps[1, 1]  # not jnp.trace: a nested jit hides linearity
        return mu * jnp.sum(eps * eps) + 0.5 * lam * tr * tr
    return energy


def _meshes(level, p):
    if p.setup == "punch":  # matching: rank-local under mpirun --local-meshes, body 2 holding
        # the cells above the rank's contact facets of body 1 as ghosts
        m1 = refined(MeshTri.init_symmetric(), level + 2)
        if p.matching:
            m2 = refined(MeshTri.init_symmetric().translated((0.0, 1.0)), level + 2,
                         ghosts_for=(m1, lambda x: x))
        else:
            n = 3 * 2 ** level
            m2 = MeshTri.init_tensor(np.linspace(0, 1, n + 1), np.linspace(1, 2, n + 1))
        return m1, m2
    if p.setup == "hertz":
        xs = graded(p.L, 0.1 * p.L, round(0.1 / p.hx), p.growth)
        ys = graded(p.L, 0.05 * p.L, round(0.05 / p.hy), p.growth)
        m1 = MeshTri.init_tensor(xs, -ys[::-1]).refined(level)
        xs2 = xs if p.matching else graded(p.L, 0.1 * p.L, 3, 1.3)
        ys2 = ys[ys <= 0.5 * p.L + 1e-12]
        m2 = MeshTri.init_tensor(xs2, ys2).refined(level)
        m2 = m2.with_boundaries({"top": lambda x: x[1] > ys2[-1] - 1e-12})
        if p.curved:  # a strip on the parabola (the facet numbering stays)
            x, y = m2.doflocs
            m2 = replace(m2, doflocs=np.stack([x, y + x ** 2 / (2 * p.R)]))
        return m1, m2
    raise AssertionError(p.setup)  # RANGES admits punch and hertz only


def _element(degree):
    return ElementVector(ElementTriP1() if degree == 1 else ElementTriP2())


def _dofs_on(field, where, component=None):
    dofs = field.dof_basis.get_dofs(field.mesh.facets_satisfying(where, boundaries_only=True))
    return dofs.all() if component is None else dofs.all(f"u^{component}")


def build(level, degree, p):
    m1, m2 = _meshes(level, p)
    e = _element(degree)
    if p.setup == "punch":
        u1 = ni.Field("u1", m1, e, fixed=lambda x: x[1] < 1e-12)
        u2 = ni.Field("u2", m2, e, fixed=lambda x: x[1] > 2 - 1e-12,
                      value=lambda x: np.stack([0 * x[0], p.tilt * (x[0] - p.x0)]))
        top = 1.0
        g0 = lambda x: 0.0
    else:
        probe1 = ni.Field("u1", m1, e)
        probe2 = ni.Field("u2", m2, e)
        fix1 = np.concatenate([_dofs_on(probe1, lambda x: x[1] < -p.L + 1e-12),
                               _dofs_on(probe1, lambda x: x[0] < 1e-12, 1)])
        top2 = probe2.dof_basis.get_dofs("top").all()
        fix2 = np.concatenate([top2, _dofs_on(probe2, lambda x: x[0] < 1e-12, 1)])
        u1 = ni.Field("u1", m1, e, fixed=fix1)
        u2 = ni.Field("u2", m2, e, fixed=fix2,
                      value=lambda x: np.stack([0 * x[0], -p.delta + 0 * x[0]]))
        top = 0.0
        g0 = lambda x: x[0] ** 2 / (2 * p.R)  # the vertical distance to the parabola
    q = 2 * degree
    w1, w2 = elastic(p.E1, p.nu1), elastic(p.E2, p.nu2)
    energy = [ni.Integral(lambda u1: w1(u1), ni.cells(u1, intorder=q)),
              ni.Integral(lambda u2: w2(u2), ni.cells(u2, intorder=q))]
    gamma = ni.interface(u1, lambda x: np.abs(x[1] - top) < 1e-12, intorder=2 * degree + 2,
                         other=u2, pairing="auto" if p.supermesh else "points")
    contact = ni.Inequality(
        gap=lambda u1, u2, n, x: dot(u2 - u1, n) + g0(x),
        multiplier=lambda u1, n: -dot(n, dot(stress(u1, p.E1, p.nu1), n)),
        scaling=ni.Scaling(p.alpha0, h_power=1, stiffness=p.E1),
        on=gamma, name="contact")
    return dict(fields=[u1, u2], energy=energy, constraints=[contact])


# -- post-processing ---------------------------------------------------------------

def von_mises(field, u, E, nu, cells=None):
    """Plane-strain von Mises stress at the quadrature points of the cells (default all),
    shape (cells, points)."""
    b = CellBasis(field.mesh, field.element, elements=cells)
    G = np.asarray(b.interpolate(u).grad)  # (2, 2, cells, points)
    mu, lam = lame(E, nu)
    eps = 0.5 * (G + G.transpose(1, 0, 2, 3))
    tr = eps[0, 0] + eps[1, 1]
    sxx, syy, sxy = 2 * mu * eps[0, 0] + lam * tr, 2 * mu * eps[1, 1] + lam * tr, 2 * mu * eps[0, 1]
    szz = lam * tr
    return np.sqrt(0.5 * ((sxx - syy) ** 2 + (syy - szz) ** 2 + (szz - sxx) ** 2) + 3 * sxy ** 2)


def cell_von_mises(field, u, E, nu):
    """The von Mises stress's mean over each cell of the mesh (the ranks' own cells
    collected)."""
    cells = partition.own_cells(field.mesh)
    return partition.collected(cells, von_mises(field, u, E, nu, cells).mean(axis=1),
                               field.mesh.nelements)


def von_mises_max(field, u, E, nu):
    """The largest von Mises stress at the quadrature points (over the ranks' own cells)."""
    cells = partition.own_cells(field.mesh)
    return float(partition.largest(von_mises(field, u, E, nu, cells).max(initial=-np.inf)))


def pressure(problem, result):
    """(x along the interface, discrete contact pressure lambda_N, weights), sorted by x
    (the points of all ranks' contact facets)."""
    v = problem.constraint_values(result.x)["contact"]
    x, lam, W = (partition.gathered(a.ravel()) for a in (v["x"][..., 0], v["multiplier"], v["W"]))
    order = np.argsort(x)
    return x[order], lam[order], W[order]


def reaction(problem, result, name, component=1):
    """Total reaction force (component) at the fixed dofs of field `name` (summed over the
    ranks' elements)."""
    g = problem.gradient(result.x)
    f = problem.by_name[name]
    dofs = f.fixed_dofs[f.fixed_dofs % 2 == component] + problem.offsets[name]
    return float(partition.summed(g[dofs].sum()))


def hertz(P, p):
    """(a, p0) of plane-strain Hertz contact for the load P per unit thickness."""
    Estar = 1.0 / ((1 - p.nu1 ** 2) / p.E1 + (1 - p.nu2 ** 2) / p.E2)
    a = np.sqrt(4 * P * p.R / (np.pi * Estar))
    return a, 2 * P / (np.pi * a)


def hertz_comparison(problem, result, p):
    """Load, a, p0 (Hertz) and the errors of the discrete pressure: half-width, peak, L2, and
    pointwise (largest error / p0) on the whole interface and on the core x <= a/2 (at the
    edge of contact the square root of p(x) limits every pointwise error)."""
    x, lam, W = pressure(problem, result)
    P = 2 * float((W * lam).sum())  # both halves
    a, p0 = hertz(P, p)
    exact = p0 * np.sqrt(np.maximum(1 - (x / a) ** 2, 0.0))
    second = float((W * lam * x ** 2).sum() / (W * lam).sum())  # = a^2/4 for Hertz
    a_h = 2 * np.sqrt(second)
    return dict(load=P, half_width=a, peak_pressure=p0, half_width_h=float(a_h),
                peak_pressure_h=float(lam.max()),
                error_half_width=abs(a_h - a) / a, error_peak_pressure=abs(lam.max() - p0) / p0,
                error_pressure_max=float(np.abs(lam - exact).max() / p0),
                error_pressure_max_core=float(np.abs(lam - exact)[x <= 0.5 * a].max() / p0),
                error_pressure_L2=float(np.sqrt((W * (lam - exact) ** 2).sum() / (W * exact ** 2).sum())))


def errors(problem, result, p):
    if p.setup != "hertz":
        return {}
    c = hertz_comparison(problem, result, p)
    return {k[6:]: v for k, v in c.items() if k.startswith("error_")}


def report(problem, result, p):
    x, lam, W = pressure(problem, result)
    out = dict(contact_force=float((W * lam).sum()),
               reaction_body1=reaction(problem, result, "u1"),
               reaction_body2=reaction(problem, result, "u2"),
               max_interpenetration=float(result.max_violation),
               von_mises_max=[von_mises_max(problem.by_name[n], result[n], E, nu)
                              for n, E, nu in (("u1", p.E1, p.nu1), ("u2", p.E2, p.nu2))],
               interface=interface_report(problem, result.x, "contact"))
    if p.setup == "hertz":
        out["hertz"] = hertz_comparison(problem, result, p)
    return out


def study_extra(problem, result, row):
    x, lam, W = pressure(problem, result)
    row["contact_force"] = float((W * lam).sum())
    row["reaction_body2"] = reaction(problem, result, "u2")


def figures(problem, result, p, outdir):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.tri as mtri
    from nitsche.io import vertex_values
    from nitsche.plot import cell_colours, write_figure
    bodies = [(n, cell_von_mises(problem.by_name[n], result[n], E, nu))
              for n, E, nu in (("u1", p.E1, p.nu1), ("u2", p.E2, p.nu2))]
    x, lam, W = pressure(problem, result)
    hertz_data = hertz_comparison(problem, result, p) if p.setup == "hertz" else None
    if outdir is None:  # a rank other than 0 under mpirun: its part is in the data above
        return []
    paths = []
    fig, ax = plt.subplots(figsize=(5.5, 6.5))
    vmax = 0.0
    scale = 1.0 if p.setup == "punch" else 5.0
    for n, vm in bodies:
        f = problem.by_name[n]
        d = vertex_values(f, result[n])
        tri = mtri.Triangulation(f.mesh.p[0] + scale * d[:, 0], f.mesh.p[1] + scale * d[:, 1],
                                 f.mesh.t.T)
        im = cell_colours(ax, tri, vm, cmap="viridis")
        vmax = max(vmax, float(np.percentile(vm, 99.5)))
        ax.triplot(tri, lw=0.1, color="k", alpha=0.3)
    for c in ax.collections + ax.images:  # (a large mesh's cell colours are an image: plot.Raster)
        if hasattr(c, "set_clim"):
            c.set_clim(0, vmax)
    fig.colorbar(im, ax=ax, shrink=0.7, label="von Mises stress")
    ax.set_aspect("equal")
    ax.set_title(f"deformed bodies (displacement x{scale:g}), von Mises stress")
    path = os.path.join(outdir, "deformed_von_mises.png")
    fig.tight_layout()
    write_figure(fig, path, dpi=130)
    paths.append(path)

    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot(x, lam, ".-", ms=3, label="Nitsche $\\lambda_N$")
    if hertz_data is not None:
        xs = np.linspace(0, x.max(), 800)
        a, p0 = hertz_data["half_width"], hertz_data["peak_pressure"]
        ax.plot(xs, p0 * np.sqrt(np.maximum(1 - (xs / a) ** 2, 0)), "k--", label="Hertz")
        ax.set_xlim(0, 2.5 * a)
    ax.set_xlabel("x on the interface")
    ax.set_ylabel("contact pressure")
    ax.legend()
    ax.grid(alpha=0.3)
    path = os.path.join(outdir, "contact_pressure.png")
    fig.tight_layout()
    write_figure(fig, path, dpi=130)
    paths.append(path)
    return paths


PAPER = [
    dict(command="run", degree=1, level=3, sets={}),
    dict(command="study", degree=1, levels=5, sets={}),
    dict(command="study", degree=1, levels=4, sets={"setup": "hertz"}),
]
