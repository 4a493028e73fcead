"""The minimum check of nitsche.distributed on the ranks of mpirun (for test_distributed.py):
python mpi_minimum.py; rank 0 prints one JSON line per problem with Newton's verdict, the
check's LOBPCG estimates and steps, the numbers all-gathered during Newton's method and the
smallest eigenvalue of the whole problem's Hessian at the result (dense, on rank 0).

- `saddle`: (u^2 - 1)^2 + |grad u|^2 from u = 0, a stationary point whose Hessian
  -4 M + 2 K has a positive diagonal but a negative eigenvalue (the constant): the check
  must fail there, by LOBPCG (the diagonal passes);
- `well`: the same from u = 0.2, converged to the well u = 1 (positive definite);
- `obstacle`: the shipped case at level 2 with GAMG (a preconditioner that is not exact)."""
import json

import numpy as np
from mpi4py import MPI
from skfem import ElementTriP1, MeshTri

import nitsche as ni
from nitsche import cases
from nitsche.distributed import DistributedProblem
from nitsche.ops import dot, grad


def double_well():
    u = ni.Field("u", MeshTri().refined(3), ElementTriP1())
    return ni.Problem([u], lambda u: (u.value ** 2 - 1) ** 2 + dot(grad(u), grad(u)))


def lowest(problem, x):
    """The smallest eigenvalue of the Hessian on the free dofs (dense)."""
    H = problem.hessian(x)[problem.free][:, problem.free].toarray()
    return float(np.linalg.eigvalsh(H)[0])


def main():
    comm = MPI.COMM_WORLD
    obstacle = cases.get("obstacle")
    make_obstacle = lambda: obstacle.problem(2, 1, obstacle.parameters({}))  # noqa: E731
    runs = [("saddle", double_well, "direct", 0.0), ("well", double_well, "direct", 0.2),
            ("obstacle", make_obstacle, "gamg", None)]
    for name, make, solver, start in runs:
        dp = DistributedProblem.build(make, comm)
        x0 = None if start is None else np.full(dp.ndofs, start)
        r = dp.minimize(x0=x0, solver=solver)
        if dp.rank == 0:
            stats = r.solver_stats
            print(json.dumps(dict(problem=name, ranks=r.ranks, converged=r.converged,
                                  reason=r.reason, estimates=stats["lobpcg_estimates"],
                                  steps=stats["lobpcg_steps"],
                                  gathered_numbers=stats["gathered_numbers"],
                                  lowest=lowest(make(), r.x))), flush=True)


if __name__ == "__main__":
    main()
