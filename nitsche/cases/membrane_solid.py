"""A membrane pushed onto a linear elastic cube (paper section 6.2), 3D.

    cube Omega_2 = (0,1)^3, displacement u (trilinear hexahedra; cells=tet: linear
    tetrahedra, six per cube), clamped at z = 0;
    membrane Omega_1 = (0,1)^2 at height z = 1 + d, deflection w (bilinear
    quadrilaterals; cells=tet: linear triangles, two per square), positive up, w = 0 on
    its boundary, downward pressure `load`;

    J = int_{Omega_1} 1/2 mu |grad w|^2 + load w  +  int_{Omega_2} 1/2 sigma(u) : eps(u),
    on the membrane cells:  g = d + w - u_z(x, y, 1) >= 0,
    lambda = load - mu lap_h w  (the membrane is the less stiff side),  alpha = alpha0 h^2 / mu,
    h = diameter of the membrane cell.

The cube is evaluated on the membrane's cells lifted to z = 1 (an interface measure);
the meshes are uniform n x n x n and m x m, n = n0 2^level, m = m0 2^level (m0 = n0 by
default: they match on the top face and the interface uses the membrane's quadrature
points; otherwise the supermesh of the membrane cells and the cube's top facets).
Hexahedra and quadrilaterals: the level-0 grids refined `level` times (nitsche.meshes.refined:
under `mpirun ... --local-meshes` each rank refines its own cells, the cube also the cells
under the rank's membrane cells, as ghosts); tetrahedra: the tensor grid of level `level`.
lap_h of bilinears on rectangles (and of linears on triangles) is 0, so lambda = load and
the multiplier term is stable for every alpha0.
"""
import os

import jax.numpy as jnp
import numpy as np
from skfem import (MeshHex, MeshQuad, MeshTet, MeshTri, ElementHex1, ElementQuad1, ElementTetP1,
                   ElementTriP1, ElementVector)
from skfem.quadrature import get_quadrature

import nitsche as ni
from nitsche import partition
from nitsche.case import Interval, NONNEGATIVE, OneOf, POISSON, POSITIVE
from nitsche.meshes import refined
from nitsche.ops import dot, grad, lame, lap, sym_grad
from nitsche.supermesh import interface_report

NAME = "membrane-solid"
SUMMARY = "membrane pushed onto an elastic cube, 3D, hexahedra and quadrilaterals or tetrahedra and triangles (section 6.2)"
PARAMETERS = {
    "mu": (1.0, "membrane tension"),
    "load": (1.0, "downward pressure on the membrane"),
    "d": (0.02, "initial gap between the membrane and the cube's top face"),
    "E": (50.0, "Young's modulus of the cube"),
    "nu": (0.3, "Poisson's ratio of the cube"),
    "alpha0": ("auto", "Nitsche parameter (alpha = alpha0 h^2 / mu, h = membrane cell diameter)"),
    "n0": (5, "cells per side at level 0 (level k: n0 2^k)"),
    "m0": (0, "membrane cells per side at level 0 (0: n0, matching the cube)"),
    "supermesh": (True, "integrate the interface on the supermesh of the membrane and the "
                        "cube's top where the meshes do not match (False: at the membrane's "
                        "quadrature points)"),
    "cells": ("hex", "'hex': trilinear hexahedra and bilinear quadrilaterals; 'tet': linear "
                     "tetrahedra and triangles (P1)"),
}
# under mpirun the hooks sum the contact force, take the principal stresses' extremes over the
# ranks' own cells and collect the figures' values (the drawn facets' cells, the contact points)
OUTPUTS_FROM_PIECES = True
RANGES = {"mu": POSITIVE, "d": NONNEGATIVE, "E": POSITIVE, "nu": POISSON, "alpha0": POSITIVE,
          "n0": Interval(1, closed_lo=True), "m0": Interval(0, closed_lo=True),
          "cells": OneOf(("hex", "tet"))}
SHAPES = {"hex": (MeshHex, MeshQuad, ElementHex1, ElementQuad1, 2),  # solid intorder 2: exact for
          "tet": (MeshTet, MeshTri, ElementTetP1, ElementTriP1, 1)}   # the stiffness (1: constant strain)
DEGREES = (1,)
RATE = {1: 1.0}


def lift(x):
    """Membrane points (x, y) -> points (x, y, 1) on the cube's top face."""
    return np.concatenate([x, np.ones_like(x[:1])], axis=0)


def build(level, degree, p):
    Solid, Sheet, solid_element, sheet_element, intorder = SHAPES[p.cells]
    if p.cells == "hex":  # the tensor meshes of level 0 refined: the same meshes, and under
        # mpirun --local-meshes each rank's cells only, the cube's with those under its membrane cells
        t, s = (np.linspace(0.0, 1.0, n + 1) for n in (p.n0, p.m0 or p.n0))
        membrane = refined(Sheet.init_tensor(s, s), level)
        cube = refined(Solid.init_tensor(t, t, t), level, ghosts_for=(membrane, lift))
    else:  # six tetrahedra per cube of the finest grid (refined tetrahedra would differ)
        t, s = (np.linspace(0.0, 1.0, n * 2 ** level + 1) for n in (p.n0, p.m0 or p.n0))
        cube, membrane = Solid.init_tensor(t, t, t), Sheet.init_tensor(s, s)
    u = ni.Field("u", cube, ElementVector(solid_element()), fixed=lambda x: x[2] < 1e-12,
                 intorder=intorder)  # the default (64 points on hexahedra) is heavy
    w = ni.Field("w", membrane, sheet_element(), fixed="boundary")
    G, Lam = lame(p.E, p.nu)

    def solid(u):
        eps = sym_grad(u)
        return G * jnp.sum(eps * eps) + 0.5 * Lam * jnp.trace(eps) ** 2

    def sheet(w):
        return 0.5 * p.mu * dot(grad(w), grad(w)) + p.load * w

    contact = ni.Inequality(
        gap=lambda w, u: p.d + w - u[2],
        multiplier=lambda w: p.load - p.mu * lap(w),
        scaling=ni.Scaling(p.alpha0, h_power=2, stiffness=p.mu),
        on=ni.interface(w, "cells", to_other=lift, intorder=2, other=u,
                        pairing="auto" if p.supermesh else "points"), name="contact")
    return dict(fields=[u, w], energy=[ni.Integral(solid, ni.cells(u)), ni.Integral(sheet, ni.cells(w))],
                constraints=[contact])


# -- post-processing ---------------------------------------------------------------

CHUNK = 2 ** 14  # cells per block of the post-processing (bounds its temporaries)


def stress(field, u, E, nu, cells):
    """sigma = 2 mu eps + lam tr(eps) I, eps = sym grad u, of a 3D vector field (ElementVector:
    dof j d + i is the scalar function phi_j in component i) at the points of the quadrature
    of order 2 maxdeg (scikit-fem's default) of the given cells, or at their centroid for a
    linear element (P1 tetrahedra: the strain is constant in a cell), shape
    (3, 3, cells, points); grad u_i = sum_j u_{j d + i} grad phi_j."""
    b, element = field.dof_basis, field.element
    d = element.dim
    X = get_quadrature(field.mesh.refdom, 0 if element.maxdeg == 1 else 2 * element.maxdeg)[0]
    grads = [np.asarray(element.elem.gbasis(b.mapping, X, j, tind=cells)[0].grad) for j in range(b.Nbfun // d)]
    Gr = np.stack([sum(u[b.dofs.element_dofs[j * d + i, cells]][:, None] * g for j, g in enumerate(grads))
                   for i in range(d)])
    mu, lam = lame(E, nu)
    eps = 0.5 * (Gr + Gr.transpose(1, 0, 2, 3))
    tr = np.trace(eps)
    return 2 * mu * eps + lam * tr * np.eye(3)[:, :, None, None]


def principal_stresses(field, u, E, nu, cells=None):
    """Principal stresses at the points of `stress` in the cells (default all), descending:
    (3, cells, points); [0] is the first (largest) principal stress.  Computed CHUNK cells
    at a time."""
    cells = np.arange(field.mesh.nelements) if cells is None else np.asarray(cells)
    parts = []
    for start in range(0, cells.size, CHUNK):
        s = stress(field, u, E, nu, cells[start:start + CHUNK])
        ev = np.linalg.eigvalsh(np.moveaxis(s, (0, 1), (-2, -1)))  # ascending
        parts.append(np.moveaxis(ev[..., ::-1], -1, 0))
    return np.concatenate(parts, axis=1)


def report(problem, result, p):
    v = problem.constraint_values(result.x)["contact"]
    fu = problem.by_name["u"]
    s1 = principal_stresses(fu, result["u"], p.E, p.nu, partition.own_cells(fu.mesh))[0]
    w = result["w"]
    return dict(contact_force=float(partition.summed((v["W"] * v["multiplier"]).sum())),
                applied_load=float(p.load),  # on the unit square
                min_deflection=float(w.min()),
                first_principal_stress_max=float(partition.largest(s1.max(initial=-np.inf))),
                first_principal_stress_min=float(partition.smallest(s1.min(initial=np.inf))),
                interface=interface_report(problem, result.x, "contact"))


def study_extra(problem, result, row):
    v = problem.constraint_values(result.x)["contact"]
    row["contact_force"] = float((v["W"] * v["multiplier"]).sum())


def figures(problem, result, p, outdir):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection
    from nitsche.io import vertex_values
    from nitsche.plot import write_figure
    paths = []
    fu, fw = problem.by_name["u"], problem.by_name["w"]
    mesh = fu.mesh
    d = vertex_values(fu, result["u"])
    facets = mesh.boundary_facets()
    owner = mesh.f2t[0, facets]
    scale = 0.2 / max(np.abs(d).max(), 1e-300)
    X = (mesh.p.T + scale * d)[mesh.facets[:, facets].T]  # (facets, 4, 3)
    centre = X.mean(axis=1)
    keep = (centre[:, 0] > -1) & (np.abs(mesh.p[2, mesh.facets[:, facets]].mean(0)) > 1e-12)
    # cell means of the first principal stress, of the drawn facets' cells only (each rank's own)
    mine = np.flatnonzero(np.isin(owner[keep], partition.own_cells(mesh)))
    s1 = principal_stresses(fu, result["u"], p.E, p.nu, owner[keep][mine])[0].mean(axis=1) \
        if mine.size else np.empty(0)
    s1 = partition.collected(mine, s1, int(keep.sum()))
    v = problem.constraint_values(result.x)["contact"]
    active = partition.gathered(v["x"].reshape(-1, 2)[v["multiplier"].ravel() > 0])  # contact points
    if outdir is None:  # a rank other than 0 under mpirun: its part is in the data above
        return []
    # the facet vertices of skfem are ordered around the face (quadrilaterals; triangles)
    fig = plt.figure(figsize=(7, 6))
    ax = fig.add_subplot(projection="3d")
    norm = plt.Normalize(s1.min(), s1.max())
    coll = Poly3DCollection(X[keep], facecolors=plt.cm.coolwarm(norm(s1)),
                            edgecolors=(0, 0, 0, 0.15), linewidths=0.2)
    ax.add_collection3d(coll)
    ax.set_xlim(0, 1), ax.set_ylim(0, 1), ax.set_zlim(0, 1.1)
    ax.view_init(elev=25, azim=-60)
    sm = plt.cm.ScalarMappable(norm=norm, cmap="coolwarm")
    fig.colorbar(sm, ax=ax, shrink=0.6, label="first principal stress")
    ax.set_title(f"cube, displacement x{scale:.3g}, first principal stress")
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_zlabel("z")
    paths.append(write_figure(fig, os.path.join(outdir, "cube_principal_stress.png"), dpi=130))

    m = fw.mesh
    wv = vertex_values(fw, result["w"])
    fig = plt.figure(figsize=(11, 4.5))
    ax = fig.add_subplot(1, 2, 1)
    import matplotlib.tri as mtri
    tri = mtri.Triangulation(m.p[0], m.p[1], m.t.T if m.t.shape[0] == 3 else
                             np.r_[m.t[[0, 1, 2]].T, m.t[[0, 2, 3]].T])
    im = ax.tricontourf(tri, wv, levels=30, cmap="viridis")
    fig.colorbar(im, ax=ax, label="membrane deflection w")
    ax.plot(active[:, 0], active[:, 1], "w.", ms=1)
    ax.set_aspect("equal")
    ax.set_title("membrane deflection (white: contact)")
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax = fig.add_subplot(1, 2, 2, projection="3d")
    ax.plot_trisurf(tri, wv, cmap="viridis", linewidth=0)
    ax.set_title("membrane deflection")
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_zlabel("w")
    fig.tight_layout()
    paths.append(write_figure(fig, os.path.join(outdir, "membrane_deflection.png"), dpi=130))
    return paths


PAPER = [
    dict(command="run", degree=1, level=2, sets={}),
    dict(command="study", degree=1, levels=4, sets={}),
]
