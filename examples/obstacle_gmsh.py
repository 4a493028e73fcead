"""An L-shaped membrane on an obstacle, P2 elements, on a mesh made with gmsh.

gmsh writes the L-shaped domain (-1, 1)^2 minus the quadrant (0, 1) x (-1, 0) with
physical groups: the curves "outer" and "reentrant" (the two edges at the notch) and the
surface "membrane".  scikit-fem reads the file (MeshTri.load) and turns the named curves
into mesh.boundaries, which Field(fixed=...), facets(...) and the reactions use by name.

    J(u)      = int 1/2 T |grad u|^2 - f u      (membrane of tension T, load f < 0: downward)
    g(u)      = u - psi >= 0   in every cell    (a flat obstacle psi = -depth below the membrane)
    lambda(u) = -T lap_h u - f                  (element-wise: the obstacle's pressure)
    alpha     = alpha0 h^2 / T                  (alpha0 = 'auto': half the stability limit)

u = 0 on the whole boundary.  Levels k = 0, 1, ... refine the gmsh mesh uniformly (the
named boundaries are refined with it), solved by nested iteration (ni.nested): each level
starts from the previous solution, and the successive differences |u_k - I u_(k-1)|_E
(energy norm) fall with h.  Asymptotically the rate is limited by the notch's corner
singularity (u ~ r^(2/3): rate 2/3) and by the free boundary of the contact set (u is C^1
but not C^2 there: rate 3/2 at most for P2); measured 1.23, then 0.77 (levels=4).
Force balance: total load |f| |Omega| = contact force + boundary reactions.
Run:  .venv/bin/python examples/obstacle_gmsh.py
"""
import os
import tempfile
import time

import numpy as np
from skfem import ElementTriP2, MeshTri

import nitsche as ni
from nitsche.norms import energy_norm
from nitsche.ops import dot, grad, lap
from nitsche.reactions import reactions


def lshape_msh(path, h0=0.2):
    """Write the L-shaped domain, mesh size h0, with named physical groups, to `path`."""
    import gmsh
    gmsh.initialize(interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("lshape")
        corners = [(-1, -1), (0, -1), (0, 0), (1, 0), (1, 1), (-1, 1)]
        pts = [gmsh.model.geo.addPoint(x, y, 0, h0) for x, y in corners]
        lines = [gmsh.model.geo.addLine(pts[i], pts[(i + 1) % 6]) for i in range(6)]
        surface = gmsh.model.geo.addPlaneSurface([gmsh.model.geo.addCurveLoop(lines)])
        gmsh.model.geo.synchronize()
        # (0,-1)-(0,0) and (0,0)-(1,0) are the notch's edges
        gmsh.model.addPhysicalGroup(1, [lines[1], lines[2]], name="reentrant")
        gmsh.model.addPhysicalGroup(1, [lines[0], lines[3], lines[4], lines[5]], name="outer")
        gmsh.model.addPhysicalGroup(2, [surface], name="membrane")
        gmsh.model.mesh.generate(2)
        gmsh.write(path)
    finally:
        gmsh.finalize()
    return path


def main(levels=3, T=1.0, f=-6.0, depth=0.2, h0=0.2, outdir=None, alpha0="auto"):
    t0 = time.perf_counter()
    outdir = outdir or tempfile.mkdtemp(prefix="nitsche-obstacle-")
    os.makedirs(outdir, exist_ok=True)
    path = lshape_msh(os.path.join(outdir, "lshape.msh"), h0)
    coarse = MeshTri.load(path)                  # physical groups -> boundaries, subdomains
    psi = -depth

    def make_problem(k):
        mesh = coarse.refined(k)
        u = ni.Field("u", mesh, ElementTriP2(), fixed="boundary")
        obstacle = ni.Inequality(gap=lambda u: u - psi,
                                 multiplier=lambda u: -T * lap(u) - f,
                                 scaling=ni.Scaling(alpha0, h_power=2, stiffness=T),
                                 on=ni.cells(u, intorder=6), name="obstacle")
        energy = lambda u: 0.5 * T * dot(grad(u), grad(u)) - f * u
        return ni.Problem([u], energy, [obstacle])

    rows, prev = [], None
    for k, problem, result in ni.nested(make_problem, range(levels), rtol=1e-12):
        result.check()
        c = result.constraints["obstacle"]
        R = reactions(problem, result.x)["u"]
        area = problem.fields[0].basis.dx.sum()       # |Omega| (= 3)
        row = dict(level=k, unknowns=int(problem.free.size), newton_iterations=result.iterations,
                   contact_force=c["total_multiplier"], contact_area=c["contact_measure"],
                   reaction=R["all"][0], reaction_outer=R["outer"][0],
                   reaction_reentrant=R["reentrant"][0],
                   balance_error=abs(R["all"][0] + c["total_multiplier"] + f * area) / abs(f * area),
                   max_violation=result.max_violation, min_u=float(result["u"].min()),
                   alpha0=float(problem.alpha0[problem.constraints[0].name].min()))
        if prev is not None:
            row["difference"] = energy_norm(problem, result.x - ni.prolongate(*prev, problem))
        rows.append(row)
        prev = (problem, result.x)
    d = [r["difference"] for r in rows[1:]]
    return dict(mesh_file=path, boundaries=sorted(coarse.boundaries), subdomains=sorted(coarse.subdomains or {}),
                levels=rows, differences=d,
                rates=[float(np.log2(a / b)) for a, b in zip(d[:-1], d[1:])],
                seconds=time.perf_counter() - t0)


if __name__ == "__main__":
    out = main()
    print("mesh:", out["mesh_file"], "boundaries:", out["boundaries"], "subdomains:", out["subdomains"])
    for row in out["levels"]:
        print("  ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items()))
    print("successive differences:", ", ".join(f"{d:.3e}" for d in out["differences"]),
          " rates:", ", ".join(f"{r:.2f}" for r in out["rates"]), f" ({out['seconds']:.1f} s)")
