"""The free vectors Newton's method is handed on the ranks of mpirun (for test_distributed.py):
python mpi_held.py CASE:LEVEL ...; each rank solves with every free vector the distributed
problem gives newton recorded (the Newton gradient, the step of each KSP solve, each product
A v, each free_part) and rank 0 prints one JSON line per case: the energy and Newton
iterations, and per rank the lengths seen, the numbers of held, owned and free dofs, and
whether the local numbering is the one of the Layout (owned dofs first, in PETSc's order,
then ghosts that other ranks own)."""
import json
import sys

import numpy as np

from nitsche import cases
from nitsche.distributed import DistributedMatrix, DistributedProblem, KrylovSolver


def recording(f, seen, kind, pick=lambda out: out):
    """f, recording the length of (a part of) what it returns under `kind`."""
    def inner(*a, **k):
        out = f(*a, **k)
        seen.setdefault(kind, set()).add(len(pick(out)))
        return out
    return inner


def main(specs):
    seen = {}
    KrylovSolver.solve = recording(KrylovSolver.solve, seen, "step")
    DistributedMatrix.__matmul__ = recording(DistributedMatrix.__matmul__, seen, "product")
    for spec in specs:
        name, level = spec.split(":")
        case = cases.get(name)
        dp = DistributedProblem.build(lambda: case.problem(int(level), case.degrees[0],
                                                           case.parameters({})))
        seen.clear()
        dp.newton_system = recording(dp.newton_system, seen, "newton gradient", lambda out: out[1])
        dp.free_part = recording(dp.free_part, seen, "free_part")
        r = dp.minimize(solver="direct")
        layout = dp.layout
        held, owned = layout.held, layout.owned
        petsc = np.empty(layout.n, np.int64)
        petsc[layout.order] = np.arange(layout.n)
        ghosts = np.searchsorted(np.cumsum(layout.counts), petsc[held[owned:]], side="right")
        row = dict(lengths={k: sorted(v) for k, v in seen.items()}, held=int(held.size),
                   owned=int(owned), free=int(layout.n),
                   owned_in_petsc_order=bool(np.array_equal(
                       petsc[held[:owned]], layout.start + np.arange(owned))),
                   ghosts_of_other_ranks=bool(np.all(ghosts != dp.rank)),
                   distinct=bool(np.unique(held).size == held.size),
                   dofs=bool(np.array_equal(layout.dofs, dp.local.free[held])))
        rows = dp.comm.gather(row, root=0)
        if dp.rank == 0:
            print(json.dumps(dict(case=name, energy=r.energy, iterations=r.iterations,
                                  converged=r.converged, ranks=rows)), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
