"""Kirchhoff plate resting on a unilateral edge support (paper section 6.4).

    J(u) = int D [1/2 (lap u)^2 + (1 - nu)(u_xy^2 - u_xx u_yy)] - f u   on (0,1)^2,
    on every boundary facet:  g(u) = u >= 0  (the plate may lift off its support),
    lambda(u) = -V(u) = -D [ sum_ij n_i u_,ijj + (1 - nu) sum_ijk n_i s_j s_k u_,ijk ]
    (Kirchhoff shear force, third derivatives of the cell that owns the facet),
    alpha = alpha0 h^3 / D  (h = cell diameter = sqrt(2) x side).

No dof is fixed: the rigid (affine) motions are held only by the contact term,
and M_nn = 0 holds naturally.  Bogner-Fox-Schmit elements (C^1 bicubics) in the
local-coordinate form of nitsche.bfs (scikit-fem's global-monomial BFS loses
digits on fine meshes).  Under the downward load the corners lift off their
support; no corner forces are used (docs/theory.md, plate-unilateral).
"""
import numpy as np
import jax.numpy as jnp
from skfem import MeshQuad

import nitsche as ni
from nitsche import partition
from nitsche.bfs import ElementQuadBFSLocal
from nitsche.case import NEGATIVE, PLATE_POISSON, POSITIVE
from nitsche.ops import hess, grad3, tangent

NAME = "plate-unilateral"
SUMMARY = "Kirchhoff plate (BFS) on a unilateral edge support, corners lift (section 6.4)"
PARAMETERS = {
    "D": (1.0, "bending stiffness"),
    "nu": (0.3, "Poisson ratio"),
    "f": (-1.0, "load per unit area (negative: downward, towards the support)"),
    "alpha0": ("auto", "Nitsche parameter (alpha = alpha0 h^3 / D, h = cell diameter); "
                       "stable below ~4e-4 (computed: 'auto' takes half the limit)"),
}
# f < 0: only the support holds the plate; an upward load lifts it off (unbounded)
RANGES = {"D": POSITIVE, "nu": PLATE_POISSON, "f": NEGATIVE, "alpha0": POSITIVE}
DEGREES = (3,)          # bicubic Bogner-Fox-Schmit
RATE = {3: 2.0}         # paper: about 2 (measured step rates are ragged, mean ~1.8)
PAPER = [dict(command="study", degree=3, levels=6, level=None, sets={}),
         dict(command="run", degree=3, levels=None, level=4, sets={})]
EDGES = ("x = 0", "x = 1", "y = 0", "y = 1")
OUTPUTS_FROM_PIECES = True  # report and figure: sums, extremes and edge lines over the ranks


def shear_force(u, n, D, nu):
    """Kirchhoff shear force V(u) = D [d_n lap u + (1 - nu) d_n d_s^2 u] on a facet."""
    G, s = grad3(u), tangent(n)
    return D * (jnp.einsum("i,ijj->", n, G) + (1 - nu) * jnp.einsum("i,j,k,ijk->", n, s, s, G))


def build(level, degree, p):
    mesh = MeshQuad().refined(level + 2)
    u = ni.Field("u", mesh, ElementQuadBFSLocal())

    def energy(u):
        H = hess(u)
        lap = H[0, 0] + H[1, 1]
        return p.D * (0.5 * lap ** 2 + (1 - p.nu) * (H[0, 1] ** 2 - H[0, 0] * H[1, 1])) - p.f * u

    support = ni.Inequality(gap=lambda u: u.value,
                            multiplier=lambda u, n: -shear_force(u, n, p.D, p.nu),
                            scaling=ni.Scaling(p.alpha0, h_power=3, stiffness=p.D),
                            on=ni.facets(u, intorder=6), name="support")
    return dict(fields=[u], energy=ni.Integral(energy, ni.cells(u, intorder=6)),
                constraints=[support])


def vertex_deflection(problem, x):
    """Deflection at the mesh vertices (the u dofs of the BFS field)."""
    f = problem.fields[0]
    return problem.split(x)[f.name][f.dof_basis.nodal_dofs[0]]


def edge_of(xq):
    """Index into EDGES of the boundary points xq (..., 2)."""
    x, y = xq[..., 0], xq[..., 1]
    return np.select([np.isclose(x, 0), np.isclose(x, 1), np.isclose(y, 0), np.isclose(y, 1)],
                     [0, 1, 2, 3], -1)


def support_quantities(problem, result, p):
    """Lifted length per edge, reaction balance, sign of the strong shear force."""
    v = problem.constraint_values(result.x)["support"]
    W, lam_n, lam = v["W"], v["multiplier"], v["lam"]
    edge = edge_of(v["x"].mean(axis=1))
    lifted = partition.summed([(W[edge == k] * (lam_n[edge == k] <= 0)).sum() for k in range(4)])
    load = -p.f * 1.0  # total load on the unit square
    reaction = float(support_reaction(problem, result.x))
    active = lam_n > 0
    # strong-form shear force -V(u_h) on the supported part: >= 0 up to consistency
    # (its extremes over the ranks' active points; infinite where no point is active)
    low = float(partition.smallest(lam[active].min(initial=np.inf)))
    high = float(partition.largest(lam[active].max(initial=-np.inf)))
    u = vertex_deflection(problem, result.x)
    corners = problem.fields[0].mesh.p
    at_corner = [int(np.argmin(np.hypot(corners[0] - a, corners[1] - b)))
                 for a, b in ((0, 0), (1, 0), (1, 1), (0, 1))]
    return dict(lifted_length=[float(s) for s in lifted],
                lifted_length_mean=float(np.mean(lifted)),
                reaction_total=reaction, load_total=load,
                reaction_balance=reaction / load,
                min_shear_reaction=low if np.isfinite(low) else 0.0,
                max_shear_reaction=high if np.isfinite(high) else 0.0,
                corner_lift=[float(u[i]) for i in at_corner],
                max_penetration=float(partition.largest(np.maximum(-v["g"], 0).max(initial=0.0))))


def support_reaction(problem, x):
    """The total support reaction int lambda_N (summed over the ranks' facets)."""
    v = problem.constraint_values(x)["support"]
    return float(partition.summed((v["W"] * v["multiplier"]).sum()))


def edge_reactions(problem, x):
    """Per edge (EDGES): the positions along it of the support's quadrature points and
    lambda_N there, in order along the edge (all ranks' points, gathered)."""
    v = problem.constraint_values(x)["support"]
    xq = partition.gathered(v["x"].reshape(-1, 2))
    lam = partition.gathered(v["multiplier"].ravel())
    edge = edge_of(xq)
    out = []
    for k in range(len(EDGES)):
        t = np.where(k < 2, xq[:, 1], xq[:, 0])[edge == k]
        o = np.argsort(t)
        out.append((t[o], lam[edge == k][o]))
    return out


def report(problem, result, p):
    return support_quantities(problem, result, p)


def study_extra(problem, result, row):
    q = support_quantities(problem, result, problem.setup.p)
    row.update(lifted_length=q["lifted_length_mean"], lifted_per_edge=q["lifted_length"],
               reaction_balance=q["reaction_balance"], min_shear_reaction=q["min_shear_reaction"],
               corner_lift=q["corner_lift"][2])


def figures(problem, result, p, outdir):
    """Fig. 9: the deflection with lifted corners, and the support reaction along the edges."""
    import os
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from nitsche.plot import write_figure
    lines, total = edge_reactions(problem, result.x), support_reaction(problem, result.x)
    if outdir is None:  # a rank other than 0 under mpirun: its part is in the data above
        return []
    mesh = problem.fields[0].mesh
    u = vertex_deflection(problem, result.x)
    fig = plt.figure(figsize=(11, 4.4))
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    n = int(round(np.sqrt(mesh.p.shape[1])))
    order = np.lexsort((mesh.p[0], mesh.p[1]))
    X, Y, Z = (a[order].reshape(n, n) for a in (mesh.p[0], mesh.p[1], u))
    ax.plot_surface(X, Y, Z, cmap="viridis", linewidth=0, antialiased=True)
    ax.set_title("deflection u (corners lift off)")
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_zlabel("deflection u")
    ax2 = fig.add_subplot(1, 2, 2)
    for (t, lam), name in zip(lines, EDGES):
        ax2.plot(t, lam, "-", lw=1.2, label=name)
    ax2.axhline(0, color="k", lw=0.5)
    ax2.set_xlabel("position along the edge")
    ax2.set_ylabel(r"support reaction $\lambda_N$ (force / length)")
    ax2.set_title(f"total reaction {total:.6f}, load {-p.f:.6f}")
    ax2.legend()
    fig.tight_layout()
    return [write_figure(fig, os.path.join(outdir, "plate_unilateral.png"), dpi=120)]
