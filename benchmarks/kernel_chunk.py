"""The Hessian kernel's time per element against the elements per call, term by term.

For a case's problem at a level, each term's 'full' kernel (energy, gradient, Hessian) is
compiled for each given number of elements per call and called on the term's first
elements at a state near the initial guess; the medians of 3 runs of CPU time per element
(all threads, what a shared machine disturbs least) and of wall time are printed beside
the call's Hessian entries (elements x points x local dofs^2: its output and the size of
its temporaries) and the term's own (small, large) sizes (Term.chunks).  Large calls of heavy elements
leave the caches: the knee shows where.

    python benchmarks/kernel_chunk.py ironing 3 [--set K=V ...] [--chunks 64 256 1024 4096]
        [--terms 0 1] [--name kernel_chunk_ironing.json]
"""
import argparse
import os
import statistics
import time

import numpy as np

from nitsche.cases import get
from nitsche.cli import parse_assignments
from run_ratio import write_results


def per_element(term, x, chunk, calls):
    """(CPU, wall) seconds per element of the term's Hessian kernel on `chunk` elements
    (medians of 3)."""
    rows = np.arange(chunk) % term.nel
    kernel = term.kernel("full", chunk)
    args = ([a if a.shape[0] == 1 else a.rows(rows) for a in term.tables]
            + [x[d[rows]] for d in term.field_dofs] + list(term.per_point(0, chunk, rows))
            + [term.parameter_data(chunk)])
    [np.asarray(o) for o in kernel(*args)]
    cpu, wall = [], []
    for _ in range(3):
        c, t = time.process_time(), time.perf_counter()
        for _ in range(calls):
            [np.asarray(o) for o in kernel(*args)]
        cpu.append((time.process_time() - c) / calls / chunk)
        wall.append((time.perf_counter() - t) / calls / chunk)
    return statistics.median(cpu), statistics.median(wall)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("case")
    ap.add_argument("level", type=int)
    ap.add_argument("--set", nargs="*", default=[], metavar="K=V", help="case parameters")
    ap.add_argument("--chunks", nargs="+", type=int, default=[64, 256, 1024, 4096, 16384])
    ap.add_argument("--terms", nargs="+", type=int, default=None, help="term indices (default all)")
    ap.add_argument("--name", default=None, help="write the rows to benchmarks/results/NAME")
    args = ap.parse_args()
    case = get(args.case)
    problem = case.problem(args.level, 1, case.parameters(parse_assignments(args.set)))
    x = problem.initial(None) + 1e-4
    terms = problem.assembler.terms
    rows = []
    for i in args.terms if args.terms is not None else range(len(terms)):
        t = terms[i]
        k = round((t.element_work / t.nq) ** 0.5)
        print(f"term {i}: {t.nel} elements, {t.nq} points, {k} local dofs, calls of {t.chunks} elements")
        for chunk in sorted(c - c % 8 if c >= 8 else c for c in args.chunks):
            cpu, wall = per_element(t, x, chunk, max(3, 20000 // chunk))
            rows.append(dict(term=i, elements=t.nel, points=t.nq, dofs=k, chunk=chunk,
                             entries=chunk * t.element_work, cpu_us_per_element=cpu * 1e6,
                             wall_us_per_element=wall * 1e6, own_chunks=list(t.chunks)))
            print(f"  {chunk:6d} elements per call: {cpu * 1e6:8.3f} us CPU, {wall * 1e6:8.3f} us wall "
                  f"per element, {chunk * t.element_work / 2 ** 20:7.2f} Mi Hessian entries per call")
    print("load average", os.getloadavg())
    if args.name:
        write_results(args.name, rows, f"{args.case} level {args.level} {' '.join(args.set)}")


if __name__ == "__main__":
    main()
