"""A clamped Kirchhoff plate pressed by a load onto a rigid flat obstacle (Morley elements).

The unit square plate, bending stiffness D, is clamped (u = du/dn = 0) on its boundary
and loaded by a uniform pressure f < 0 (downward).  A rigid flat table lies `depth` below
it: without the table the centre would sag by 0.00126 |f| / D, so for a smaller depth the
plate touches the table in a patch around the centre.

    J(u)      = int D/2 [(1 - nu) hess u : hess u + nu (lap u)^2] - f u   (element-wise:
                Morley is non-conforming)
    g(u)      = u + depth >= 0   in every cell        (the table is the plane u = -depth)
    lambda(u) = D lap^2 u - f    (element-wise; Morley is quadratic, so lambda_h = -f)
    alpha     = alpha0 h^4 / D   (lambda does not depend on u: J_h is convex for every
                alpha0, and 'auto' takes the cap 0.1)

Force balance: the load |f| |Omega| is carried by the clamped edges (the reactions of the
fixed value dofs) and the table (the contact force sum of W lambda_N).  In the contact
patch the plate is flat and the table's pressure is -f; the rest of the table force is
a line load along the patch's edge, which the discrete lambda_N spreads over a band of
cells around it.  On coarse levels alpha |lambda| = 0.1 h^4 |f| / D can exceed the depth:
then every cell counts as active (lambda_N > 0) although nothing touches yet, so read the
contact area from the finer levels.
Run:  .venv/bin/python examples/plate_obstacle.py
"""
import time

import numpy as np
from skfem import ElementTriMorley, MeshTri

import nitsche as ni
from nitsche.ops import hess
from nitsche.reactions import reactions


def main(level=4, D=1.0, nu=0.3, f=-1.0, depth=4e-4, alpha0="auto"):
    t0 = time.perf_counter()

    def bending(u):
        H = hess(u)
        tr = H[0, 0] + H[1, 1]
        return 0.5 * D * ((1 - nu) * (H ** 2).sum() + nu * tr ** 2) - f * u.value

    def make_problem(k):
        mesh = MeshTri().refined(k + 2)              # the unit square, 2 x 4^(k+2) triangles
        u = ni.Field("u", mesh, ElementTriMorley(), fixed="boundary")   # clamped: u, du/dn
        table = ni.Inequality(gap=lambda u: u + depth,
                              multiplier=lambda u: -f + 0.0 * u.value,   # D lap^2 u_h = 0
                              scaling=ni.Scaling(alpha0, h_power=4, stiffness=D),
                              on=ni.cells(u, intorder=4), name="table")
        return ni.Problem([u], ni.Integral(bending, ni.cells(u, intorder=2)), [table])

    rows = []
    for k, problem, result in ni.nested(make_problem, range(level + 1), rtol=1e-12):
        result.check()
        c = result.constraints["table"]
        R = reactions(problem, result.x)["u"]["all"][0]   # value dofs only (not the slopes)
        load = -f * 1.0                                  # |f| |Omega|
        mesh = problem.fields[0].mesh
        u = result["u"]
        centre = u[problem.fields[0].basis.nodal_dofs[0]][np.argmin(np.hypot(*(mesh.p - 0.5)))]
        rows.append(dict(level=k, unknowns=int(problem.free.size), newton_iterations=result.iterations,
                         load=load, edge_reaction=R, contact_force=c["total_multiplier"],
                         balance_error=abs(R + c["total_multiplier"] - load) / load,
                         contact_area=c["contact_measure"], centre_deflection=float(centre),
                         max_penetration=result.max_violation,
                         penetration_over_depth=result.max_violation / depth))
    return dict(levels=rows, seconds=time.perf_counter() - t0, free_sag=0.00126532 * -f / D)


if __name__ == "__main__":
    out = main()
    for row in out["levels"]:
        print("  ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items()))
    print(f"centre deflection without the table: {-out['free_sag']:.4g}; {out['seconds']:.1f} s")
