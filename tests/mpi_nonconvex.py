"""A double well (u^2 - 1)^2 + 1e-3 |grad u|^2 started at u = 0.2, where its Hessian is
negative definite, minimized by nitsche.distributed on the ranks of mpirun (for
test_distributed.py): rank 0 prints one JSON line (converged, u's range, iterations, the
diagonal shifts of the convexified steps, ranks)."""
import json

import numpy as np
from mpi4py import MPI
from skfem import ElementTriP1, MeshTri

import nitsche as ni
from nitsche.distributed import DistributedProblem
from nitsche.ops import dot, grad
from nitsche.partition import local


def double_well():
    u = ni.Field("u", MeshTri().refined(3), ElementTriP1())
    return ni.Problem([u], lambda u: (u.value ** 2 - 1) ** 2 + 1e-3 * dot(grad(u), grad(u)))


def main():
    comm = MPI.COMM_WORLD
    with local(comm):
        problem = DistributedProblem(double_well(), comm)
    r = problem.minimize(x0=np.full(problem.ndofs, 0.2), solver="direct")
    if problem.rank == 0:
        print(json.dumps(dict(converged=r.converged, reason=r.reason, low=float(r.x.min()),
                              high=float(r.x.max()), iterations=r.iterations,
                              shifts=list(r.shifts), ranks=r.ranks)), flush=True)


if __name__ == "__main__":
    main()
