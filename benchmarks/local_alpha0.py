"""The cost of alpha0='auto' (element-local stability limits) against one Newton assembly,
and against the global eigenproblem it replaced, at several sizes in 2D and 3D.

Problems: the obstacle (P2, cell Laplacian on every cell), the elastic-contact punch (P2,
facet traction) and a 3D Signorini block (vector Q1 or P2 tetrahedra, traction on the
bottom facets, cells graded towards the contact: flat cells there).  Per size:
  local     Problem.local_limits() with the energy's element Hessians already stored (they
            are computed once per mesh and reused by the Newton assembly: their cost is
            reported in 'first_assembly');
  assembly  one Newton assembly, Problem.newton_system(x) (J_h, gradient, Hessian);
  first_assembly  the first one, quadratic energy terms included;
  global    Problem.stability_limits(), the sparse-LU eigenproblem of the previous version
            (skipped above --global-max unknowns).
Medians of --repeat runs; kernels compiled beforehand (compilation is reported apart).
Usage:  python benchmarks/local_alpha0.py [--repeat 3] [--global-max 40000]
Writes benchmarks/results/local_alpha0.json.
"""
import argparse
import json
import os
import statistics
import time

import jax.numpy as jnp
import numpy as np
from skfem import ElementHex1, ElementTetP2, ElementVector, MeshHex, MeshTet

import nitsche as ni
import nitsche.assembly
from nitsche.cases import get
from nitsche.ops import dot, sym_grad

RESULTS = os.path.join(os.path.dirname(__file__), "results")


def signorini_3d(n, element="Q1", grading=1.5):
    """Unit cube, E = 1, nu = 0.3, contact with a rigid plane on z = 0 (gap u_z + x^2/2 >= 0,
    multiplier -sigma_zz), top pushed down by 0.01; n cells per side, z graded by `grading`."""
    t = np.linspace(0, 1, n + 1)
    z = t ** grading
    mesh = MeshHex.init_tensor(t, t, z)
    if element == "P2":
        mesh = MeshTet.init_tensor(t, t, z)
    e = ElementVector(ElementHex1() if element == "Q1" else ElementTetP2())
    mu, lam = 1 / 2.6, 0.3 / (1.3 * 0.4)
    top = lambda x: x[2] > 1 - 1e-12
    u = ni.Field("u", mesh, e, fixed=top,
                 value=lambda x: np.stack([0 * x[0], 0 * x[0], -0.01 + 0 * x[0]]))

    def energy(u):
        eps = sym_grad(u)
        tr = eps[0, 0] + eps[1, 1] + eps[2, 2]
        return mu * jnp.sum(eps * eps) + 0.5 * lam * tr * tr

    def sigma_nn(u, n):
        eps = sym_grad(u)
        tr = eps[0, 0] + eps[1, 1] + eps[2, 2]
        return dot(n, dot(2 * mu * eps + lam * tr * jnp.eye(3), n))

    contact = ni.Inequality(gap=lambda u, x: u[2] + 0.5 * (x[0] - 0.5) ** 2,
                            multiplier=lambda u, n: -sigma_nn(u, n),
                            scaling=ni.Scaling("auto", h_power=1, stiffness=1.0),
                            on=ni.facets(u, lambda x: x[2] < 1e-12), name="contact")
    return ni.Problem([u], ni.Integral(energy, ni.cells(u)), [contact])


def median_time(fn, repeat):
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def measure(label, make, repeat, global_max):
    c0 = nitsche.assembly.compile_seconds[0]
    t = time.perf_counter()
    problem = make()
    construct = time.perf_counter() - t
    x = problem.initial(None)
    t = time.perf_counter()
    problem.newton_system(x)
    first = time.perf_counter() - t
    local, assembly = [], []
    for _ in range(repeat):  # interleaved: the machine is shared
        local.append(median_time(problem.local_limits, 1))
        assembly.append(median_time(lambda: problem.newton_system(x), 1))
    local, assembly = statistics.median(local), statistics.median(assembly)
    glob = median_time(problem.stability_limits, 1) if problem.free.size <= global_max else None
    row = dict(problem=label, unknowns=int(problem.free.size),
               elements=int(sum(t.nel for t in problem.constraint_terms)),
               local=local, assembly=assembly, first_assembly=first, construct=construct,
               global_=glob, local_over_assembly=local / assembly,
               compile=nitsche.assembly.compile_seconds[0] - c0,
               limit_min={k: float(v.min()) for k, v in problem.limits.items()},
               limit_median={k: float(np.median(v)) for k, v in problem.limits.items()})
    print(f"{label:<28} {row['unknowns']:>8} unknowns {row['elements']:>7} el.  local {local:7.3f} s  "
          f"assembly {assembly:7.3f} s  (x{local / assembly:5.2f})  first {first:7.3f} s  "
          f"global {glob if glob is None else round(glob, 3)} s", flush=True)
    return row


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--global-max", type=int, default=40000)
    ap.add_argument("--small", action="store_true", help="the two smallest sizes only")
    args = ap.parse_args()
    obstacle, punch = get("obstacle"), get("elastic-contact")
    runs = [(f"obstacle P2 level {k}", lambda k=k: obstacle.problem(k, 2, obstacle.parameters()))
            for k in (3, 4, 5)]
    runs += [(f"elastic-contact P2 level {k}", lambda k=k: punch.problem(k, 2, punch.parameters()))
             for k in (2, 3, 4)]
    runs += [(f"3D Signorini Q1 n={n}", lambda n=n: signorini_3d(n, "Q1")) for n in (8, 16, 24)]
    runs += [(f"3D Signorini P2 tet n={n}", lambda n=n: signorini_3d(n, "P2")) for n in (4, 8, 12)]
    if args.small:
        runs = [r for i, r in enumerate(runs) if i % 3 < 2]
    rows = [measure(label, make, args.repeat, args.global_max) for label, make in runs]
    os.makedirs(RESULTS, exist_ok=True)
    with open(os.path.join(RESULTS, "local_alpha0.json"), "w") as fh:
        json.dump(dict(rows=rows, cpu_count=os.cpu_count()), fh, indent=1)


if __name__ == "__main__":
    main()
