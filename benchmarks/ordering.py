"""CHOLMOD's orderings against the geometric nested dissection (nitsche.ordering), side by side.

For each matrix and ordering, in a fresh process (interleaved: amd, metis, ours, amd, ...):
the symbolic analysis (ours: the nested dissection, the permuted pattern and CHOLMOD's
analysis without ordering), the numeric factorization (median of 3), nnz(L), one solve
(median of 3) and the memory the analysis and factorization add (peak resident memory
after the matrix is built, VmHWM reset then, minus the resident memory at that point),
all through nitsche.linalg.Cholmod as a Newton solve uses it; CPU times (user + system).
The matrices, on the free (interior) nodes of the cases' meshes, K + M (P1 stiffness and
mass: every element coupling, the pattern of the Newton matrices; the Laplacian alone
drops the couplings that cancel on right-angled triangles):
  obstacle      the obstacle case's mesh (the square (-2, 2)^2, criss-cross triangles;
                1m: the 1024 x 1024 tensor mesh of the scaling study),
  two-membrane  two fields u1, u2 on the unit square's mesh (numbered one after the
                other, as the case's), coupled by the mass matrix C of the cells in the
                disc |x - (0.5, 0.5)| < 0.25 (a contact set): [[K + M + C, -C], [-C,
                K + M + C]] (1m: the 708 x 708 tensor mesh),
  tet           the unit cube's n^3 cubes, six P1 tetrahedra each.
Writes benchmarks/results/ordering.json (--name: another file).

    python benchmarks/ordering.py --cases obstacle two-membrane --sizes 130k 523k 1m
    python benchmarks/ordering.py --cases tet --sizes 24k 118k
"""
import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from memory_phases import status as vm  # noqa: E402  (a /proc/self/status value in MB)

HERE = os.path.dirname(os.path.abspath(__file__))
RESULTS = os.path.join(HERE, "results")
ORDERINGS = ("amd", "metis", "ours")
# size label -> refinements of the case's coarsest mesh (2D), or cubes per side (tet);
# "1m": the tensor meshes of about a million unknowns
SIZES = {"obstacle": {"8k": 6, "33k": 7, "130k": 8, "523k": 9, "1m": 1024},
         "two-membrane": {"8k": 6, "33k": 7, "130k": 8, "523k": 9, "1m": 708},
         "tet": {"6k": 20, "24k": 30, "54k": 39, "118k": 50}}


def matrix(case, size):
    """(A CSC on the free dofs, their points (n, dim)) of a case at a size label."""
    import scipy.sparse as sp
    from skfem import Basis, ElementTetP1, ElementTriP1, MeshTet, MeshTri, asm
    from skfem.models.poisson import laplace, mass
    k = SIZES[case][size]
    if case == "tet":
        t = np.linspace(0.0, 1.0, k + 1)
        mesh, element = MeshTet.init_tensor(t, t, t), ElementTetP1()
    elif size == "1m":
        t = np.linspace(-2.0, 2.0, k + 1) if case == "obstacle" else np.linspace(0.0, 1.0, k + 1)
        mesh, element = MeshTri.init_tensor(t, t), ElementTriP1()
    elif case == "obstacle":
        mesh = MeshTri.init_symmetric().scaled((4.0, 4.0)).translated((-2.0, -2.0)).refined(k)
        element = ElementTriP1()
    else:
        mesh, element = MeshTri().refined(k), ElementTriP1()
    basis = Basis(mesh, element)
    K = (asm(laplace, basis) + asm(mass, basis)).tocsc()
    free = basis.complement_dofs(basis.get_dofs())
    points = mesh.p.T[free]
    K = K[free][:, free]
    if case != "two-membrane":
        return K.tocsc(), points
    centroids = mesh.p[:, mesh.t].mean(axis=1)
    disc = np.flatnonzero(np.hypot(centroids[0] - 0.5, centroids[1] - 0.5) < 0.25)
    C = asm(mass, Basis(mesh, element, elements=disc)).tocsc()[free][:, free]
    A = sp.bmat([[K + C, -C], [-C, K + C]], format="csc")
    return A, np.concatenate([points, points])


def cpu():
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def child(case, size, ordering):
    """One matrix, one ordering: the measurements as a JSON line on stdout."""
    import gc
    from nitsche.linalg import Cholmod, NonzeroPattern
    A, points = matrix(case, size)
    b = np.ones(A.shape[0])
    gc.collect()
    with open("/proc/self/clear_refs", "w") as fh:
        fh.write("5")  # VmHWM := VmRSS
    base = vm("VmRSS")
    lin = Cholmod(ordering="amd" if ordering == "ours" else ordering, geometric=ordering == "ours")
    lin.keep_factored = False
    lin.coordinates = (lambda: points) if ordering == "ours" else None
    t = cpu()
    lin.analyzed = NonzeroPattern(A)
    lin._analyze(A)
    analysis = cpu() - t
    factor, solve = [], []
    for _ in range(3):
        t = cpu()
        lin._factor(A)
        factor.append(cpu() - t)
    for _ in range(3):
        t = cpu()
        x = lin._solve(b)
        solve.append(cpu() - t)
    peak = vm("VmHWM") - base
    residual = float(np.linalg.norm(A @ x - b) / np.linalg.norm(b))
    nnz = int(lin.factor.nnz)
    print(json.dumps(dict(case=case, size=size, ordering=ordering, n=A.shape[0], nnz_A=int(A.nnz),
                          analysis=analysis, factor=statistics.median(factor), solve=statistics.median(solve),
                          nnz_L=nnz, memory_mb=peak, residual=residual)))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="+", default=["obstacle", "two-membrane"])
    ap.add_argument("--sizes", nargs="+", default=["130k", "523k", "1m"])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--name", default="ordering.json", help="the results file in benchmarks/results")
    ap.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        return child(*args.child)
    unknown = [f"{c} {s}" for c in args.cases for s in args.sizes if s not in SIZES.get(c, {})]
    if unknown:
        ap.error(f"no such matrix: {', '.join(unknown)}; sizes: "
                 + "; ".join(f"{c}: {', '.join(v)}" for c, v in SIZES.items()))
    rows = []
    for case in args.cases:
        for size in args.sizes:
            runs = {o: [] for o in ORDERINGS}
            for _ in range(args.repeat):
                for o in ORDERINGS:
                    out = subprocess.run([sys.executable, __file__, "--child", case, size, o],
                                         capture_output=True, text=True, check=True).stdout
                    runs[o].append(json.loads(out.strip().splitlines()[-1]))
            for o in ORDERINGS:
                row = dict(runs[o][0])
                for key in ("analysis", "factor", "solve", "memory_mb"):
                    row[key] = statistics.median(r[key] for r in runs[o])
                row["runs"] = runs[o]
                rows.append(row)
                print(f"{case:<13}{row['n']:>9d} {o:<6}{row['analysis']:>9.3f}{row['factor']:>9.3f}"
                      f"{row['analysis'] + row['factor']:>9.3f}{row['nnz_L'] / 1e6:>9.2f}"
                      f"{row['solve']:>8.3f}{row['memory_mb']:>9.0f}", flush=True)
    print(f"\n{'case':<13}{'unknowns':>9} {'order':<6}{'analysis':>9}{'factor':>9}{'sum':>9}"
          f"{'nnz(L) M':>9}{'solve':>8}{'MB':>9}   (CPU s, medians of {args.repeat})")
    for row in rows:
        print(f"{row['case']:<13}{row['n']:>9d} {row['ordering']:<6}{row['analysis']:>9.3f}"
              f"{row['factor']:>9.3f}{row['analysis'] + row['factor']:>9.3f}{row['nnz_L'] / 1e6:>9.2f}"
              f"{row['solve']:>8.3f}{row['memory_mb']:>9.0f}")
    os.makedirs(RESULTS, exist_ok=True)
    with open(os.path.join(RESULTS, args.name), "w") as fh:
        json.dump(dict(rows=rows, cpu_count=os.cpu_count(), load=os.getloadavg(),
                       date=time.strftime("%Y-%m-%d %H:%M"), repeat=args.repeat), fh, indent=1)


if __name__ == "__main__":
    sys.exit(main())
