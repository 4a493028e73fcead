"""The cost of pairing in 3D (nitsche.projection.closest_facets) against one linear solve.

A box (0, 1)^2 x (0, 0.2) of n x n x 2 hexahedra (Q1) or of their tetrahedra (P1); its top is
waved (z += 0.02 sin(6 x) cos(5 y)) and paired with 4 points above each top facet's
quarter (the quadrature points of a slave surface twice as fine).  Per size and facet type:
the first pairing (a k-d tree search), a re-pairing with the previous facets (hysteresis),
and, for scale, one assemble-and-solve of the box's linear elasticity (scikit-fem assembly,
nitsche.linalg's direct solver); medians of --repeat runs.  Prints a table and writes
benchmarks/results/pairing_3d.json.  Usage:
    python benchmarks/pairing_3d.py [--sizes 16 32 64] [--repeat 3]
"""
import argparse
import json
import os
import statistics
import time

import numpy as np
from skfem import Basis, BilinearForm, ElementHex1, ElementTetP1, ElementVector, MeshHex, MeshTet, asm, condense
from skfem.helpers import ddot, sym_grad

from nitsche.linalg import make_solver
from nitsche.projection import closest_facets
from nitsche.sliding import HYSTERESIS


@BilinearForm
def elasticity(u, v, w):
    return ddot(sym_grad(u), sym_grad(v))


def surface(n, tets):
    grid = (np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1), np.linspace(0, 0.2, 3))
    m = MeshTet.init_tensor(*grid) if tets else MeshHex.init_tensor(*grid)
    top = m.facets_satisfying(lambda p: p[2] > 0.2 - 1e-9, boundaries_only=True)
    p = m.p.copy()
    p[2] += 0.02 * np.sin(6 * p[0]) * np.cos(5 * p[1])
    return m, p.T[m.facets[:, top].T]


def slave_points(n):
    """4 points per quarter of a top facet, 0.01 above the flat top."""
    s = (np.arange(4 * n) + 0.5) / (4 * n)
    x, y = np.meshgrid(s, s)
    return np.stack([x.ravel(), y.ravel(), np.full(x.size, 0.21)], 1)


def one_solve(m, tets):
    basis = Basis(m, ElementVector(ElementTetP1() if tets else ElementHex1()))
    t = time.perf_counter()
    A = asm(elasticity, basis)
    b = np.ones(basis.N)
    A, b = condense(A, b, D=basis.get_dofs(lambda x: x[2] < 1e-9).all(), expand=False)[:2]
    lin = make_solver("auto", A.shape[0], 3, True)
    lin.solve(A.tocsr(), b, rtol=0.0)
    return time.perf_counter() - t, basis.N


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", type=int, nargs="+", default=[16, 32, 64])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    rows = []
    for n in args.sizes:
        for tets in (False, True):
            m, v = surface(n, tets)
            x = slave_points(n)
            first, again, solve = [], [], []
            for _ in range(args.repeat):
                t = time.perf_counter()
                facet, _ = closest_facets(x, v)
                first.append(time.perf_counter() - t)
                t = time.perf_counter()
                closest_facets(x + 0.001, v, facet, HYSTERESIS)
                again.append(time.perf_counter() - t)
                seconds, dofs = one_solve(m, tets)
                solve.append(seconds)
            row = dict(n=n, facets="triangles" if tets else "quadrilaterals", facet_count=len(v),
                       points=len(x), dofs=int(dofs), pairing=statistics.median(first),
                       re_pairing=statistics.median(again), solve=statistics.median(solve))
            row["pairing_over_solve"] = row["pairing"] / row["solve"]
            row["re_pairing_over_solve"] = row["re_pairing"] / row["solve"]
            rows.append(row)
            print(f"n={n:3d} {row['facets']:>14s} facets {len(v):6d} points {len(x):7d} dofs {dofs:7d} | "
                  f"pairing {row['pairing']:.3f} s, re-pairing {row['re_pairing']:.3f} s, one solve "
                  f"{row['solve']:.3f} s | ratios {row['pairing_over_solve']:.2f}, "
                  f"{row['re_pairing_over_solve']:.2f}", flush=True)
    out = os.path.join(os.path.dirname(__file__), "results", "pairing_3d.json")
    with open(out + ".tmp", "w") as f:
        json.dump(dict(rows=rows, load=os.getloadavg()), f, indent=1)
    os.replace(out + ".tmp", out)


if __name__ == "__main__":
    main()
