"""Obstacle (or two-membrane) case, P1, at about 130 000 unknowns: assembly and solve against
plain scikit-fem.

Prints a table (and writes benchmarks/results/obstacle_assembly.json):
  - Hessian assembly of J_h per Newton step, and its first assembly (quadratic terms
    included), divided by scikit-fem's BilinearForm Laplace assembly on the same mesh
    (once per field: two for two-membrane);
  - the Newton solve at the finest level (nested iteration from the level below) and the
    whole nested chain, divided by one linear Laplace assemble-and-solve of the same size;
  - JIT compilation time, reported separately (compiled kernels are reused across levels).
Timings are medians of --repeat runs, interleaved.  Usage:
    python benchmarks/obstacle_assembly.py [--case two-membrane] [--level 6] [--repeat 5]
"""
import argparse
import json
import os
import statistics
import time

from skfem import BilinearForm, LinearForm, asm, condense
from skfem.helpers import dot, grad

import numpy as np
import scipy.sparse as sp

import nitsche.assembly
from nitsche.cases import get
from nitsche.linalg import make_solver
from nitsche.study import prolongate


@BilinearForm
def laplace(u, v, w):
    return dot(grad(u), grad(v))


@LinearForm
def unit(v, w):
    return v


def timed(fn):
    t = time.perf_counter()
    out = fn()
    return time.perf_counter() - t, out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", default="obstacle", choices=["obstacle", "two-membrane"])
    ap.add_argument("--level", type=int, default=6)
    ap.add_argument("--degree", type=int, default=1)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    case = get(args.case)
    p = case.parameters({"compare": "false"} if args.case == "two-membrane" else {})
    c0 = nitsche.assembly.compile_seconds[0]

    # the nested chain: levels 0 .. level, each starting from the previous solution
    chain, solved, its = [], [], []
    for level in range(args.level + 1):
        t_setup, problem = timed(lambda: case.problem(level, args.degree, p))
        x0 = prolongate(*solved[-1], problem) if solved else None
        t_solve, res = timed(lambda: problem.minimize(x0))
        res.check()
        chain.append(t_setup + t_solve)
        its.append(res.iterations)
        solved.append((problem, res.x))
    compile_total = nitsche.assembly.compile_seconds[0] - c0
    fine, x_fine = solved[-1]
    basis = fine.fields[0].basis
    nfields = len(fine.fields)
    x_start = prolongate(*solved[-2], fine)

    rows = {"ours_hessian_step": [], "ours_hessian_first": [], "skfem_laplace": [],
            "ours_solve_fine": [], "linear_assemble_solve": []}
    for _ in range(args.repeat):
        fresh = case.problem(args.level, args.degree, p)
        rows["ours_hessian_first"].append(timed(lambda: fresh.newton_system(x_fine))[0])
        rows["ours_hessian_step"].append(timed(lambda: fresh.newton_system(x_fine))[0])
        rows["skfem_laplace"].append(timed(lambda: [asm(laplace, basis) for _ in range(nfields)])[0])
        rows["ours_solve_fine"].append(timed(lambda: fresh.minimize(x_start))[0])

        def linear():
            K = sp.block_diag([asm(laplace, basis) for _ in range(nfields)])
            f = np.concatenate([asm(unit, basis)] * nfields)
            A, b, _, I = condense(K.tocsr(), f, D=fine.fixed)
            return make_solver("auto").solve(A.tocsr(), b)
        rows["linear_assemble_solve"].append(timed(linear)[0])
    med = {k: statistics.median(v) for k, v in rows.items()}
    out = dict(case=args.case, level=args.level, degree=args.degree, unknowns=int(fine.free.size), dofs=int(fine.ndofs),
               newton_iterations_per_level=its, chain_seconds=sum(chain),
               compile_seconds=compile_total, medians=med,
               ratio_hessian_step=med["ours_hessian_step"] / med["skfem_laplace"],
               ratio_hessian_first=med["ours_hessian_first"] / med["skfem_laplace"],
               ratio_solve_fine=med["ours_solve_fine"] / med["linear_assemble_solve"],
               ratio_chain=(sum(chain) - compile_total) / med["linear_assemble_solve"],
               solver=make_solver("auto").name, cpu_count=os.cpu_count(),
               date=time.strftime("%Y-%m-%d"))
    print(f"{args.case} P{args.degree}, level {args.level}: {out['unknowns']} unknowns, solver {out['solver']}")
    print(f"Newton iterations per level (nested): {its}")
    print(f"{'quantity':<44}{'seconds':>10}{'ratio':>9}{'target':>8}")
    print(f"{'scikit-fem BilinearForm Laplace assembly' + (' x2' if nfields == 2 else ''):<44}{med['skfem_laplace']:>10.3f}")
    print(f"{'J_h Hessian assembly, per Newton step':<44}{med['ours_hessian_step']:>10.3f}"
          f"{out['ratio_hessian_step']:>9.2f}{'<= 2':>8}")
    print(f"{'J_h Hessian assembly, first (incl. quadratic)':<44}{med['ours_hessian_first']:>10.3f}"
          f"{out['ratio_hessian_first']:>9.2f}{'<= 2':>8}")
    print(f"{'linear Laplace assemble + solve':<44}{med['linear_assemble_solve']:>10.3f}")
    print(f"{'Newton solve, finest level (nested start)':<44}{med['ours_solve_fine']:>10.3f}"
          f"{out['ratio_solve_fine']:>9.2f}{'<= 10':>8}")
    print(f"{'whole nested chain, levels 0..' + str(args.level) + ' (no compile)':<44}"
          f"{sum(chain) - compile_total:>10.3f}{out['ratio_chain']:>9.2f}")
    print(f"{'JIT compilation (all levels, reported apart)':<44}{compile_total:>10.3f}")
    os.makedirs(os.path.join(os.path.dirname(__file__), "results"), exist_ok=True)
    with open(os.path.join(os.path.dirname(__file__), "results", f"{args.case}_assembly.json"), "w") as fh:
        json.dump(out, fh, indent=2)


if __name__ == "__main__":
    main()
