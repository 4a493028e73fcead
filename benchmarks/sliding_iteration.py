"""The pieces of one Newton iteration of ironing (pairing='current') per rank: the CPU time of
Problem.update_pairing (pairing, re-tabulation of the other body, the pattern's scatters),
of the pairing alone, of the local assembly with the Hessian and of the gradient, and of
each term's kernel calls, at the rest state (the tabulations and kernels do not depend on
the contact state).

    python benchmarks/sliding_iteration.py OUT.json LEVEL [REPEATS]              # serial
    mpirun -n R python benchmarks/sliding_iteration.py OUT.json LEVEL [REPEATS]  # each rank

Each piece is run once (compiled kernels, caches) and then timed over REPEATS runs; one row
per rank is appended to OUT.json (a list): ranks (0: serial), rank, unknowns, the sliding
interfaces' points and elements on the rank, milliseconds of CPU per piece, per term its
elements, the elements its kernel calls take (the padded chunks) and milliseconds per
Hessian call, the sizes of its calls, the seconds this process spent compiling or loading
kernels (assembly.compile_seconds: the kernel store warm, loading) and the load average."""
import json
import os
import sys
import time

import numpy as np

from nitsche import assembly, cases
from nitsche.distributed import launched_by_mpirun


def main(out, level, repeats):
    case = cases.get("ironing")
    p = case.parameters({})
    comm = None
    if launched_by_mpirun():
        from mpi4py import MPI
        from nitsche.distributed import DistributedProblem
        comm = MPI.COMM_WORLD
        problem = DistributedProblem.build(lambda: case.problem(level, case.degrees[0], p), comm).local
    else:
        problem = case.problem(level, case.degrees[0], p)
    x = problem.initial(None)
    x[problem.free] = 0.0
    measures = [problem.constraints[i].on for i in problem.sliding]
    terms = [problem.constraint_terms[i] for i in problem.sliding]

    def ms(f):
        f()
        if comm is not None:
            comm.Barrier()
        c = time.process_time()
        for _ in range(repeats):
            f()
        return round(1e3 * (time.process_time() - c) / repeats, 2)

    def pair():
        parts = problem.split(x)
        for m in measures:
            m.pair(parts[m.mine.name], parts[m.other.name])
    a = problem.assembler
    row = dict(level=level, ranks=0 if comm is None else comm.size, rank=0 if comm is None else comm.rank,
               unknowns=int(problem.free.size), points=[int(np.prod(m.shape)) for m in measures],
               elements=[t.nel for t in terms],
               ms=dict(update_pairing=ms(lambda: problem.update_pairing(x)), pair=ms(pair),
                       evaluate=ms(lambda: a.evaluate(x)), gradient=ms(lambda: a.gradient(x))),
               terms=[dict(elements=t.nel, called=sum(n for _, n in t.blocks(t.nel)),
                           calls=[n for _, n in t.blocks(t.nel)],
                           hessian_ms=ms(lambda t=t: list(t.calls("full", x)))) for t in a.terms],
               kernel_seconds=round(assembly.compile_seconds[0], 3), load_average=round(os.getloadavg()[0], 2))
    rows = [row] if comm is None else comm.gather(row, root=0)
    if comm is None or comm.rank == 0:
        old = json.load(open(out)) if os.path.exists(out) else []
        with open(out, "w") as f:
            json.dump(old + rows, f, indent=1)
        for r in rows:
            print(json.dumps(r), flush=True)


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), int(sys.argv[3]) if len(sys.argv) > 3 else 10)
