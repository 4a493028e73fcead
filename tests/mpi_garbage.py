"""What PETSc holds over repeated Newton steps on the ranks of mpirun (for
test_distributed.py): with PETSc's allocations traced (-malloc_debug), the obstacle at level 2
takes the steps of Newton's method (the Newton system, a KSP solve, a product, the minimum
check) 8 times at one x; rank 0 prints one JSON line with each rank's PETSc-held bytes
(PetscMallocGetCurrentUsage) after every step.  The vectors Python drops must be destroyed
(petsc4py keeps parallel ones until PETSc.garbage_cleanup): the bytes stay the same."""
import ctypes
import json

import petsc4py

petsc4py.init(["-malloc_debug"])

import numpy as np  # noqa: E402

from nitsche import cases  # noqa: E402
from nitsche.distributed import DistributedProblem, KrylovSolver  # noqa: E402


def petsc_bytes():
    with open("/proc/self/maps") as fh:  # the libpetsc petsc4py loaded
        path = next(line.split()[-1] for line in fh if "/libpetsc.so" in line)
    used = ctypes.c_double()
    ctypes.CDLL(path).PetscMallocGetCurrentUsage(ctypes.byref(used))
    return used.value


def main():
    case = cases.get("obstacle")
    dp = DistributedProblem.build(lambda: case.problem(2, 1, case.parameters({})))
    solver = KrylovSolver("gamg", dp)
    solver.prepare(dp)
    x = dp.local.initial(np.zeros(dp.local.ndofs))
    held = []
    for _ in range(8):
        _, g, A = dp.newton_system(x)
        dx = solver.solve(A, -g, 1e-8)
        A @ dx
        solver.is_positive_definite(A)
        held.append(petsc_bytes())
    rows = dp.comm.gather(held, root=0)
    if dp.rank == 0:
        print(json.dumps(dict(ranks=dp.ranks, petsc_bytes=rows)), flush=True)


if __name__ == "__main__":
    main()
